"""POST /api/domains/{domain}/interpret: status codes and error text (an app with no libraries: none are needed)."""

from __future__ import annotations

import functools
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from rba.domains import domain_names, get_domain
from rba.interact import free_text
from rba.interact.free_text import MAX_TEXT, anchors
from server.common.app_settings import Settings
from server.main import create_app
from server.ops import text_feedback
from server.runtime.services import Services


def settings_in(root: Path, **overrides) -> Settings:
    """An app with no libraries (none are needed), its files under ``root``."""
    return Settings(**{"data_dir": root / "data", "models_dir": root / "models", "cache_dir": root / "clips",
                       "warm_start": False, "prerender": False, "prerender_library": False,
                       "database_url": f"sqlite:///{root / 'rba.db'}", **overrides})


@pytest.fixture(scope="module")
def client(tmp_path_factory) -> Iterator[TestClient]:
    with TestClient(create_app(settings_in(tmp_path_factory.mktemp("interpret")))) as c:
        yield c


def post(client: TestClient, domain: str, body: object):
    return client.post(f"/api/domains/{domain}/interpret", json=body)


def test_a_sentence_becomes_attribute_feedback(client):
    r = post(client, "walker", {"text": "bigger but softer steps"})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["feedback"] == [{"attribute": "step_size", "direction": "more"},
                                {"attribute": "softness", "direction": "more"}]
    assert set(body) == {"feedback", "confidence", "low_confidence", "alternatives"}
    assert 0.4 <= body["confidence"] <= 1.0
    body = post(client, "walker", {"text": "stomp less"}).json()
    assert body["feedback"] == [{"attribute": "softness", "direction": "more"}]
    assert body["low_confidence"] is False and body["alternatives"] == []  # sure: one reading, yes or no
    assert post(client, "toy", {"text": "swing wider, but slower"}).json()["feedback"] == \
        [{"attribute": "amplitude", "direction": "more"}, {"attribute": "pace", "direction": "less"}]


def test_an_unsure_reading_offers_the_two_likeliest_to_choose_from(client):
    body = post(client, "manipulator", {"text": "steadier please"}).json()
    assert body["low_confidence"] is True and body["confidence"] < 0.6
    assert body["alternatives"] == [[{"attribute": "instability", "direction": "less"}],
                                    [{"attribute": "instability", "direction": "more"}]]
    assert body["feedback"] == body["alternatives"][0]


def test_each_domain_lists_examples_the_interpreter_reads_surely(client):
    listed = {d["name"]: d["examples"] for d in client.get("/api/domains").json()["domains"]}
    assert listed["lane_change"] == listed["lane_change_image"] == ["smooth turn", "leave plenty of room"]
    assert listed["snake"] == ["narrow bends", "bunch up tightly", "slow"]
    for name, examples in listed.items():
        assert 2 <= len(examples) <= 3, name
        for text in examples:
            body = post(client, name, {"text": text}).json()
            assert len(body["feedback"]) == 1 and not body["low_confidence"], (name, text, body)


def test_the_sentence_model_loads_at_start_up_once_before_any_request(tmp_path, monkeypatch):
    """Services.start builds every domain's interpreter in the background (a domain and its views share one); a
    request afterwards builds nothing."""
    built: list = []
    real = free_text._interpreter
    monkeypatch.setattr(free_text, "_interpreter", functools.cache(lambda phrases: built.append(phrases)
                                                                   or real(phrases)))
    svc = Services.start(settings_in(tmp_path, warm_start=True))
    try:
        svc.reading.join(300)
        assert not svc.reading.is_alive()
        assert sorted(built, key=str) == sorted({anchors(get_domain(n)) for n in domain_names()}, key=str)
        assert text_feedback.interpret(svc, "lane_change_image", "turn more gently").feedback == \
            (("sharpness", "less"),)
        assert len(built) == len({anchors(get_domain(n)) for n in domain_names()})
    finally:
        svc.stop()
    cold = Services.start(settings_in(tmp_path / "cold"))
    cold.stop()
    assert cold.reading is None  # without a warm start (tests), the first request loads it


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
