"""POST /api/domains/{domain}/interpret: status codes and error text (an app with no libraries: none are needed)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from rba.domains import domain_names
from rba.interact.free_text import MAX_TEXT
from server.common.app_settings import Settings
from server.main import create_app


@pytest.fixture(scope="module")
def client(tmp_path_factory) -> Iterator[TestClient]:
    root = tmp_path_factory.mktemp("interpret")
    settings = Settings(data_dir=root / "data", models_dir=root / "models", cache_dir=root / "clips",
                        warm_start=False, prerender=False, prerender_library=False,
                        database_url=f"sqlite:///{root / 'rba.db'}")
    with TestClient(create_app(settings)) as c:
        yield c


def post(client: TestClient, domain: str, body: object):
    return client.post(f"/api/domains/{domain}/interpret", json=body)


def test_a_sentence_becomes_attribute_feedback(client):
    r = post(client, "walker", {"text": "bigger but softer steps"})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["feedback"] == [{"attribute": "step_size", "direction": "more"},
                                {"attribute": "softness", "direction": "more"}]
    assert set(body) == {"feedback", "confidence"} and 0.4 <= body["confidence"] <= 1.0
    assert post(client, "walker", {"text": "stomp less"}).json()["feedback"] == \
        [{"attribute": "softness", "direction": "more"}]
    assert post(client, "toy", {"text": "swing wider, but slower"}).json()["feedback"] == \
        [{"attribute": "amplitude", "direction": "more"}, {"attribute": "pace", "direction": "less"}]


def test_not_understood_is_a_422_naming_the_attributes_as_the_page_shows_them(client):
    r = post(client, "snake", {"text": "what a lovely day"})
    assert r.status_code == 422
    assert r.json()["detail"].startswith("I didn't understand 'what a lovely day'; "
                                         "the attributes are: bend width, compression, speed.")


def test_an_unknown_domain_is_a_422_listing_the_valid_ones(client):  # as on every route that takes a domain
    r = post(client, "kitchen", {"text": "faster"})
    assert r.status_code == 422
    assert f"domain: unknown domain 'kitchen'; valid: {', '.join(domain_names())}" in r.json()["detail"]


@pytest.mark.parametrize(("body", "message"), [
    ({"text": ""}, "text: is empty: say what to change, e.g. 'land more gently'"),
    ({"text": "   "}, "text: is empty: say what to change"),
    ({"text": "x" * (MAX_TEXT + 1)}, f"text: is {MAX_TEXT + 1} characters long; at most {MAX_TEXT}"),
    ({}, "text: Field required"),
    ({"text": 3}, "text: Input should be a valid string"),
    ({"text": "faster", "attribute": "speed"}, "attribute: Extra inputs are not permitted"),
])
def test_bad_bodies_are_422s_that_say_what_is_wrong(client, body, message):
    r = post(client, "walker", body)
    assert r.status_code == 422
    assert r.json()["detail"].startswith(message), r.json()["detail"]


def test_the_route_is_documented(client):
    route = client.get("/openapi.json").json()["paths"]["/api/domains/{domain}/interpret"]["post"]
    assert set(route["responses"]) >= {"200", "422"}
    assert route["requestBody"]["content"]["application/json"]["schema"]["$ref"].endswith("InterpretCreate")
