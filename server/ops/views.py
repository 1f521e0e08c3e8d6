"""What the public API shows of domains, sessions and clips (read-only, no transactions).

Import direction: above ``server.runtime.services`` (it reads the catalog and the clip cache through it),
``server.ops.model_versions`` and ``server.ops.session_searches``, below ``server.ops.session_steps`` and the routes; it
never imports either.
"""

from __future__ import annotations

import copy
import math
from urllib.parse import quote

import numpy as np
from sqlmodel import Session, select

from rba.core.methods import REPS, generating_methods, get_method, trainable
from rba.data.library import LibraryNotFoundError
from rba.domains import Domain
from rba.interact import SATISFIED, restore_agent
from rba.interact.free_text import examples
from rba.learn.embed import REPRESENTATIONS
from server.common.errors import not_found
from server.db.admin_tables import BUILTIN_VERSION, ModelVersion
from server.db.tables import (
    AttributeChoice,
    AttributePublic,
    ClipPublic,
    ClipStatusPublic,
    DomainPublic,
    DomainsPublic,
    FeedbackEvent,
    FeedbackPublic,
    MethodPublic,
    ReadingPublic,
    SessionPublic,
    SessionStatus,
    TargetRange,
    TrainablePublic,
    TuningSession,
    attribute_methods,
)
from server.ops import session_searches
from server.ops.model_versions import active_version
from server.runtime.clip_sources import UnknownRollout
from server.runtime.services import Services


def clip_url(domain: str, rollout_id: str) -> str:
    return f"/api/clips/{quote(domain)}/{quote(rollout_id)}.mp4"


def clip_data_url(domain: Domain, rollout_id: str) -> str | None:
    """The clip's per-frame data the page draws itself (docs/architecture.md, clip data); None for a domain whose
    clips are MP4s only."""
    return f"/api/clips/{quote(domain.name)}/{quote(rollout_id)}.json" if domain.draws_clips else None


def clip_public(svc: Services, db: Session, domain: str, rollout_id: str) -> ClipPublic:
    """A clip's URLs (MP4, and data where the domain has it), its measured attribute values and whether it is
    rendered already."""
    url = clip_url(domain, rollout_id)
    data_url = clip_data_url(svc.catalog.domain(domain), rollout_id)
    try:
        clip = svc.sources.resolve(db, domain, rollout_id)
    except UnknownRollout as exc:  # the library was rebuilt since: nothing to measure
        return ClipPublic(rollout_id=rollout_id, url=url, data_url=data_url, measured={}, ready=False,
                          generated=exc.generated)
    return ClipPublic(rollout_id=rollout_id, url=url, data_url=data_url, measured=clip.measured,
                      ready=svc.clips.cached(clip.key), generated=clip.generated)


def attributes_public(domain: Domain, svc: Services | None = None,
                      specs: list[dict] | None = None) -> list[AttributePublic]:
    """The domain's attributes (or ``specs`` from a model card); with ``svc``, also measured ranges."""
    ranges: dict[str, tuple[float, float]] = {}
    fine: dict[str, float] = {}  # the high-precision ε of the domain's own attributes
    if svc is not None:
        try:
            lib = svc.catalog.library(domain.name)
            lo, hi = lib.proxies.min(0), lib.proxies.max(0)
            ranges = {a: (float(lo[j]), float(hi[j])) for j, a in enumerate(lib.attribute_names)}
            if lib.attribute_names == domain.attribute_names:
                fine = dict(zip(lib.attribute_names, domain.epsilons(lib.proxies, "high").tolist(), strict=True))
        except LibraryNotFoundError:
            pass
    specs = specs if specs is not None else [{"name": a.name, "description": a.description, "unit": a.unit}
                                             for a in domain.attributes]
    known = {a.name: a for a in domain.attributes}
    out = []
    for a in specs:
        low, high = ranges.get(a["name"], (None, None))
        spec = known.get(a["name"])  # an attribute admins added has no spec (nor ε): decimals from its range
        reading = spec.reading if spec is not None else None
        eps = fine.get(a["name"])
        out.append(AttributePublic(
            name=a["name"], description=a["description"], unit=a["unit"], low=low, high=high,
            decimals=epsilon_decimals(eps) if eps else range_decimals(low, high),
            reading=ReadingPublic(label=reading.label, sign=reading.sign, note=reading.note) if reading else None))
    return out


def epsilon_decimals(eps: float) -> int:
    """Decimals that show a change of ``eps`` (the high-precision ε: snake speed needs 3, not 2)."""
    return max(0, min(4, math.ceil(-math.log10(eps))))


def range_decimals(low: float | None, high: float | None) -> int:
    """Decimals that tell apart a fiftieth of the range (2 when the range is unknown)."""
    if low is None or high is None or high <= low:
        return 2
    return max(0, min(4, math.ceil(-math.log10((high - low) / 50))))


def target_public(svc: Services, s: TuningSession) -> list[TargetRange] | None:
    """The agent's belief about the target, in measured values: its ranks mapped onto the serve library's proxies."""
    try:
        ctx = svc.catalog.context(s.domain, s.method, s.rep, s.model_set)
        ranks = restore_agent(copy.deepcopy(s.agent_state), ctx).target_ranks()
        lib = svc.catalog.library(s.domain)
    except (FileNotFoundError, KeyError, ValueError, LibraryNotFoundError):  # models gone: no belief to show
        return None
    if ranks is None:
        return None
    out = []
    for name, (lo, hi) in ranks.items():
        if name not in lib.attribute_names:  # an admin-added attribute has no proxy to map onto
            continue
        values = lib.proxies[:, lib.attribute_names.index(name)]
        low, high = np.quantile(values, [lo, hi])
        out.append(TargetRange(attribute=name, low=float(low), high=float(high)))
    return out


def clip_status(svc: Services, db: Session, domain: str, rollout_id: str) -> ClipStatusPublic:
    """How far the render of a clip is; 404 for an unknown domain or rollout."""
    svc.catalog.domain(domain)
    try:
        key = svc.sources.resolve(db, domain, rollout_id).key
    except UnknownRollout as exc:
        raise not_found(str(exc)) from exc
    st = svc.clips.status(key)
    return ClipStatusPublic(rollout_id=key.rollout_id, state=st.state, elapsed_seconds=st.elapsed,
                            typical_seconds=st.typical)


def history_public(svc: Services, db: Session, s: TuningSession) -> list[FeedbackPublic]:
    """The session's rounds of feedback, oldest first."""
    events = db.exec(select(FeedbackEvent).where(FeedbackEvent.session_id == s.id).order_by(FeedbackEvent.step)).all()
    out = []
    for e in events:
        satisfied = e.feedback == SATISFIED
        choices = None if satisfied else [AttributeChoice(**c) for c in e.feedback]
        out.append(FeedbackPublic(step=e.step, feedback=choices, satisfied=satisfied,
                                  rollout_before=clip_public(svc, db, s.domain, e.rollout_before),
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
                         clip=clip_public(svc, db, s.domain, s.current_rollout_id),
                         history=history_public(svc, db, s), target=target_public(svc, s),
                         generate=s.generate, generation=session_searches.current(svc, s),
                         created_at=s.created_at, updated_at=s.updated_at)


def method_public(method: str, rep: str) -> MethodPublic:
    """A method/rep pair as the picker shows it: its label, its one line, and whether it is a research variant."""
    m = get_method(method)
    return MethodPublic(method=method, rep=rep, label=m.label, description=m.describe(rep),
                        advanced=REPS[rep].research)


def domains_public(svc: Services, db: Session) -> DomainsPublic:
    """Every domain with its attributes and the method/rep pairs new sessions can get."""
    domains = []
    for name in svc.catalog.names():
        domain = svc.catalog.domain(name)
        pairs = dict.fromkeys(svc.catalog.available(name))  # the shipped models, then the active version's
        active = active_version(db, name)
        specs = None  # the domain's own attributes, unless the models the active version trained learnt others
        if active != BUILTIN_VERSION and (served := svc.catalog.available(name, active)):
            pairs |= dict.fromkeys(served)
            row = db.get(ModelVersion, active)  # its other models were carried over (``Store.carry_over``)
            trained = (row.method, row.rep) if row is not None else served[0]
            specs = svc.catalog.card_attributes(name, *trained, active)
        available = [method_public(m, r) for m, r in pairs]
        domains.append(DomainPublic(name=name, attributes=attributes_public(domain, specs=specs),
                                    frame_rate=domain.frame_rate, states=domain.states_view,
                                    examples=examples(domain),
                                    description=domain.summary, advanced=domain.states_view != "features",
                                    available=available, missing=svc.catalog.missing_reason(name)))
    return DomainsPublic(domains=domains, methods=list(attribute_methods()), reps=list(REPRESENTATIONS),
                         trainable=[TrainablePublic(method=m.name, label=m.label, presets=list(m.presets))
                                    for m in trainable()],
                         generate=svc.settings.generate, generating=list(generating_methods()))
