"""Edges an attacker found: conditional clip requests (If-Range, If-None-Match), activations at once, the admin
failure limit against the right token, and query parameters given twice."""

from __future__ import annotations

import shutil
import threading
from collections.abc import Iterator
from typing import Annotated

import pytest
from fastapi import Depends, FastAPI, Query
from fastapi.testclient import TestClient
from sqlmodel import Session

from server.api.deps import known_query
from server.db.admin_tables import ModelVersion
from server.main import create_app
from server.ops.model_versions import active_version
from tests.fakes import InstantCompute

TOKEN = "edges-test-token-1"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
FAILURES = 3  # RBA_ADMIN_FAILURES_PER_MINUTE here
VERSIONS = ("toy-v2", "toy-v3")  # published copies of the toy models


@pytest.fixture
def client(make_settings, database_url, tmp_path, toy_roots) -> Iterator[TestClient]:
    """An app on SQLite or PostgreSQL whose toy domain has two published versions besides its built-in models."""
    models = tmp_path / "models"
    shutil.copytree(toy_roots[1], models)
    for version in VERSIONS:
        shutil.copytree(models / "toy", models / "versions" / version / "toy")
    settings = make_settings(database_url=database_url, admin_token=TOKEN, models_dir=models,
                             admin_failures_per_minute=FAILURES)
    with TestClient(create_app(settings, InstantCompute()), raise_server_exceptions=False) as c:
        with Session(c.app.state.services.engine) as db:
            for version in VERSIONS:
                db.add(ModelVersion(version=version, domain="toy", method="global", rep="onehot", job_id="j",
                                    attributes=["amplitude", "pace"], held_out={}))
            db.commit()
        yield c


@pytest.fixture
def clip(client) -> tuple[str, str]:
    """A session's first clip: its URL and its ETag."""
    url = client.post("/api/sessions", json={"domain": "toy"}).json()["clip"]["url"]
    r = client.get(url)
    assert r.status_code == 200 and r.content == InstantCompute.CLIP
    return url, r.headers["etag"]


# -- If-Range, If-None-Match ------------------------------------------------------------------------

@pytest.mark.parametrize(("if_range", "status"), [
    ("{etag}", 206),
    ('"x"', 200),
    ("W/{etag}", 200),
    ("Mon, 07 Dec 2026 19:59:02 GMT", 200),
], ids=["current-etag", "other-etag", "weak-etag", "date"])
def test_if_range_gives_the_range_only_for_the_current_strong_etag(client, clip, if_range, status):
    url, etag = clip
    for method in ("GET", "HEAD"):
        r = client.request(method, url, headers={"Range": "bytes=0-3", "If-Range": if_range.format(etag=etag)})
        assert r.status_code == status, r.text
    r = client.get(url, headers={"Range": "bytes=0-3", "If-Range": if_range.format(etag=etag)})
    assert r.content == (InstantCompute.CLIP[:4] if status == 206 else InstantCompute.CLIP)


def test_if_range_keeps_the_range_error_bodies(client, clip):
    url, etag = clip
    size = len(InstantCompute.CLIP)
    r = client.get(url, headers={"Range": f"bytes={size + 10}-", "If-Range": etag})
    assert r.status_code == 416 and r.json()["detail"] == f"range 'bytes={size + 10}-' starts outside the clip's " \
                                                          f"{size} bytes"
    r = client.get(url, headers={"Range": "pages=1-2", "If-Range": etag})
    assert r.status_code == 400 and "bad Range header 'pages=1-2'" in r.json()["detail"]
    r = client.get(url, headers={"Range": "pages=1-2", "If-Range": '"stale"'})  # the range is ignored: no 400
    assert r.status_code == 200 and r.content == InstantCompute.CLIP


@pytest.mark.parametrize(("if_none_match", "status"), [
    ("{etag}", 304),
    ("W/{etag}", 304),
    ("*", 304),
    ('"other", W/{etag}', 304),
    ('"other"', 200),
    ('W/"other"', 200),
], ids=["strong", "weak", "star", "in-list", "other", "other-weak"])
def test_if_none_match_compares_weakly_and_star_matches(client, clip, if_none_match, status):
    url, etag = clip
    r = client.get(url, headers={"If-None-Match": if_none_match.format(etag=etag)})
    assert r.status_code == status and r.headers["etag"] == etag
    assert r.content == (b"" if status == 304 else InstantCompute.CLIP)


# -- activations at once --------------------------------------------------------------------------

def test_activations_at_once_all_succeed_and_one_wins(client):
    """Real threads against the real database (a file for SQLite): each round starts from the built-in models, the
    state where every activation used to read "no row" and insert one."""
    choices = (*VERSIONS, "builtin")
    threads_per_round, rounds = 12, 4

    def activate(version: str, start: threading.Barrier, codes: list[tuple[int, str]]) -> None:
        start.wait()
        r = client.post(f"/api/admin/models/{version}/activate", params={"domain": "toy"}, headers=AUTH)
        codes.append((r.status_code, r.text))

    for _ in range(rounds):
        assert client.post("/api/admin/models/builtin/activate", params={"domain": "toy"},
                           headers=AUTH).status_code == 200
        start, codes = threading.Barrier(threads_per_round), []
        threads = [threading.Thread(target=activate, args=(choices[i % len(choices)], start, codes))
                   for i in range(threads_per_round)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        assert [c for c in codes if c[0] != 200] == [] and len(codes) == threads_per_round
        with Session(client.app.state.services.engine) as db:
            assert active_version(db, "toy") in choices
        active = [v["version"] for v in client.get("/api/admin/models", params={"domain": "toy"},
                                                   headers=AUTH).json() if v["active"]]
        assert len(active) == 1 and active[0] in choices


def test_an_activation_replaces_the_active_version(client):
    for version in (*VERSIONS, VERSIONS[0]):
        assert client.post(f"/api/admin/models/{version}/activate", headers=AUTH).status_code == 200
        with Session(client.app.state.services.engine) as db:
            assert active_version(db, "toy") == version
        assert client.post("/api/sessions", json={"domain": "toy"}).json()["model_set"] == version
    client.post("/api/admin/models/builtin/activate", params={"domain": "toy"}, headers=AUTH)
    client.post("/api/admin/models/builtin/activate", params={"domain": "toy"}, headers=AUTH)  # twice: a no-op
    assert client.post("/api/sessions", json={"domain": "toy"}).json()["model_set"] == "builtin"


# -- the admin failure limit ----------------------------------------------------------------------

def test_the_right_token_gets_in_while_wrong_ones_wait(client):
    wrong = {"Authorization": "Bearer guess"}
    for _ in range(FAILURES):
        assert client.get("/api/admin/jobs", headers=wrong).status_code == 401
    r = client.get("/api/admin/jobs", headers=wrong)
    assert r.status_code == 429 and 55 <= int(r.headers["retry-after"]) <= 60
    r = client.get("/api/admin/jobs", headers=AUTH)
    assert r.status_code == 200 and r.json() == []
    assert client.get("/api/admin/jobs", headers=wrong).status_code == 429  # the address still waits for wrong ones
    assert client.get("/api/admin/jobs").status_code == 401  # no token at all is no guess


# -- query parameters given twice -----------------------------------------------------------------

@pytest.mark.parametrize(("path", "query", "named"), [
    ("/api/admin/models", "domain=toy&domain=walker", "'domain'"),
    ("/api/admin/labels", "domain=toy&limit=5&attribute=pace&limit=6&attribute=amplitude", "'attribute', 'limit'"),
])
def test_a_query_parameter_given_twice_is_a_422_naming_it(client, path, query, named):
    r = client.get(f"{path}?{query}", headers=AUTH)
    assert r.status_code == 422, r.text
    assert r.json()["detail"] == f"query parameter(s) {named} given more than once; each may be given once"


def test_a_list_query_parameter_may_repeat():
    """A route that declares a list takes every value: the check reads the route's declared parameters."""
    app = FastAPI(dependencies=[Depends(known_query)])

    @app.get("/tags")
    def tags(tag: Annotated[list[str] | None, Query()] = None, one: str = "") -> dict:
        return {"tag": tag, "one": one}

    with TestClient(app) as c:
        assert c.get("/tags?tag=a&tag=b&one=x").json() == {"tag": ["a", "b"], "one": "x"}
        r = c.get("/tags?tag=a&one=x&one=y")
        assert r.status_code == 422 and "'one' given more than once" in r.json()["detail"]
