"""Hostile input: one error body everywhere, strict bodies, the JSON cap, the admin gate and its failure limit,
clients that disconnect mid-body, and an OpenAPI document that says all of it."""

from __future__ import annotations

import json
import logging
from collections.abc import Iterable, Iterator
from typing import NamedTuple

import pytest
from fastapi.testclient import TestClient

from rba.domains import domain_names
from server.api.auth import FailureLimiter
from server.common.app_settings import Settings
from server.db.tables import attribute_methods
from server.main import create_app
from tests.conftest import own_copy
from tests.fakes import InstantCompute

TOKEN = "hardening-test-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
CAP = 4096  # RBA_JSON_MAX_BYTES here
FAILURES = 3  # RBA_ADMIN_FAILURES_PER_MINUTE here
ERROR_KEYS = {"detail", "errors", "problems"}


@pytest.fixture(scope="module")
def client(toy_roots, tmp_path_factory) -> Iterator[TestClient]:
    root = tmp_path_factory.mktemp("hardening")
    own_copy(toy_roots, root)
    settings = Settings(data_dir=root / "data", models_dir=root / "models", cache_dir=root / "clips",
                        database_url=f"sqlite:///{root / 'rba.db'}", admin_token=TOKEN, warm_start=False,
                        prerender=False, prerender_library=False, json_max_bytes=CAP,
                        admin_failures_per_minute=FAILURES, upload_max_bytes=64 * 1024)
    with TestClient(create_app(settings, InstantCompute()), raise_server_exceptions=False) as c:
        yield c


def an_error(r, status: int) -> str:
    """The response is ``status`` with the one error body; its detail."""
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == "application/json"
    body = r.json()
    assert set(body) <= ERROR_KEYS and isinstance(body["detail"], str)
    return body["detail"]


class Reply(NamedTuple):
    status: int
    body: dict | list | None
    consumed: int  # body chunks the app read
    headers: dict[str, str]


def call(client: TestClient, method: str, path: str, headers: dict[str, str], chunks: Iterable[bytes],
         peer: str = "203.0.113.9", disconnect: bool = False) -> Reply:
    """Drive the app at the ASGI level from client ``peer``, the body streamed chunk by chunk.

    ``disconnect``: after the chunks the client is gone (as uvicorn reports a connection closed mid-body).
    """
    async def run() -> Reply:
        consumed, sent, pending = 0, [], iter(chunks)

        async def receive() -> dict:
            nonlocal consumed
            chunk = next(pending, None)
            if chunk is None:
                return {"type": "http.disconnect"} if disconnect else {"type": "http.request", "body": b""}
            consumed += 1
            return {"type": "http.request", "body": chunk, "more_body": True}

        async def send(message: dict) -> None:
            sent.append(message)

        scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1", "method": method,
                 "scheme": "http", "path": path, "raw_path": path.encode(), "root_path": "", "query_string": b"",
                 "headers": [(k.lower().encode(), v.encode()) for k, v in headers.items()],
                 "client": (peer, 5000), "server": ("testserver", 80), "state": {}}
        await client.app(scope, receive, send)
        start = next(m for m in sent if m["type"] == "http.response.start")
        body = b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
        return Reply(start["status"], json.loads(body) if body else None, consumed,
                     {k.decode(): v.decode() for k, v in start.get("headers", [])})

    return client.portal.call(run)


def megabytes(n: int) -> Iterator[bytes]:
    for _ in range(n):
        yield b" " * 2**20


# -- one error model ------------------------------------------------------------------------------

@pytest.mark.parametrize(("method", "path", "status", "message"), [
    ("PUT", "/api/sessions", 405, "PUT is not allowed on /api/sessions; allowed: POST"),
    ("DELETE", "/api/sessions/abc", 405, "DELETE is not allowed on /api/sessions/abc; allowed: GET"),
    ("GET", "/api/nothing/here", 404, "no API route /api/nothing/here; see /docs for the routes"),
    ("GET", "/nothing", 404, "no page /nothing; see /docs for the routes"),
    ("GET", "/api/clips/walker/serve-00001.mp4", 404, "no serve library for 'walker'"),
    ("GET", "/api/sessions/" + "x" * 65, 422, "session_id: String should have at most 64 characters"),
])
def test_routing_errors_have_the_error_body(client, method, path, status, message):
    r = client.request(method, path)
    assert message in an_error(r, status)
    if status == 405:
        assert r.headers["allow"] == message.split("allowed: ")[1]


@pytest.mark.parametrize(("body", "message"), [
    (b'{"domain": "to\xff"}', "body: the JSON is not UTF-8 text"),
    (b"[" * 2000 + b"]" * 2000, "body: the JSON is nested too deeply"),  # under the cap, deeper than Python goes
], ids=["not-utf8", "nested"])
def test_unreadable_json_is_422_saying_why(client, body, message):
    r = client.post("/api/sessions", content=body, headers={"Content-Type": "application/json"})
    assert an_error(r, 422) == message
    assert r.json()["errors"] == [{"loc": ["body"], "msg": message, "type": "json_invalid"}]


def test_range_refusals_have_the_error_body(client):
    url = client.post("/api/sessions", json={"domain": "toy"}).json()["clip"]["url"]
    size = len(InstantCompute.CLIP)
    r = client.get(url, headers={"Range": f"bytes={size + 10}-"})
    assert an_error(r, 416) == f"range 'bytes={size + 10}-' starts outside the clip's {size} bytes"
    assert r.headers["content-range"] == f"bytes */{size}"
    assert "bad Range header 'pages=1-2'" in an_error(client.get(url, headers={"Range": "pages=1-2"}), 400)
    assert client.get(url, headers={"Range": "bytes=0-3"}).content == InstantCompute.CLIP[:4]


def test_a_bug_is_a_500_with_the_error_body(client, monkeypatch):
    def broken(*_args):
        raise RuntimeError("boom")

    monkeypatch.setattr("server.api.routes.domains.domains_public", broken)
    r = client.get("/api/domains")
    assert an_error(r, 500) == "internal error in GET /api/domains; the server log has the details"


# -- strict bodies --------------------------------------------------------------------------------

@pytest.mark.parametrize(("body", "message"), [
    ({"step": 0, "satisfied": "yes"}, "satisfied: Input should be a valid boolean"),
    ({"step": True, "satisfied": True}, "step: Input should be a valid integer"),
    ({"step": "0", "satisfied": True}, "step: Input should be a valid integer"),
    ({"step": 0, "satisfied": True, "why": "because"}, "why: Extra inputs are not permitted"),
    ({"step": 0, "feedback": [{"attribute": "pace", "direction": "more", "by": 2}]},
     "feedback.0.by: Extra inputs are not permitted"),
])
def test_feedback_bodies_are_strict(client, body, message):
    session = client.post("/api/sessions", json={"domain": "toy"}).json()
    r = client.post(f"/api/sessions/{session['id']}/feedback", json=body)
    assert message in an_error(r, 422)
    assert client.get(f"/api/sessions/{session['id']}").json()["step"] == 0


@pytest.mark.parametrize(("path", "body", "message"), [
    ("/api/sessions", {"domain": "toy", "colour": "red"}, "colour: Extra inputs are not permitted"),
    ("/api/sessions", {"domain": "toy", "method": "pbrl"},
     f"method: unknown method 'pbrl'; valid: {', '.join(attribute_methods())}"),
    ("/api/admin/train", {"domain": "toy", "include_page_labels": "yes"},
     "include_page_labels: Input should be a valid boolean"),
    ("/api/admin/train", {"domain": "toy", "preset": "huge"}, "preset: unknown preset 'huge'; valid: "),
    ("/api/admin/attributes", {"domain": "toy", "name": "wobble", "description": "How much it wobbles.", "x": 1},
     "x: Extra inputs are not permitted"),
])
def test_request_bodies_are_strict_and_name_the_valid_values(client, path, body, message):
    assert message in an_error(client.post(path, json=body, headers=AUTH), 422)
    assert client.get("/api/admin/jobs", headers=AUTH).json() == []


# -- the JSON cap ---------------------------------------------------------------------------------

@pytest.mark.parametrize(("path", "headers", "message"), [
    ("/api/domains?x=1", {}, "unknown query parameter(s) 'x'; valid: none"),
    ("/api/admin/datasets?domian=toy", AUTH, "unknown query parameter(s) 'domian'; valid: domain"),
])
def test_unknown_query_parameters_are_422_naming_the_valid_ones(client, path, headers, message):
    r = client.get(path, headers=headers)
    assert r.status_code == 422 and r.json()["detail"] == message
    assert client.get("/api/admin/datasets?domain=toy", headers=AUTH).status_code == 200
    assert client.get("/?utm_source=mail").status_code == 200  # the pages take any query string


def test_a_declared_body_over_the_cap_is_413_unread(client):
    status, body, consumed, _ = call(client, "POST", "/api/sessions",
                                     {"content-type": "application/json", "content-length": str(CAP + 1)},
                                     [b" " * (CAP + 1)])
    assert (status, consumed) == (413, 0)
    assert body["detail"] == (f"request body too large: {CAP + 1} bytes, over the limit of {CAP} bytes "
                              "(RBA_JSON_MAX_BYTES); datasets go to POST /api/admin/datasets")


@pytest.mark.parametrize("declared", [None, "10"], ids=["chunked", "lying-content-length"])
def test_a_streamed_body_is_cut_off_at_the_cap(client, declared):
    headers = {"content-type": "application/json", **({"content-length": declared} if declared else {})}
    status, body, consumed, _ = call(client, "POST", "/api/sessions", headers, (b" " * 1024 for _ in range(1000)))
    assert status == 413 and consumed == CAP // 1024 + 1  # stopped at the first chunk past the cap
    assert f"more than {CAP} bytes, over the limit of {CAP} bytes" in body["detail"]


def test_the_upload_has_its_own_limit_not_the_json_cap(client):
    labels = json.dumps({"orderings": [], "pad": " " * (2 * CAP)}).encode()
    r = client.post("/api/admin/datasets", data={"domain": "toy"}, headers=AUTH,
                    files={"labels": ("labels.json", labels, "application/json")})
    assert "labels" in an_error(r, 422)  # checked, not refused for its size
    assert r.json()["problems"]


def test_the_default_cap_is_one_megabyte():
    assert Settings().json_max_bytes == 2**20


# -- the admin gate -------------------------------------------------------------------------------

@pytest.mark.parametrize(("headers", "message"), [
    ({}, "admin token required: send 'Authorization: Bearer <token>'"),
    ({"authorization": "Bearer nope"}, "wrong admin token"),
])
def test_admin_token_is_checked_before_the_body_is_read(client, headers, message):
    reply = call(client, "POST", "/api/admin/train", {"content-type": "application/json", **headers}, megabytes(50),
                 peer="198.51.100.20")
    assert (reply.status, reply.body, reply.consumed) == (401, {"detail": message}, 0)
    assert reply.headers["www-authenticate"] == "Bearer"


def test_repeated_wrong_tokens_are_slowed_down(client):
    peer = "198.51.100.30"
    for _ in range(FAILURES + 2):  # no token at all is no guess: it never counts
        assert call(client, "GET", "/api/admin/jobs", {}, [], peer).status == 401
    for _ in range(FAILURES):
        reply = call(client, "GET", "/api/admin/jobs", {"authorization": "Bearer guess"}, [], peer)
        assert (reply.status, reply.body) == (401, {"detail": "wrong admin token"})
    reply = call(client, "GET", "/api/admin/jobs", {"authorization": "Bearer guess"}, [], peer)
    wait = int(reply.headers["retry-after"])
    assert 55 <= wait <= 60
    assert (reply.status, reply.body) == (429, {"detail": f"too many wrong admin tokens from {peer}: "
                                                          f"try again in {wait} s"})
    r = client.get("/api/admin/jobs", headers=AUTH)  # another client is not slowed down
    assert r.status_code == 200 and r.json() == []


def test_failure_limiter_forgets_old_failures_and_old_clients():
    now = [0.0]
    limiter = FailureLimiter(limit=3, window=60, clock=lambda: now[0], max_clients=2)
    for t in (0, 10, 20):
        now[0] = t
        assert limiter.retry_after("a") == 0
        limiter.failed("a")
    assert limiter.retry_after("a") == 40
    now[0] = 60.5
    assert limiter.retry_after("a") == 0  # the failure at 0 s has expired
    limiter.failed("a")
    assert limiter.retry_after("a") == 10  # 10 s + 60 s - 60.5 s, rounded up
    limiter = FailureLimiter(limit=1, window=60, clock=lambda: 0.0, max_clients=2)
    for client in ("a", "b", "c"):
        limiter.failed(client)
    assert [limiter.retry_after(c) for c in "abc"] == [0, 60, 60]  # the oldest client was dropped


# -- clients that leave mid-body ------------------------------------------------------------------

@pytest.mark.parametrize(("path", "content_type"), [
    ("/api/admin/datasets", "multipart/form-data; boundary=xyz"),
    ("/api/sessions", "application/json"),
])
def test_a_false_content_length_logs_no_traceback(client, caplog, path, content_type):
    caplog.set_level(logging.INFO)
    headers = {"content-type": content_type, "content-length": "3000", **AUTH}
    call(client, "POST", path, headers, [b"--xyz\r\n" + b"a" * 100], disconnect=True)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING or r.exc_info], caplog.text
    assert f"POST {path}: the client disconnected before sending its whole body" in caplog.text


# -- the document says all of it --------------------------------------------------------------------

def test_the_document_lists_errors_enums_auth_and_the_upload_form(client):
    spec = client.get("/openapi.json").json()
    schemas = spec["components"]["schemas"]
    assert "HTTPValidationError" not in schemas
    for path, item in spec["paths"].items():
        for method, op in item.items():
            codes = {int(c) for c in op["responses"]}
            for code in (c for c in codes if c >= 400):  # every error has the one body
                assert op["responses"][str(code)]["content"]["application/json"]["schema"] == \
                    {"$ref": "#/components/schemas/ErrorPublic"}, (method, path, code)
            assert 413 in codes, (method, path)
            if op.get("parameters") or op.get("requestBody"):
                assert 422 in codes, (method, path)
            if path.startswith("/api/admin"):
                assert {401, 429, 503} <= codes and op["security"] == [{"HTTPBearer": []}], (method, path)
    domains = list(domain_names())
    assert schemas["SessionCreate"]["properties"]["domain"]["enum"] == domains
    assert schemas["SessionCreate"]["properties"]["method"]["enum"] == list(attribute_methods())
    assert schemas["SessionCreate"]["properties"]["rep"]["enum"] == ["onehot", "language"]
    assert schemas["SessionCreate"]["additionalProperties"] is False
    clip = spec["paths"]["/api/clips/{domain}/{rollout_id}.mp4"]["get"]["parameters"][0]
    assert clip["schema"]["enum"] == domains
    form = spec["paths"]["/api/admin/datasets"]["post"]["requestBody"]["content"]["multipart/form-data"]
    assert form["schema"] == {"$ref": "#/components/schemas/DatasetUpload"}
    upload = schemas["DatasetUpload"]
    assert upload["required"] == ["domain", "labels"] and upload["properties"]["domain"]["enum"] == domains
    assert upload["properties"]["trajectories"]["format"] == "binary"
