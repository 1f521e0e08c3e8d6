"""One error body for every 4xx and 5xx the app answers: ``ErrorPublic``, ``{"detail": "<one readable sentence>"}``.

``install`` gives that shape to what FastAPI and Starlette would answer in their own (invalid requests,
unknown routes, wrong methods, bodies that are not JSON, unexpected failures); ``responses`` documents
it on the routes, so that the OpenAPI document says what clients really get.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

from fastapi import FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect
from starlette.routing import Match

from rba.data.library import LibraryNotFoundError

log = logging.getLogger(__name__)


class FieldError(BaseModel):
    loc: list[str | int] = Field(description="where: 'body', 'query' or 'path', then the field's path")
    msg: str
    type: str


class ErrorPublic(BaseModel):
    """Every error response: ``detail`` says what is wrong and what is valid."""

    detail: str = Field(description="what is wrong and what is valid, in one sentence")
    errors: list[FieldError] | None = Field(default=None, description="an invalid request (422): each problem")
    problems: list[str] | None = Field(default=None, description="an invalid upload (422): every problem found")


DESCRIPTIONS = {
    400: "the body could not be read",
    401: "missing or wrong admin token",
    404: "not found",
    409: "conflict with the current state",
    413: "the request body is over the limit",
    416: "the byte range is outside the file",
    422: "invalid request: the message names what is wrong and the valid values",
    429: "too many wrong admin tokens from this client: wait Retry-After seconds",
    503: "admin disabled (RBA_ADMIN_TOKEN unset)",
}


def responses(*codes: int, said: Mapping[int, str] | None = None) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` for ``codes``, all with the error model (``said`` overrides descriptions)."""
    said = said or {}
    return {code: {"model": ErrorPublic, "description": said.get(code, DESCRIPTIONS[code])} for code in codes}


def error_response(status: int, detail: str, headers: Mapping[str, str] | None = None, **extra: Any) -> JSONResponse:
    return JSONResponse(status_code=status, content={"detail": detail, **extra}, headers=dict(headers or {}))


def not_found(detail: str) -> HTTPException:
    return HTTPException(status_code=404, detail=detail)


def conflict(detail: str) -> HTTPException:
    return HTTPException(status_code=409, detail=detail)


def invalid(detail: str) -> HTTPException:
    return HTTPException(status_code=422, detail=detail)


def _where(loc: tuple) -> str:
    parts = [str(p) for p in loc if p not in ("body",)]
    return ".".join(parts) or "body"


async def _validation_error(_request: Request, exc: RequestValidationError) -> JSONResponse:
    """FastAPI lists pydantic errors; we also join them into one sentence for people and UIs."""
    errors = exc.errors()
    messages = []
    for err in errors:
        msg = str(err.get("msg", "invalid")).removeprefix("Value error, ")
        messages.append(f"{_where(tuple(err.get('loc', ())))}: {msg}")
    clean = [{"loc": [p if isinstance(p, int) else str(p) for p in e.get("loc", ())], "msg": str(e.get("msg")),
              "type": str(e.get("type"))} for e in errors]
    return error_response(422, "; ".join(messages) or "invalid request", errors=clean)


# Why FastAPI could not read a JSON body (it answers 400 "There was an error parsing the body" for all).
_UNREADABLE = {
    UnicodeDecodeError: "body: the JSON is not UTF-8 text",
    RecursionError: "body: the JSON is nested too deeply",
}


def _unmatched(request: Request, exc: StarletteHTTPException) -> str | None:
    """Our words for Starlette's own 404 (no route), else None (405: ``_not_allowed``)."""
    path = request.url.path
    if exc.status_code == 404 and "endpoint" not in request.scope:
        where = "API route" if path.startswith("/api/") else "page"
        return f"no {where} {path}; see /docs for the routes"
    return None


METHODS = ("DELETE", "GET", "PATCH", "POST", "PUT")


def _allowed(request: Request) -> str:
    """Every method some route takes at this path (Starlette's 405 names only the first such route's): the
    routes asked as the router asks them, one method at a time."""
    return ", ".join(m for m in METHODS if any(route.matches({**request.scope, "method": m})[0] == Match.FULL
                                               for route in request.app.router.routes))


async def _http_error(request: Request, exc: StarletteHTTPException) -> Response:
    if exc.status_code in (204, 304):
        return Response(status_code=exc.status_code, headers=exc.headers)
    cause = exc.__cause__
    if isinstance(cause, ClientDisconnect):
        return await _disconnected(request, cause)
    if exc.status_code == 400 and type(cause) in _UNREADABLE:
        return error_response(422, _UNREADABLE[type(cause)], errors=[
            {"loc": ["body"], "msg": _UNREADABLE[type(cause)], "type": "json_invalid"}])
    if exc.status_code == 405:
        allowed = _allowed(request)
        return error_response(405, f"{request.method} is not allowed on {request.url.path}; allowed: {allowed}",
                              {**(exc.headers or {}), "Allow": allowed})
    return error_response(exc.status_code, _unmatched(request, exc) or str(exc.detail), exc.headers)


async def _disconnected(request: Request, _exc: Exception) -> Response:
    """The client left before its body was complete (or lied in Content-Length): nobody reads the answer."""
    log.info("%s %s: the client disconnected before sending its whole body", request.method, request.url.path)
    return error_response(400, "the client disconnected before the body was complete")


async def _no_library(_request: Request, exc: LibraryNotFoundError) -> Response:
    return error_response(404, str(exc))


async def _unexpected(request: Request, exc: Exception) -> Response:
    """A bug: Starlette logs the traceback after this answer; the client gets the error model, not plain text."""
    return error_response(500, f"internal error in {request.method} {request.url.path}; the server log has the "
                               "details")


def install(app: FastAPI) -> None:
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(StarletteHTTPException, _http_error)
    app.add_exception_handler(ClientDisconnect, _disconnected)
    app.add_exception_handler(LibraryNotFoundError, _no_library)
    app.add_exception_handler(Exception, _unexpected)
