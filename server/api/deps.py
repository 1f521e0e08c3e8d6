"""Annotated dependencies: the app's services and one database session per request."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Request
from fastapi.dependencies.models import Dependant
from sqlmodel import Session

from server.common.errors import invalid
from server.runtime.services import Services


def get_services(request: Request) -> Services:
    return request.app.state.services


ServicesDep = Annotated[Services, Depends(get_services)]


def get_db(svc: ServicesDep) -> Iterator[Session]:
    with Session(svc.engine, expire_on_commit=False) as db:
        yield db


DbDep = Annotated[Session, Depends(get_db)]


def known_query(request: Request) -> None:
    """Unknown query parameters are a 422, as unknown body fields are: a misspelt ``?domian=`` must not be
    silently ignored (every API router gets this where the app includes it)."""
    route = request.scope.get("route")
    if route is None or not request.query_params:
        return
    known = _query_names(route.dependant)
    unknown = sorted(set(request.query_params) - known)
    if unknown:
        valid = ", ".join(sorted(known)) or "none"
        raise invalid(f"unknown query parameter(s) {', '.join(map(repr, unknown))}; valid: {valid}")


def _query_names(dependant: Dependant) -> set[str]:
    """The query parameters a route declares, its dependencies' included."""
    names = {p.alias for p in dependant.query_params}
    for sub in dependant.dependencies:
        names |= _query_names(sub)
    return names
