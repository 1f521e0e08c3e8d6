"""Session operations behind the routes: one database transaction per change.

The agent lives in the database as its JSON state; every request restores a fresh copy
from that state, so a session continues exactly after a restart and concurrent guesses
(prerendering) never touch the stored agent.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from urllib.parse import quote

from sqlalchemy.exc import IntegrityError
from sqlmodel import Session, select

from rba.domains import Domain
from rba.interact import SATISFIED, AttributeFeedback, Feedback
from rba.library import LibraryNotFoundError
from server.admin_models import BUILTIN_VERSION
from server.errors import conflict, invalid, not_found
from server.models import (
    AttributeChoice,
    AttributePublic,
    ClipPublic,
    FeedbackCreate,
    FeedbackEvent,
    FeedbackPublic,
    SessionCreate,
    SessionPublic,
    SessionStatus,
    TuningSession,
    utcnow,
)
from server.services import Services
from server.transitions import to_feedback
from server.versions import serving_version

log = logging.getLogger(__name__)


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


def _history(svc: Services, db: Session, s: TuningSession) -> list[FeedbackPublic]:
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
    except (FileNotFoundError, KeyError):  # its models were deleted: show the domain's own attributes
        specs = None
    return SessionPublic(id=s.id, domain=s.domain, method=s.method, rep=s.rep, model_version=s.model_version,
                         model_set=s.model_set, status=SessionStatus(s.status), step=s.step,
                         attributes=attributes_public(domain, svc, specs),
                         clip=clip_public(svc, s.domain, s.current_rollout_id),
                         history=_history(svc, db, s), created_at=s.created_at, updated_at=s.updated_at)


def load_session(db: Session, session_id: str) -> TuningSession:
    s = db.get(TuningSession, session_id)
    if s is None:
        raise not_found(f"no session {session_id!r}; create one with POST /api/sessions")
    return s


def create_session(svc: Services, db: Session, body: SessionCreate) -> SessionPublic:
    if body.domain in svc.catalog.names():
        version = serving_version(svc, db, body.domain, body.method, body.rep)
    else:
        version = BUILTIN_VERSION
    svc.catalog.check_available(body.domain, body.method, body.rep, version)
    ctx = svc.catalog.context(body.domain, body.method, body.rep, version)
    rollout_id, state = svc.transitions.first(ctx, body.method)
    s = TuningSession(domain=body.domain, method=body.method, rep=body.rep, model_version=ctx.model_version,
                      model_set=version, current_rollout_id=rollout_id, agent_state=state)
    db.add(s)
    db.commit()
    db.refresh(s)
    log.info("session %s: %s/%s/%s starts at %s", s.id, s.domain, s.method, s.rep, rollout_id)
    schedule_prerender(svc, s, None)
    return session_public(svc, db, s)


def _feedback(svc: Services, domain: Domain, valid: tuple[str, ...], body: FeedbackCreate) -> Feedback:
    if body.satisfied:
        return SATISFIED
    seen: set[str] = set()
    for c in body.feedback or ():
        svc.catalog.check_attribute(domain, c.attribute, valid)
        if c.attribute in seen:
            raise invalid(f"attribute {c.attribute!r} appears more than once; give each attribute at most once")
        seen.add(c.attribute)
    return to_feedback([(c.attribute, c.direction) for c in body.feedback or ()])


def give_feedback(svc: Services, db: Session, session_id: str, body: FeedbackCreate) -> SessionPublic:
    """Advance the session by one round; 409 if the step is stale or the session is closed."""
    with svc.session_locks(session_id):
        s = load_session(db, session_id)
        if s.status != SessionStatus.active:
            raise conflict(f"session {s.id} is {s.status}; it takes no more feedback (start a new session)")
        if body.step != s.step:
            raise conflict(f"step {body.step} is stale: session {s.id} is at step {s.step}; "
                           "GET the session and answer about the clip it shows now")
        domain = svc.catalog.domain(s.domain)
        ctx = svc.catalog.context(s.domain, s.method, s.rep, s.model_set)
        feedback = _feedback(svc, domain, ctx.attribute_names, body)
        if ctx.model_version != s.model_version:
            raise conflict(f"the served model changed since session {s.id} started ({s.model_version} -> "
                           f"{ctx.model_version}); start a new session")
        try:
            rollout_id, state = svc.transitions.advance(ctx, s.method, s.agent_state, feedback)
        except ValueError as exc:
            raise invalid(str(exc)) from exc
        stored = SATISFIED if feedback == SATISFIED else [c.model_dump() for c in body.feedback or ()]
        db.add(FeedbackEvent(session_id=s.id, step=s.step, feedback=stored, rollout_before=s.current_rollout_id,
                             rollout_after=rollout_id))
        s.step += 1
        s.current_rollout_id = rollout_id
        s.agent_state = state
        s.status = SessionStatus.satisfied.value if feedback == SATISFIED else SessionStatus.active.value
        s.updated_at = utcnow()
        db.add(s)
        try:
            db.commit()
        except IntegrityError as exc:  # another process answered this step first
            db.rollback()
            raise conflict(f"step {body.step} is stale: session {session_id} already moved on") from exc
        db.refresh(s)
    if s.status == SessionStatus.active:
        schedule_prerender(svc, s, None if feedback == SATISFIED else feedback)
    else:
        stop_prerender(svc, s.id)
    return session_public(svc, db, s)


def abandon_session(svc: Services, db: Session, session_id: str) -> SessionPublic:
    with svc.session_locks(session_id):
        s = load_session(db, session_id)
        if s.status != SessionStatus.active:
            raise conflict(f"session {s.id} is {s.status} already; only active sessions can be abandoned")
        s.status = SessionStatus.abandoned.value
        s.updated_at = utcnow()
        db.add(s)
        db.commit()
        db.refresh(s)
    stop_prerender(svc, s.id)
    return session_public(svc, db, s)


# -- prerendering ------------------------------------------------------------------------------

def candidate_order(attributes: tuple[str, ...], last: Feedback | None) -> list[AttributeFeedback]:
    """Every single feedback, most likely first: people often repeat their last answer."""
    options = [AttributeFeedback(a, d) for a in attributes for d in (1, -1)]
    if not last or last == SATISFIED:
        return options
    asked = {(fb.attribute, fb.direction) for fb in last}
    return sorted(options, key=lambda fb: (0 if (fb.attribute, fb.direction) in asked
                                           else 1 if any(fb.attribute == a for a, _ in asked) else 2))


def next_clips(svc: Services, key: tuple[str, str, str, str], state: dict, last: Feedback | None,
               stale: Callable[[], bool]) -> list[str]:
    """The rollout each possible single next feedback would show, most likely first (computed on copies).

    ``key`` is (domain, method, rep, model version).
    """
    ctx = svc.catalog.context(*key)
    method = key[1]
    nexts: list[str] = []
    for fb in candidate_order(ctx.attribute_names, last):
        if stale():
            break
        nexts.append(svc.transitions.advance(ctx, method, state, [fb])[0])
    return list(dict.fromkeys(nexts))


def render_clips(svc: Services, domain: str, rollout_ids: list[str], stale: Callable[[], bool]) -> None:
    lib = svc.catalog.library(domain)
    for rid in dict.fromkeys(rollout_ids):
        if stale():
            return
        svc.clips.get(svc.clips.key(lib, rid), lib, background=True)


def schedule_prerender(svc: Services, s: TuningSession, last: Feedback | None) -> None:
    """While the person watches: work out every possible next answer, then render the clips they would show.

    Two queues, each keeping only a session's newest job: thinking is quick and is what makes the next
    feedback request fast; rendering is slow and runs on one thread. The shown clip comes first in the
    render queue, though the page's own request usually renders it first (the cache renders a key once).
    """
    if svc.thinker is None or svc.renderer is None or not svc.settings.prerender:
        return
    session_id, step, shown = s.id, s.step, s.current_rollout_id
    key, state = (s.domain, s.method, s.rep, s.model_set), s.agent_state
    svc.prerendering[session_id] = step
    renderer = svc.renderer

    def stale() -> bool:
        return svc.stopping or svc.prerendering.get(session_id) != step

    def think() -> None:
        clips = [shown, *next_clips(svc, key, state, last, stale)]
        if not stale():  # most likely first, dealt round-robin to the render threads
            names = render_keys(svc, session_id)
            for w, name in enumerate(names):
                part = clips[w::len(names)]
                renderer.submit(name, lambda part=part: render_clips(svc, key[0], part, stale))

    svc.thinker.submit(session_id, think)


def render_keys(svc: Services, session_id: str) -> list[str]:
    """One background key per render thread, so a session's clips render in parallel."""
    return [f"{session_id}#{w}" for w in range(len(svc.renderer.workers))] if svc.renderer else []


def stop_prerender(svc: Services, session_id: str) -> None:
    svc.prerendering.pop(session_id, None)
    if svc.thinker is not None:
        svc.thinker.cancel(session_id)
    for name in render_keys(svc, session_id):
        svc.renderer.cancel(name)


def resume_prerender(svc: Services, s: TuningSession) -> None:
    """After a restart (or a missed step) nothing is queued for an active session: queue it."""
    if s.status == SessionStatus.active and svc.prerendering.get(s.id) != s.step:
        schedule_prerender(svc, s, None)


def warm_up(svc: Services) -> None:
    """Load every available model and render every first clip, then the clips one answer away from them.

    Every session starts in the same state, so this is the prerender of every new session's first step.
    """
    starts = []
    for name in svc.catalog.names():
        for method, rep in svc.catalog.available(name):
            if svc.stopping:
                return
            try:
                ctx = svc.catalog.context(name, method, rep)
                rollout_id, state = svc.transitions.first(ctx, method)
                render_clips(svc, name, [rollout_id], lambda: svc.stopping)
                starts.append(((name, method, rep, BUILTIN_VERSION), state))
            except Exception:
                log.exception("warm-up of %s/%s/%s failed", name, method, rep)
    if svc.settings.prerender:
        for key, state in starts:
            render_clips(svc, key[0], next_clips(svc, key, state, None, lambda: svc.stopping), lambda: svc.stopping)
    if svc.settings.prerender_library:
        for name in dict.fromkeys(key[0] for key, _ in starts):
            render_clips(svc, name, list(svc.catalog.library(name).ids), lambda: svc.stopping)
