"""GET /api/domains: what can be tuned here, and with which methods."""

from __future__ import annotations

from fastapi import APIRouter

from rba.embed import REPRESENTATIONS
from server.admin_models import BUILTIN_VERSION
from server.catalog import attribute_methods
from server.deps import DbDep, ServicesDep
from server.models import DomainPublic, DomainsPublic, MethodPublic
from server.versions import active_version
from server.views import attributes_public

router = APIRouter(prefix="/api/domains", tags=["domains"])


@router.get("", response_model=DomainsPublic, summary="List domains, their attributes and available methods")
def list_domains(svc: ServicesDep, db: DbDep) -> DomainsPublic:
    domains = []
    for name in svc.catalog.names():
        domain = svc.catalog.domain(name)
        pairs = dict.fromkeys(svc.catalog.available(name))  # the shipped models, then the active version's
        active = active_version(db, name)
        if active != BUILTIN_VERSION:
            pairs |= dict.fromkeys(svc.catalog.available(name, active))
        available = [MethodPublic(method=m, rep=r) for m, r in pairs]
        domains.append(DomainPublic(name=name, attributes=attributes_public(domain), frame_rate=domain.frame_rate,
                                    available=available, missing=svc.catalog.missing_reason(name)))
    return DomainsPublic(domains=domains, methods=list(attribute_methods()), reps=list(REPRESENTATIONS))
