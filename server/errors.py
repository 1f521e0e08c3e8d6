"""Error bodies that say what is wrong: always ``{"detail": "<one readable sentence>"}``."""

from __future__ import annotations

from fastapi import FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse


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
    clean = [{"loc": list(e.get("loc", ())), "msg": str(e.get("msg")), "type": e.get("type")} for e in errors]
    return JSONResponse(status_code=422, content={"detail": "; ".join(messages) or "invalid request", "errors": clean})


def install(app: FastAPI) -> None:
    app.add_exception_handler(RequestValidationError, _validation_error)
