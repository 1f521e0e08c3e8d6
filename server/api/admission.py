"""``Admission``: heavy requests run in bounded slots of their own, so they cannot starve light ones.

Sync routes run in Starlette's one thread pool (anyio's default limiter: 40 threads), first come first served.
Without a bound, a burst of heavy requests (a sentence model, an agent step that searches, a render waited on)
takes every thread and CPU, and a light ``GET /api/sessions/{id}`` waits behind all of them. So the heavy routes,
listed once here (``HEAVY``), enter the app only holding one of ``RBA_HEAVY_WORKERS`` slots (an anyio
``CapacityLimiter``, at most 32 of the 40 threads); others wait for a slot, up to ``RBA_HEAVY_QUEUE`` of them, and
one client (address) may have at most ``RBA_HEAVY_PER_CLIENT`` running or waiting. Beyond those the answer is at
once a 429 (this client has too many) or a 503 (the server is full), with ``Retry-After``: a client backs off
instead of holding a connection for minutes. Light routes pass straight through.

A slot is freed when the response starts: streaming a clip's bytes to a slow client is not heavy work.
"""

from __future__ import annotations

import math
import re
import time
from collections import Counter

import anyio
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.common.errors import error_response

_CLIP = re.compile(r"/api/clips/[^/]+/[^/]+\.mp4")
HEAVY: tuple[tuple[str, re.Pattern[str]], ...] = (
    ("POST", re.compile(r"/api/domains/[^/]+/interpret")),  # a sentence model
    ("POST", re.compile(r"/api/sessions")),  # an agent's first query, may search
    ("POST", re.compile(r"/api/sessions/[^/]+/feedback")),  # an agent step, may search or re-fit
    ("POST", re.compile(r"/api/participate/[^/]+/answer")),  # a study trial's agent step
    ("GET", re.compile(r"/api/sessions/[^/]+/export")),  # a zip with a clip and a re-fitted reward
    ("GET", _CLIP), ("HEAD", _CLIP),  # may simulate, and waits for a render
    ("POST", re.compile(r"/api/admin/datasets")),  # an upload, checked whole
)
FIRST_GUESS_SECONDS = 1.0  # what a heavy request takes, until some were timed
SMOOTHING = 0.2  # weight of the latest heavy request's time in the running estimate


def heavy(method: str, path: str) -> bool:
    """Whether a request is heavy work (``HEAVY``); everything else is light."""
    return any(method == m and pattern.fullmatch(path) for m, pattern in HEAVY)


class Admission:
    """ASGI middleware: heavy requests run at most ``workers`` at once, ``queue`` more wait, ``per_client`` each."""

    def __init__(self, app: ASGIApp, workers: int, queue: int, per_client: int) -> None:
        self.app, self.workers, self.queue, self.per_client = app, workers, queue, per_client
        self.slots = anyio.CapacityLimiter(workers)
        self.clients: Counter[str] = Counter()  # heavy requests running or waiting, per client
        self.seconds = FIRST_GUESS_SECONDS  # a heavy request's running time, smoothed

    @property
    def in_flight(self) -> int:
        return self.clients.total()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or not heavy(scope["method"], scope["path"]):
            await self.app(scope, receive, send)
            return
        client = scope["client"][0] if scope.get("client") else "unknown"
        refusal = self._refusal(client)
        if refusal is not None:
            await refusal(scope, receive, send)
            return
        self.clients[client] += 1  # the event loop's thread alone counts: no lock
        token, started, held = object(), 0.0, False

        def release() -> None:
            nonlocal held
            if held:
                held = False
                self.slots.release_on_behalf_of(token)
                self.seconds += SMOOTHING * (time.monotonic() - started - self.seconds)

        async def sending(message: Message) -> None:
            if message["type"] == "http.response.start":
                release()
            await send(message)

        try:
            await self.slots.acquire_on_behalf_of(token)
            started, held = time.monotonic(), True
            await self.app(scope, receive, sending)
        finally:
            release()
            self.clients[client] -= 1
            if self.clients[client] <= 0:
                del self.clients[client]

    def _refusal(self, client: str) -> ASGIApp | None:
        """A 429 if ``client`` has its share in flight, a 503 if the server has; None to admit the request."""
        if self.clients[client] >= self.per_client:
            wait = self._retry_after(self.clients[client])
            return error_response(429, f"too many heavy requests from this client at once: {self.clients[client]} "
                                  f"running or waiting, the limit is {self.per_client} (RBA_HEAVY_PER_CLIENT); "
                                  f"retry after {wait} s", {"Retry-After": str(wait)})
        if self.in_flight >= self.workers + self.queue:
            wait = self._retry_after(self.in_flight)
            return error_response(503, f"the server is busy: {self.in_flight} heavy requests running or waiting, the "
                                  f"limit is {self.workers} running (RBA_HEAVY_WORKERS) and {self.queue} waiting "
                                  f"(RBA_HEAVY_QUEUE); retry after {wait} s", {"Retry-After": str(wait)})
        return None

    def _retry_after(self, ahead: int) -> int:
        """Whole seconds until ``ahead`` heavy requests have likely ended, on ``workers`` slots (at least 1)."""
        return max(1, math.ceil(self.seconds * ahead / self.workers))
