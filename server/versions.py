"""Which model version serves what: new sessions get the domain's active version, running ones keep theirs.

Import direction: above ``server.services`` (it reads the catalog through it); the sessions and
the admin routes import it, it imports neither.
"""

from __future__ import annotations

from sqlmodel import Session, select

from rba.domains import Domain
from server.admin_models import BUILTIN_VERSION, ActiveModel, ModelVersion, VersionPublic
from server.errors import conflict, invalid, not_found
from server.models import utcnow
from server.services import Services


def active_version(db: Session, domain: str) -> str:
    row = db.get(ActiveModel, domain)
    return row.version if row is not None else BUILTIN_VERSION


def serving_version(svc: Services, db: Session, domain: str, method: str, rep: str) -> str:
    """The active version if it has models for (method, rep), else the built-in models."""
    version = active_version(db, domain)
    if version != BUILTIN_VERSION and (method, rep) not in svc.catalog.available(domain, version):
        return BUILTIN_VERSION
    return version


def _builtin_public(domain: Domain, method: str, rep: str, active: bool) -> VersionPublic:
    return VersionPublic(version=BUILTIN_VERSION, domain=domain.name, method=method, rep=rep,
                         attributes=list(domain.attribute_names), held_out={}, active=active, created_at=None)


def list_versions(svc: Services, db: Session, domain: str) -> list[VersionPublic]:
    """The built-in models (if any are available), then every version jobs made, oldest first."""
    d = svc.catalog.domain(domain)
    active = active_version(db, d.name)
    out = [_builtin_public(d, m, r, active == BUILTIN_VERSION) for m, r in svc.catalog.available(d.name)[:1]]
    rows = db.exec(select(ModelVersion).where(ModelVersion.domain == d.name).order_by(ModelVersion.created_at)).all()
    return out + [VersionPublic.model_validate(r, update={"active": r.version == active}) for r in rows]


def activate_builtin(svc: Services, db: Session, domain: str | None) -> VersionPublic:
    """Serve the shipped models to ``domain``'s new sessions again."""
    if not domain:
        raise invalid("say which domain goes back to its built-in models: "
                      "POST /api/admin/models/builtin/activate?domain=<name>")
    d = svc.catalog.domain(domain)
    current = db.get(ActiveModel, d.name)
    if current is not None:
        db.delete(current)
        db.commit()
    return _builtin_public(d, "global", "onehot", True)


def activate_version(svc: Services, db: Session, version: str, domain: str | None) -> VersionPublic:
    """Serve ``version`` to its domain's new sessions; 404 if unknown, 409 if its files are missing."""
    if version == BUILTIN_VERSION:
        return activate_builtin(svc, db, domain)
    row = db.get(ModelVersion, version)
    if row is None:
        have = db.exec(select(ModelVersion.version)).all()
        raise not_found(f"no model version {version!r}; versions: {', '.join(have) or 'none yet'}, builtin")
    if (row.method, row.rep) not in svc.catalog.available(row.domain, row.version):
        raise conflict(f"the files of version {version} are missing under {svc.catalog.models(version).root}; "
                       "it cannot be served")
    current = db.get(ActiveModel, row.domain) or ActiveModel(domain=row.domain, version=version)
    current.version, current.updated_at = version, utcnow()
    db.add(current)
    db.commit()
    return VersionPublic.model_validate(row, update={"active": True})
