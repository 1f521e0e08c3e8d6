"""Admin labelling: attributes added to a domain, labels made on the admin page, clip pairs to label."""

from __future__ import annotations

import random

from fastapi import APIRouter, Depends, Query
from sqlmodel import select

from server import labelling
from server.admin_models import AttributeCreate, LabelCreate, LabelPublic, LabelRecord
from server.auth import require_admin
from server.deps import DbDep, ServicesDep
from server.sessions import clip_url

router = APIRouter(prefix="/api/admin", tags=["admin"], dependencies=[Depends(require_admin)],
                   responses={401: {"description": "missing or wrong admin token"},
                              503: {"description": "admin disabled (RBA_ADMIN_TOKEN unset)"}})


@router.get("/attributes", summary="A domain's attributes: its own and those admins added")
def list_attributes(domain: str, svc: ServicesDep, db: DbDep) -> dict:
    d = svc.catalog.domain(domain)
    own = [{"name": a.name, "description": a.description, "added": False} for a in d.attributes]
    added = [{"name": n, "description": desc, "added": True}
             for n, desc in labelling.declared_attributes(db, d.name).items()]
    return {"domain": d.name, "attributes": own + added}


@router.post("/attributes", status_code=201, summary="Add an attribute (name + one-sentence description)")
def create_attribute(body: AttributeCreate, svc: ServicesDep, db: DbDep) -> dict:
    row = labelling.add_attribute(svc, db, body.domain, body.name, body.description)
    return {"domain": row.domain, "name": row.name, "description": row.description, "added": True}


@router.post("/labels", status_code=201, response_model=LabelPublic,
             summary="Save one label (an ordering, a comparison or a local change) as it is made")
def create_label(body: LabelCreate, svc: ServicesDep, db: DbDep) -> LabelRecord:
    return labelling.add_label(svc, db, body)


@router.get("/labels", response_model=list[LabelPublic], summary="Labels made on the admin page")
def list_labels(domain: str, db: DbDep, attribute: str | None = None,
                limit: int = Query(default=500, ge=1, le=10_000)) -> list[LabelRecord]:
    q = select(LabelRecord).where(LabelRecord.domain == domain)
    if attribute:
        q = q.where(LabelRecord.attribute == attribute)
    return list(db.exec(q.order_by(LabelRecord.id.desc()).limit(limit)).all())  # type: ignore[union-attr]


@router.get("/pairs", summary="Clips to label next: serve rollouts, with their clip URLs")
def next_clips(domain: str, svc: ServicesDep, db: DbDep, size: int = Query(default=2, ge=2, le=8),
               anchor: bool = False, seed: int | None = Query(default=None, ge=0)) -> dict:
    """``size`` random serve clips (seeded by ``seed``, else by how many labels exist: a reload shows the same).

    With ``anchor``, the first clip is an anchor and the others its nearest neighbours in the
    library's measured attributes: candidates for "the same, but a little more α".
    """
    d = svc.catalog.domain(domain)
    lib = svc.catalog.library(d.name)
    if seed is None:
        seed = len(db.exec(select(LabelRecord.id).where(LabelRecord.domain == d.name)).all())
    rng = random.Random(seed)
    if anchor:
        a = rng.randrange(len(lib))
        span = lib.proxies.max(0) - lib.proxies.min(0) + 1e-9
        dist = (((lib.proxies - lib.proxies[a]) / span) ** 2).sum(1)
        picks = [a, *[int(i) for i in dist.argsort()[1:size]]]
    else:
        picks = rng.sample(range(len(lib)), size)
    ids = [lib.ids[i] for i in picks]
    return {"domain": d.name, "clips": [{"rollout_id": r, "url": clip_url(d.name, r)} for r in ids]}
