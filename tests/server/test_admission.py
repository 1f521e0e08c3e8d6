"""Heavy requests run in bounded slots (server.api.admission): a client's excess is a 429, a full server a 503, and
light requests are answered while every heavy slot is busy. The heavy call is a stand-in held on an Event."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor

import anyio.to_thread
import pytest
from fastapi.testclient import TestClient

from server.api.admission import Admission, heavy
from server.common.errors import invalid
from server.main import create_app
from server.ops import text_feedback

INTERPRET = "/api/domains/toy/interpret"
HANG_GUARD = 60.0  # seconds: only a broken server takes this long; no speed is asserted


class Held:
    """The interpret operation, replaced: each call counts itself in and waits until ``gate`` is set."""

    def __init__(self) -> None:
        self.gate, self.entered, self._lock = threading.Event(), 0, threading.Lock()

    def __call__(self, svc, domain: str, text: str):
        with self._lock:
            self.entered += 1
        self.gate.wait(HANG_GUARD)
        raise invalid("not understood (a stand-in)")


@pytest.fixture
def held(monkeypatch) -> Iterator[Held]:
    stand_in = Held()
    monkeypatch.setattr(text_feedback, "interpret", stand_in)
    yield stand_in
    stand_in.gate.set()


@pytest.fixture
def app(make_settings) -> Iterator[Callable[..., TestClient]]:
    """app(**settings) -> a running app's client; requests from a pool of threads go through it at once."""
    clients: list[TestClient] = []

    def make(**overrides) -> TestClient:
        clients.append(TestClient(create_app(make_settings(**overrides))).__enter__())
        return clients[-1]

    yield make
    for client in clients:
        client.__exit__(None, None, None)


def admission(client: TestClient) -> Admission | None:
    layer = client.app.middleware_stack
    while layer is not None and not isinstance(layer, Admission):
        layer = getattr(layer, "app", None)
    return layer


def wait_until(condition: Callable[[], bool]) -> None:
    deadline = time.monotonic() + HANG_GUARD
    while not condition():
        assert time.monotonic() < deadline, "the requests never got there"
        time.sleep(0.01)


def fire(pool: ThreadPoolExecutor, client: TestClient, n: int) -> list[Future]:
    return [pool.submit(client.post, INTERPRET, json={"text": f"faster {i}"}) for i in range(n)]


def test_heavy_and_light_routes():
    for method, path in [("POST", INTERPRET), ("POST", "/api/sessions"), ("POST", "/api/sessions/ab12/feedback"),
                         ("GET", "/api/clips/toy/serve-00001.mp4"), ("HEAD", "/api/clips/toy/gen-ab.mp4"),
                         ("GET", "/api/sessions/ab12/export"), ("POST", "/api/admin/datasets")]:
        assert heavy(method, path), (method, path)
    for method, path in [("GET", "/api/sessions/ab12"), ("GET", "/api/domains"), ("GET", "/healthz"),
                         ("GET", "/static/app.js"), ("GET", "/api/clips/toy/serve-00001/status"),
                         ("GET", "/api/admin/jobs"), ("GET", "/")]:
        assert not heavy(method, path), (method, path)


def test_a_clients_heavy_request_past_its_share_is_a_429_with_retry_after(app, held):
    client = app(heavy_workers=1, heavy_queue=5, heavy_per_client=2)
    with ThreadPoolExecutor(2) as pool:
        first = fire(pool, client, 2)  # one runs, one waits for the slot
        wait_until(lambda: admission(client).in_flight == 2 and held.entered == 1)
        r = client.post(INTERPRET, json={"text": "faster"})
        assert r.status_code == 429, r.text
        assert int(r.headers["Retry-After"]) >= 1
        assert r.json()["detail"].startswith("too many heavy requests from this client at once: 2 running or "
                                             "waiting, the limit is 2 (RBA_HEAVY_PER_CLIENT); retry after ")
        held.gate.set()
        assert [f.result(HANG_GUARD).status_code for f in first] == [422, 422]
    assert client.post(INTERPRET, json={"text": "faster"}).status_code == 422  # its share is free again
    assert admission(client).in_flight == 0


def test_a_full_server_answers_503_with_retry_after(app, held):
    client = app(heavy_workers=1, heavy_queue=1, heavy_per_client=10)
    with ThreadPoolExecutor(2) as pool:
        first = fire(pool, client, 2)
        wait_until(lambda: admission(client).in_flight == 2)
        r = client.post(INTERPRET, json={"text": "faster"})
        assert r.status_code == 503, r.text
        assert int(r.headers["Retry-After"]) >= 1
        assert r.json()["detail"].startswith("the server is busy: 2 heavy requests running or waiting, the limit is "
                                             "1 running (RBA_HEAVY_WORKERS) and 1 waiting (RBA_HEAVY_QUEUE)")
        held.gate.set()
        assert [f.result(HANG_GUARD).status_code for f in first] == [422, 422]


def test_a_light_request_is_answered_while_every_heavy_slot_is_busy(app, held):
    """Three request threads in all: without the heavy slots, three held heavy requests would take every one."""
    client = app(heavy_workers=1, heavy_queue=10, heavy_per_client=10)
    session = client.post("/api/sessions", json={"domain": "toy", "method": "global", "rep": "onehot"}).json()
    threads = 3

    def shrink() -> None:
        anyio.to_thread.current_default_thread_limiter().total_tokens = threads

    client.portal.call(shrink)
    with ThreadPoolExecutor(threads + 1) as pool:
        heavy_requests = fire(pool, client, threads)
        wait_until(lambda: admission(client).in_flight == threads and held.entered == 1)
        light = pool.submit(client.get, f"/api/sessions/{session['id']}")
        assert light.result(HANG_GUARD).status_code == 200
        assert not held.gate.is_set() and held.entered == 1  # answered while the heavy ones still wait
        held.gate.set()
        assert [f.result(HANG_GUARD).status_code for f in heavy_requests] == [422] * threads
