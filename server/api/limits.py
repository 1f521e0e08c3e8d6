"""``BodyLimit``: request bodies over a cap are a 413, counted as they stream in.

A Content-Length may lie and a chunked body has none, so the bytes are counted as the app receives
them; a declared length over the cap is refused before anything is read. One middleware holds every
cap: JSON bodies get RBA_JSON_MAX_BYTES, the dataset upload its own, larger RBA_UPLOAD_MAX_BYTES.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

from fastapi import HTTPException
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.common.errors import error_response


class Cap(NamedTuple):
    """A body limit and how its 413 names it."""

    bytes: int
    setting: str  # the RBA_* variable that sets it
    what: str = "request body"
    hint: str = ""  # appended to the message, e.g. where a larger body goes

    def message(self, size: str) -> str:
        return f"{self.what} too large: {size}, over the limit of {self.bytes} bytes ({self.setting}){self.hint}"


class BodyLimit:
    """ASGI middleware: at most ``default.bytes`` body bytes per request, or the cap of its (method, path)."""

    def __init__(self, app: ASGIApp, default: Cap, routes: Mapping[tuple[str, str], Cap] | None = None) -> None:
        self.app, self.default, self.routes = app, default, dict(routes or {})

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        cap = self.routes.get((scope["method"], scope["path"]), self.default)
        declared = Headers(scope=scope).get("content-length", "")
        if declared.isdigit() and int(declared) > cap.bytes:
            await error_response(413, cap.message(f"{int(declared)} bytes"))(scope, receive, send)
            return
        received = 0

        async def counted() -> Message:
            """FastAPI re-raises an HTTPException from here as it is: our error handler answers 413."""
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > cap.bytes:
                    raise HTTPException(413, cap.message(f"more than {cap.bytes} bytes"))
            return message

        await self.app(scope, counted, send)
