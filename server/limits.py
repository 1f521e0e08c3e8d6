"""``BodyLimit``: request bodies over a cap are a 413, counted as they stream in.

A Content-Length may lie and a chunked body has none, so the bytes are counted as the app receives
them; a declared length over the cap is refused before anything is read. The dataset upload is exempt:
it streams its multipart body under its own, larger limit (RBA_UPLOAD_MAX_BYTES).
"""

from __future__ import annotations

from fastapi import HTTPException
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.errors import error_response


class BodyLimit:
    """ASGI middleware: at most ``limit`` body bytes per request, except on the ``exempt`` (method, path) pairs."""

    def __init__(self, app: ASGIApp, limit: int, exempt: frozenset[tuple[str, str]] = frozenset()) -> None:
        self.app, self.limit, self.exempt = app, limit, exempt

    def message(self, size: str) -> str:
        return (f"request body too large: {size}, over the limit of {self.limit} bytes (RBA_JSON_MAX_BYTES); "
                "datasets go to POST /api/admin/datasets")

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or (scope["method"], scope["path"]) in self.exempt:
            await self.app(scope, receive, send)
            return
        declared = Headers(scope=scope).get("content-length", "")
        if declared.isdigit() and int(declared) > self.limit:
            await error_response(413, self.message(f"{int(declared)} bytes"))(scope, receive, send)
            return
        received = 0

        async def counted() -> Message:
            """FastAPI re-raises an HTTPException from here as it is: our error handler answers 413."""
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.limit:
                    raise HTTPException(413, self.message(f"more than {self.limit} bytes"))
            return message

        await self.app(scope, counted, send)
