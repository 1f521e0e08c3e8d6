"""Session transactions behind the routes: create, answer, abandon; one database transaction per change.

The agent lives in the database as its JSON state; every request restores a fresh copy
from that state, so a session continues exactly after a restart and concurrent guesses
(prerendering) never touch the stored agent.

Import direction: above ``server.services``, ``server.views``, ``server.prerender``,
``server.feedback`` and ``server.versions``; only the routes import it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from sqlalchemy import update
from sqlalchemy.exc import IntegrityError
from sqlmodel import Session

from rba.interact import SATISFIED, Feedback
from server.errors import conflict, invalid, not_found
from server.feedback import parse_feedback
from server.models import (
    FeedbackCreate,
    FeedbackEvent,
    SessionCreate,
    SessionPublic,
    SessionStatus,
    TuningSession,
    utcnow,
)
from server.prerender import schedule_prerender, stop_prerender
from server.services import Services
from server.versions import serving_version
from server.views import session_public

log = logging.getLogger(__name__)


def load_session(db: Session, session_id: str) -> TuningSession:
    s = db.get(TuningSession, session_id)
    if s is None:
        raise not_found(f"no session {session_id!r}; create one with POST /api/sessions")
    return s


def create_session(svc: Services, db: Session, body: SessionCreate) -> SessionPublic:
    version = serving_version(svc, db, body.domain, body.method, body.rep)
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


def _closed(s: TuningSession) -> str:
    return f"session {s.id} is {s.status}; it takes no more feedback (start a new session)"


def _answerable(db: Session, session_id: str, body: FeedbackCreate) -> TuningSession:
    """The session, if it is active, at ``body.step`` and showing ``body.clip`` (when given); 409 otherwise."""
    s = load_session(db, session_id)
    if s.status != SessionStatus.active:
        raise conflict(_closed(s))
    if body.clip is not None and body.clip != s.current_rollout_id:
        raise conflict(f"the answer is about clip {body.clip} but session {s.id} now shows clip "
                       f"{s.current_rollout_id}; watch that clip and answer about it")
    if body.step != s.step:
        raise conflict(f"step {body.step} is stale: session {s.id} is at step {s.step}; "
                       "GET the session and answer about the clip it shows now")
    return s


class _Lost(Exception):
    """The session was no longer where this request read it."""


def _move(db: Session, s: TuningSession, at_step: int | None, lost: Callable[[TuningSession], str],
          **values) -> None:
    """Set ``values`` on the session only if it is still active (and at ``at_step``, unless None), then commit.

    ``session_locks`` serialise one process's requests; this compare-and-set makes a request that lost
    a race with another replica a 409 too (``lost(session as it is now)``), never a lost update.
    """
    where = [TuningSession.id == s.id, TuningSession.status == SessionStatus.active.value]
    if at_step is not None:
        where.append(TuningSession.step == at_step)
    try:
        moved = db.exec(update(TuningSession).where(*where).values(updated_at=utcnow(), **values))
        if moved.rowcount != 1:
            raise _Lost
        db.commit()
    except (IntegrityError, _Lost) as exc:  # the feedback row is unique per (session, step) as well
        db.rollback()
        db.refresh(s)
        raise conflict(lost(s)) from exc
    db.refresh(s)


def _record_step(db: Session, s: TuningSession, body: FeedbackCreate, feedback: Feedback, rollout_id: str,
                 state: dict) -> None:
    """Store the round and move the session on, in one transaction; 409 if another request answered first."""
    stored = SATISFIED if feedback == SATISFIED else [c.model_dump() for c in body.feedback or ()]
    db.add(FeedbackEvent(session_id=s.id, step=s.step, feedback=stored, rollout_before=s.current_rollout_id,
                         rollout_after=rollout_id))
    status = SessionStatus.satisfied.value if feedback == SATISFIED else SessionStatus.active.value

    def lost(now: TuningSession) -> str:
        if now.status != SessionStatus.active:
            return _closed(now)
        return f"step {body.step} is stale: session {now.id} already moved on"

    _move(db, s, s.step, lost, step=s.step + 1, current_rollout_id=rollout_id, agent_state=state, status=status)


def give_feedback(svc: Services, db: Session, session_id: str, body: FeedbackCreate) -> SessionPublic:
    """Advance the session by one round; 409 if the step is stale or the session is closed."""
    with svc.session_locks(session_id):
        s = _answerable(db, session_id, body)
        domain = svc.catalog.domain(s.domain)
        ctx = svc.catalog.context(s.domain, s.method, s.rep, s.model_set)
        feedback = parse_feedback(body.choices(), body.satisfied, domain.name, ctx.attribute_names)
        if ctx.model_version != s.model_version:
            raise conflict(f"the served model changed since session {s.id} started ({s.model_version} -> "
                           f"{ctx.model_version}); start a new session")
        try:  # server.feedback already refused what the agent would; an agent's ValueError is still the client's
            rollout_id, state = svc.transitions.advance(ctx, s.method, s.agent_state, feedback)
        except ValueError as exc:
            raise invalid(str(exc)) from exc
        _record_step(db, s, body, feedback, rollout_id, state)
    if s.status == SessionStatus.active:
        schedule_prerender(svc, s, None if feedback == SATISFIED else feedback)
    else:
        stop_prerender(svc, s.id)
    return session_public(svc, db, s)


def _not_abandonable(s: TuningSession) -> str:
    return f"session {s.id} is {s.status} already; only active sessions can be abandoned"


def abandon_session(svc: Services, db: Session, session_id: str) -> SessionPublic:
    with svc.session_locks(session_id):
        s = load_session(db, session_id)
        if s.status != SessionStatus.active:
            raise conflict(_not_abandonable(s))
        _move(db, s, None, _not_abandonable, status=SessionStatus.abandoned.value)
    stop_prerender(svc, s.id)
    return session_public(svc, db, s)
