"""Admin labelling: attributes added to a domain, labels made on the admin page, clip pairs to label."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query

from server.api.auth import ADMIN_ERRORS, require_admin
from server.api.deps import DbDep, ServicesDep
from server.common.errors import responses
from server.db.admin_tables import (
    AttributeAddedPublic,
    AttributeCreate,
    AttributesPublic,
    ClipsToLabelPublic,
    LabelCreate,
    LabelPublic,
    LabelRecord,
)
from server.db.tables import DomainName
from server.ops import label_admin

router = APIRouter(prefix="/api/admin", tags=["admin"], dependencies=[Depends(require_admin)],
                   responses=responses(*ADMIN_ERRORS))


@router.get("/attributes", response_model=AttributesPublic,
            summary="A domain's attributes: its own and those admins added")
def list_attributes(domain: DomainName, svc: ServicesDep, db: DbDep) -> AttributesPublic:
    return label_admin.list_attributes(svc, db, domain)


@router.post("/attributes", status_code=201, response_model=AttributeAddedPublic,
             responses=responses(409, said={409: "the domain has this attribute already"}),
             summary="Add an attribute (name + one-sentence description)")
def create_attribute(body: AttributeCreate, svc: ServicesDep, db: DbDep) -> AttributeAddedPublic:
    return label_admin.add_attribute(svc, db, body.domain, body.name, body.description)


@router.post("/labels", status_code=201, response_model=LabelPublic,
             responses=responses(404, said={404: "the domain has no skill library to label"}),
             summary="Save one label (an ordering, a comparison or a local change) as it is made")
def create_label(body: LabelCreate, svc: ServicesDep, db: DbDep) -> LabelRecord:
    return label_admin.add_label(svc, db, body)


@router.get("/labels", response_model=list[LabelPublic], summary="Labels made on the admin page")
def list_labels(domain: DomainName, db: DbDep, attribute: str | None = None,
                limit: int = Query(default=500, ge=1, le=10_000)) -> list[LabelRecord]:
    return label_admin.list_labels(db, domain, attribute, limit)


@router.get("/pairs", response_model=ClipsToLabelPublic, responses=responses(404, said={404: "no serve library"}),
            summary="Clips to label next: serve rollouts, with their clip URLs")
def next_clips(domain: DomainName, svc: ServicesDep, db: DbDep, size: int = Query(default=2, ge=2, le=8),
               anchor: bool = False, seed: int | None = Query(default=None, ge=0)) -> ClipsToLabelPublic:
    """Clips to label next (``server.ops.label_admin.clips_to_label``)."""
    return label_admin.clips_to_label(svc, db, domain, size, anchor, seed)
