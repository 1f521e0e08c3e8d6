"""Admin routes need ``Authorization: Bearer <RBA_ADMIN_TOKEN>`` (compared in constant time).

``AdminGate`` checks it in front of the app: FastAPI reads and parses a JSON body before any dependency
runs, so a dependency would check the token only after a stranger's 50 MB body was read. The gate also
makes a client that keeps sending wrong tokens wait (``FailureLimiter``: 429 with ``Retry-After``); the right
token still gets in from that address, so a guesser sharing an admin's address (a NAT, a proxy) cannot lock the
admin out.
"""

from __future__ import annotations

import hmac
import math
import time
from collections import deque
from collections.abc import Callable
from typing import Annotated

from fastapi import HTTPException, Request, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.datastructures import Headers
from starlette.responses import Response
from starlette.types import ASGIApp, Receive, Scope, Send

from server.common.errors import error_response

ADMIN_PREFIX = "/api/admin"
CHECKED = "rba.admin_checked"  # scope key: the gate let this request through
BEARER = HTTPBearer(auto_error=False, description="RBA_ADMIN_TOKEN, as 'Authorization: Bearer <token>'")
CHALLENGE = {"WWW-Authenticate": "Bearer"}
ADMIN_ERRORS = (401, 413, 422, 429, 503)
"""What every admin route may answer (its own errors aside)."""


class FailureLimiter:
    """Wrong tokens per client, in memory: after ``limit`` within ``window`` seconds the client must wait.

    Each client keeps at most ``limit`` times and at most ``max_clients`` clients are kept (the oldest go).
    """

    def __init__(self, limit: int, window: float = 60.0, clock: Callable[[], float] = time.monotonic,
                 max_clients: int = 10_000) -> None:
        self.limit, self.window, self.clock, self.max_clients = limit, window, clock, max_clients
        self._times: dict[str, deque[float]] = {}

    def retry_after(self, client: str) -> int:
        """Seconds until ``client`` may try again (0: now)."""
        times = self._times.get(client)
        if times is None or len(times) < self.limit:
            return 0
        wait = times[0] + self.window - self.clock()
        if wait <= 0:
            return 0
        return max(1, math.ceil(wait))

    def failed(self, client: str) -> None:
        self._times.setdefault(client, deque(maxlen=self.limit)).append(self.clock())
        if len(self._times) > self.max_clients:
            del self._times[next(iter(self._times))]


def is_admin_path(path: str) -> bool:
    return path == ADMIN_PREFIX or path.startswith(ADMIN_PREFIX + "/")


class AdminGate:
    """ASGI middleware: every request under /api/admin is refused here, before its body is read, unless its token is
    right; 503 when no token is configured."""

    def __init__(self, app: ASGIApp, token: str | None, failures: FailureLimiter) -> None:
        self.app, self.token, self.failures = app, token, failures

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and is_admin_path(scope["path"]):
            refusal = self.refusal(scope)
            if refusal is not None:
                await refusal(scope, receive, send)
                return
            scope[CHECKED] = True
        await self.app(scope, receive, send)

    def refusal(self, scope: Scope) -> Response | None:
        if not self.token:
            return error_response(503, "admin disabled: set RBA_ADMIN_TOKEN to enable the admin routes")
        scheme, _, given = Headers(scope=scope).get("authorization", "").partition(" ")
        if scheme.lower() != "bearer" or not given.strip():
            return error_response(401, "admin token required: send 'Authorization: Bearer <token>'", CHALLENGE)
        client = (scope.get("client") or ("unknown",))[0]
        if hmac.compare_digest(given.strip().encode(), self.token.encode()):
            return None  # even while wrong ones from its address wait, which they still do after it
        wait = self.failures.retry_after(client)
        if wait:
            return error_response(429, f"too many wrong admin tokens from {client}: try again in {wait} s",
                                  {"Retry-After": str(wait)})
        self.failures.failed(client)
        return error_response(401, "wrong admin token", CHALLENGE)


def require_admin(request: Request,
                  _bearer: Annotated[HTTPAuthorizationCredentials | None, Security(BEARER)] = None) -> None:
    """Declares the bearer scheme in the OpenAPI document; the gate checked the token already.

    A route outside /api/admin that asks for this fails closed: the gate never saw it.
    """
    if not request.scope.get(CHECKED):
        raise HTTPException(401, f"admin routes live under {ADMIN_PREFIX}, where the token is checked",
                            headers=CHALLENGE)

