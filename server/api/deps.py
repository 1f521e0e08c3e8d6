"""Annotated dependencies: the app's services and one database session per request."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Request
from fastapi.dependencies.models import Dependant
from fastapi.dependencies.utils import field_annotation_is_sequence
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
    silently ignored; nor may a one-value parameter given twice (``?domain=a&domain=b`` would quietly mean
    ``b``). Every API router gets this where the app includes it."""
    route = request.scope.get("route")
    if route is None or not request.query_params:
        return
    declared = _query_params(route.dependant)
    unknown = sorted(set(request.query_params) - set(declared))
    if unknown:
        valid = ", ".join(sorted(declared)) or "none"
        raise invalid(f"unknown query parameter(s) {', '.join(map(repr, unknown))}; valid: {valid}")
    repeated = sorted(name for name, many in declared.items()
                      if not many and len(request.query_params.getlist(name)) > 1)
    if repeated:
        raise invalid(f"query parameter(s) {', '.join(map(repr, repeated))} given more than once; "
                      "each may be given once")


def _query_params(dependant: Dependant) -> dict[str, bool]:
    """The query parameters a route declares, its dependencies' included: name -> whether it takes many values."""
    names = {p.alias: field_annotation_is_sequence(p.field_info.annotation) for p in dependant.query_params}
    for sub in dependant.dependencies:
        names |= _query_params(sub)
    return names
