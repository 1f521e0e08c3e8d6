"""What the public API shows of domains, sessions and clips (read-only, no transactions).

Import direction: above ``server.services`` (it reads the catalog and the clip cache through it)
and ``server.versions``, below ``server.sessions`` and the routes; it never imports either.
"""

from __future__ import annotations

from urllib.parse import quote

from sqlmodel import Session, select

from rba.domains import Domain
from rba.embed import REPRESENTATIONS
from rba.interact import SATISFIED
from rba.library import LibraryNotFoundError
from rba.methods import trainable
from server.admin_models import BUILTIN_VERSION
from server.models import (
    AttributeChoice,
    AttributePublic,
    ClipPublic,
    DomainPublic,
    DomainsPublic,
    FeedbackEvent,
    FeedbackPublic,
    MethodPublic,
    SessionPublic,
    SessionStatus,
    TrainablePublic,
    TuningSession,
    attribute_methods,
)
from server.services import Services
from server.versions import active_version


def clip_url(domain: str, rollout_id: str) -> str:
    return f"/api/clips/{quote(domain)}/{quote(rollout_id)}.mp4"


def clip_public(svc: Services, domain: str, rollout_id: str) -> ClipPublic:
    """A clip's URL, its measured attribute values and whether it is rendered already."""
    try:
        lib = svc.catalog.library(domain)
        i = lib.index_of(rollout_id)
    except (LibraryNotFoundError, KeyError):  # the library was rebuilt since: nothing to measure
        return ClipPublic(rollout_id=rollout_id, url=clip_url(domain, rollout_id), measured={}, ready=False)
    ready = svc.clips.cached(svc.clips.key(lib, rollout_id))
    return ClipPublic(rollout_id=rollout_id, url=clip_url(domain, rollout_id), measured=lib.proxies_of(i), ready=ready)


def attributes_public(domain: Domain, svc: Services | None = None,
                      specs: list[dict] | None = None) -> list[AttributePublic]:
    """The domain's attributes (or ``specs`` from a model card); with ``svc``, also measured ranges."""
    ranges: dict[str, tuple[float, float]] = {}
    if svc is not None:
        try:
            lib = svc.catalog.library(domain.name)
            lo, hi = lib.proxies.min(0), lib.proxies.max(0)
            ranges = {a: (float(lo[j]), float(hi[j])) for j, a in enumerate(lib.attribute_names)}
        except LibraryNotFoundError:
            pass
    specs = specs if specs is not None else [{"name": a.name, "description": a.description, "unit": a.unit}
                                             for a in domain.attributes]
    out = []
    for a in specs:
        low, high = ranges.get(a["name"], (None, None))
        out.append(AttributePublic(name=a["name"], description=a["description"], unit=a["unit"], low=low, high=high))
    return out


def history_public(svc: Services, db: Session, s: TuningSession) -> list[FeedbackPublic]:
    """The session's rounds of feedback, oldest first."""
    events = db.exec(select(FeedbackEvent).where(FeedbackEvent.session_id == s.id).order_by(FeedbackEvent.step)).all()
    out = []
    for e in events:
        satisfied = e.feedback == SATISFIED
        choices = None if satisfied else [AttributeChoice(**c) for c in e.feedback]
        out.append(FeedbackPublic(step=e.step, feedback=choices, satisfied=satisfied,
                                  rollout_before=clip_public(svc, s.domain, e.rollout_before),
                                  rollout_after=e.rollout_after, created_at=e.created_at))
    return out


def session_public(svc: Services, db: Session, s: TuningSession) -> SessionPublic:
    domain = svc.catalog.domain(s.domain)
    try:
        specs = svc.catalog.card_attributes(s.domain, s.method, s.rep, s.model_set)
    except (FileNotFoundError, KeyError, ValueError):  # its models (or method) are gone: the domain's own attributes
        specs = None
    return SessionPublic(id=s.id, domain=s.domain, method=s.method, rep=s.rep, model_version=s.model_version,
                         model_set=s.model_set, status=SessionStatus(s.status), step=s.step,
                         attributes=attributes_public(domain, svc, specs),
                         clip=clip_public(svc, s.domain, s.current_rollout_id),
                         history=history_public(svc, db, s), created_at=s.created_at, updated_at=s.updated_at)


def domains_public(svc: Services, db: Session) -> DomainsPublic:
    """Every domain with its attributes and the method/rep pairs new sessions can get."""
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
    return DomainsPublic(domains=domains, methods=list(attribute_methods()), reps=list(REPRESENTATIONS),
                         trainable=[TrainablePublic(method=m.name, label=m.label, presets=list(m.presets))
                                    for m in trainable()])
