"""GET /api/domains: what can be tuned here, and with which methods."""

from __future__ import annotations

from fastapi import APIRouter

from server.api.deps import DbDep, ServicesDep
from server.common.errors import responses
from server.db.tables import DomainsPublic
from server.ops.views import domains_public

router = APIRouter(prefix="/api/domains", tags=["domains"], responses=responses(413))


@router.get("", response_model=DomainsPublic, summary="List domains, their attributes and available methods")
def list_domains(svc: ServicesDep, db: DbDep) -> DomainsPublic:
    return domains_public(svc, db)
