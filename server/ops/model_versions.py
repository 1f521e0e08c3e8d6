"""Which model version serves what: new sessions get the domain's active version, running ones keep theirs.

Import direction: above ``server.runtime.services`` (it reads the catalog through it); the sessions and
the admin routes import it, it imports neither.
"""

from __future__ import annotations

import logging
from typing import Any

from sqlmodel import Session, delete, select

from rba.core.methods import UnknownMethodError, get_method
from rba.domains import Domain
from server.common.errors import conflict, invalid, not_found
from server.db.admin_tables import BUILTIN_VERSION, ActiveModel, ModelVersion, VersionPublic
from server.db.engine import dialect_insert
from server.db.tables import utcnow
from server.runtime.services import Services

log = logging.getLogger(__name__)


def active_version(db: Session, domain: str) -> str:
    """Read afresh, never from the session's identity map: activations write the row with core statements."""
    version = db.exec(select(ActiveModel.version).where(ActiveModel.domain == domain)).first()
    return version if version is not None else BUILTIN_VERSION


def serving_version(svc: Services, db: Session, domain: str, method: str, rep: str) -> str:
    """The active version if it has models for (method, rep), else the built-in models."""
    version = active_version(db, domain)
    if version != BUILTIN_VERSION and (method, rep) not in svc.catalog.available(domain, version):
        return BUILTIN_VERSION
    return version


# Held-out numbers of a model card where higher is better: (model kind, keys into the card's held_out, label).
HEADLINES = (("global_reward", ("argmax_within_epsilon",), "argmax within ε"),
             ("global_reward", ("argmax_within_high_precision_epsilon",), "argmax within fine ε"),
             ("local_reward", ("argmax_over_serve", "useful_edit_rate"), "useful edit rate"),
             ("local_reward", ("target_vs_negative",), "target vs negative"))


def _dig(held_out: dict, keys: tuple[str, ...]) -> Any:
    for key in keys:
        held_out = held_out.get(key) if isinstance(held_out, dict) else None
    return held_out


def _pair_accuracies(held_out: dict) -> dict[str, float | None]:
    """ζσ's share of held-out pairs ordered right, per attribute; None for one with no held-out pairs (untested)."""
    out: dict[str, float | None] = {}
    for name, m in held_out.items():
        if isinstance(m, dict) and "pairwise_accuracy" in m:
            out[f"pair accuracy · {name}"] = m["pairwise_accuracy"]
        elif isinstance(m, dict) and "held_out_pairs" in m:
            out[f"pair accuracy · {name}"] = m.get("held_out_pair_accuracy") if m["held_out_pairs"] else None
    return out


def scores(svc: Services, domain: str, method: str, rep: str, version: str) -> dict[str, float | None]:
    """The headline held-out numbers of ``version``'s (method, rep) models, read from their cards."""
    try:
        kinds = get_method(method).model_kinds
    except UnknownMethodError:
        return {}
    out: dict[str, float | None] = {}
    for kind in kinds:
        held_out = (svc.catalog.card(domain, kind, rep, version) or {}).get("held_out") or {}
        out |= _pair_accuracies(held_out)
        for of, keys, label in HEADLINES:
            value = _dig(held_out, keys) if of == kind else None
            if isinstance(value, int | float):
                out[label] = float(value)
    return out


def concerns(new: dict[str, float | None], old: dict[str, float | None], old_version: str) -> list[str]:
    """Why activating ``new`` needs a second thought: numbers below ``old``'s, or untested attributes."""
    out = [f"{k}: untested (no held-out pairs)" for k, v in new.items() if v is None]
    out += [f"{k}: {v:.3f}, below {old[k]:.3f} of {old_version}" for k, v in new.items()
            if v is not None and isinstance(old.get(k), float) and v < old[k]]
    return out if new else ["no held-out numbers to judge it by"]


def _compared(svc: Services, db: Session, v: VersionPublic) -> VersionPublic:
    """``v`` with its held-out numbers beside those of what new sessions of its (method, rep) get now."""
    v.scores = scores(svc, v.domain, v.method, v.rep, v.version)
    baseline = serving_version(svc, db, v.domain, v.method, v.rep)
    if baseline != v.version:
        v.baseline, v.baseline_scores = baseline, scores(svc, v.domain, v.method, v.rep, baseline)
        v.concerns = concerns(v.scores, v.baseline_scores, baseline)
    return v


def _builtin_public(domain: Domain, method: str, rep: str, active: bool) -> VersionPublic:
    return VersionPublic(version=BUILTIN_VERSION, domain=domain.name, method=method, rep=rep,
                         attributes=list(domain.attribute_names), held_out={}, active=active, created_at=None)


def list_versions(svc: Services, db: Session, domain: str) -> list[VersionPublic]:
    """The built-in models (if any are available), then every version jobs made, oldest first; each with its
    held-out numbers and, unless it serves already, those of what it would replace."""
    d = svc.catalog.domain(domain)
    active = active_version(db, d.name)
    out = [_builtin_public(d, m, r, active == BUILTIN_VERSION) for m, r in svc.catalog.available(d.name)[:1]]
    rows = db.exec(select(ModelVersion).where(ModelVersion.domain == d.name).order_by(ModelVersion.created_at)).all()
    out += [VersionPublic.model_validate(r, update={"active": r.version == active}) for r in rows]
    return [_compared(svc, db, v) for v in out]


def activate_builtin(svc: Services, db: Session, domain: str | None) -> VersionPublic:
    """Serve the shipped models to ``domain``'s new sessions again."""
    if not domain:
        raise invalid("say which domain goes back to its built-in models: "
                      "POST /api/admin/models/builtin/activate?domain=<name>")
    d = svc.catalog.domain(domain)
    before = active_version(db, d.name)
    db.exec(delete(ActiveModel).where(ActiveModel.domain == d.name))  # a no-op if another request deleted it first
    db.commit()
    log.info("%s: new sessions get the built-in models again (was %s)", d.name, before)
    return _builtin_public(d, "global", "onehot", True)


def activate_version(svc: Services, db: Session, version: str, domain: str | None) -> VersionPublic:
    """Serve ``version`` to its domain's new sessions; 404 if unknown, 409 if its files are missing."""
    if version == BUILTIN_VERSION:
        return activate_builtin(svc, db, domain)
    row = db.get(ModelVersion, version)
    if row is None:
        have = db.exec(select(ModelVersion.version)).all()
        raise not_found(f"no model version {version!r}; versions: {', '.join(have) or 'none yet'}, builtin")
    if domain is not None and domain != row.domain:
        raise invalid(f"version {version} is {row.domain}'s, not {domain}'s; leave domain out (a version names its "
                      "own) or give its own")
    if (row.method, row.rep) not in svc.catalog.available(row.domain, row.version):
        raise conflict(f"the files of version {version} are missing under {svc.catalog.models(version).root}; "
                       "it cannot be served")
    before = active_version(db, row.domain)
    # One upsert: activations at once each succeed (the last one wins), none trips over the other's new row.
    values = {"domain": row.domain, "version": version, "updated_at": utcnow()}
    db.exec(dialect_insert(db, ActiveModel).values(**values)
            .on_conflict_do_update(index_elements=["domain"], set_=values))
    db.commit()
    log.info("%s: new sessions get version %s (%s/%s; was %s)", row.domain, version, row.method, row.rep, before)
    return VersionPublic.model_validate(row, update={"active": True})
