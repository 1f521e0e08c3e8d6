"""Session transactions behind the routes: create, answer, abandon; one database transaction per change.

The agent lives in the database as its JSON state; every request restores a fresh copy
from that state, so a session continues exactly after a restart and concurrent guesses
(prerendering) never touch the stored agent.

Import direction: above ``server.runtime.services``, ``server.ops.views``, ``server.ops.prerender``,
``server.common.feedback`` and ``server.ops.model_versions``; only the routes import it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from concurrent.futures import Future
from functools import partial
from typing import Any

from fastapi import HTTPException
from sqlalchemy import update
from sqlalchemy.exc import IntegrityError
from sqlmodel import Session

from rba.core.methods import generating_methods, get_method
from rba.interact import SATISFIED, Feedback
from server.common.errors import conflict, invalid, not_found
from server.common.feedback import parse_feedback
from server.db.tables import (
    FeedbackCreate,
    FeedbackEvent,
    GeneratedClip,
    SessionCreate,
    SessionPublic,
    SessionStatus,
    TuningSession,
    utcnow,
)
from server.ops import session_searches
from server.ops.model_versions import serving_version
from server.ops.prerender import schedule_prerender, stop_prerender
from server.ops.views import session_public
from server.runtime.services import Services

log = logging.getLogger(__name__)


def load_session(db: Session, session_id: str) -> TuningSession:
    s = db.get(TuningSession, session_id)
    if s is None:
        raise not_found(f"no session {session_id!r}; create one with POST /api/sessions")
    return s


def _generates(svc: Services, body: SessionCreate) -> bool:
    """Whether the new session's agent makes behaviours: the body's ``generate``, else ``RBA_GENERATE`` where
    the method can (422 naming the methods that can, when the body asks for one that cannot)."""
    able = generating_methods()
    if body.generate is None:
        return svc.settings.generate and body.method in able
    if body.generate and body.method not in able:
        raise invalid(f"method {body.method!r} cannot generate behaviours; valid with generate: "
                      f"{', '.join(able)} (or leave generate out)")
    return body.generate


def create_session(svc: Services, db: Session, body: SessionCreate) -> SessionPublic:
    generate = _generates(svc, body)
    version = serving_version(svc, db, body.domain, body.method, body.rep)
    svc.catalog.check_available(body.domain, body.method, body.rep, version)
    ctx = svc.catalog.context(body.domain, body.method, body.rep, version, generate)
    rollout_id, state = svc.transitions.first(ctx, get_method(body.method).form(generate))
    s = TuningSession(domain=body.domain, method=body.method, rep=body.rep, model_version=ctx.model_version,
                      model_set=version, library_version=svc.catalog.library(body.domain).version,
                      current_rollout_id=rollout_id, agent_state=state, generate=generate)
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
                 state: dict, made: GeneratedClip | None = None) -> None:
    """Store the round (and the clip it made) and move the session on, in one transaction; 409 if another
    request answered first."""
    stored = SATISFIED if feedback == SATISFIED else [c.model_dump() for c in body.feedback or ()]
    db.add(FeedbackEvent(session_id=s.id, step=s.step, feedback=stored, rollout_before=s.current_rollout_id,
                         rollout_after=rollout_id))
    if made is not None:
        session_searches.add_generated(db, made)
    status = SessionStatus.satisfied.value if feedback == SATISFIED else SessionStatus.active.value

    def lost(now: TuningSession) -> str:
        if now.status != SessionStatus.active:
            return _closed(now)
        return f"step {body.step} is stale: session {now.id} already moved on"

    _move(db, s, s.step, lost, step=s.step + 1, current_rollout_id=rollout_id, agent_state=state, status=status)


def give_feedback(svc: Services, db: Session, session_id: str, body: FeedbackCreate) -> tuple[SessionPublic, bool]:
    """Advance the session by one round; 409 if the step is stale, the session is closed or still searching.

    Returns the session and whether its step is still searching (a generating session's: 202, poll its progress).
    """
    with svc.session_locks(session_id):
        s = _answerable(db, session_id, body)
        if (search := session_searches.running(svc, s.id)) is not None:
            raise conflict(f"session {s.id} is still making a new behaviour for step {search.step} (generation "
                           f"{search.generation} of {search.generations}); wait for it: "
                           f"GET /api/sessions/{s.id}/generation")
        domain = svc.catalog.domain(s.domain)
        ctx = svc.catalog.context(s.domain, s.method, s.rep, s.model_set)
        feedback = parse_feedback(body.choices(), body.satisfied, domain.name, ctx.attribute_names)
        if ctx.model_version != s.model_version:
            raise conflict(f"the served model changed since session {s.id} started ({s.model_version} -> "
                           f"{ctx.model_version}); start a new session")
        if s.generate:
            searching = _search(svc, s, body, feedback)
            if not searching:
                db.refresh(s)
            return session_public(svc, db, s), searching
        rollout_id, state = _advance(svc, ctx, s, feedback)
        _record_step(db, s, body, feedback, rollout_id, state)
    _after_step(svc, s, feedback)
    return session_public(svc, db, s), False


def _advance(svc: Services, ctx: Any, s: TuningSession, feedback: Feedback) -> tuple[str, dict]:
    try:  # server.common.feedback already refused what the agent would; an agent's ValueError is still the client's
        return svc.transitions.advance(ctx, get_method(s.method).form(s.generate), s.agent_state, feedback)
    except ValueError as exc:
        raise invalid(str(exc)) from exc


def _after_step(svc: Services, s: TuningSession, feedback: Feedback, clip: Future | None = None) -> None:
    """Guess the next answers' clips (once ``clip``, the one the person now waits for, is rendered)."""
    if s.status == SessionStatus.active:
        schedule_prerender(svc, s, None if feedback == SATISFIED else feedback, clip)
    else:
        stop_prerender(svc, s.id)


def _search(svc: Services, s: TuningSession, body: FeedbackCreate, feedback: Feedback) -> bool:
    """Run a generating session's step as a job on the searcher; back once it simulates (a search: it goes on, True)
    or ends (False). A step that ends without simulating is the request's as any other: its failure is raised here."""
    search = session_searches.begin(svc, s)
    stop_prerender(svc, s.id)  # guesses about the answers not given: they would only slow the search
    ctx = session_searches.step_context(svc, (s.domain, s.method, s.rep, s.model_set), search)
    job = svc.searcher.submit(s.id, partial(_searched_step, svc, s, body, feedback, ctx, search))
    search.follow(job)
    job.add_done_callback(partial(_guess_after, svc, feedback))
    return session_searches.answer(svc, search)


def _searched_step(svc: Services, s: TuningSession, body: FeedbackCreate, feedback: Feedback, ctx: Any,
                   search: session_searches.Search) -> tuple[TuningSession, Future | None]:
    """The step itself, on the searcher: the agent's answer (a search if it must), stored with the clip it made in
    one transaction, then that clip's render asked for (the page asks for it next). Returns the moved session and
    that render; every failure of the step is an HTTPException, as the request would have raised it."""
    try:
        rollout_id, state = _advance(svc, ctx, s, feedback)
        with Session(svc.engine, expire_on_commit=False) as db:
            moving = db.get(TuningSession, s.id)
            if moving.step != s.step:
                raise conflict(f"step {s.step} is stale: session {s.id} already moved on")
            made = session_searches.generated_row(svc, db, s.domain, rollout_id, state)
            _record_step(db, moving, body, feedback, rollout_id, state, made)
            shown = session_searches.made_shown(svc, db, s.domain, rollout_id, state)
    except HTTPException:
        raise
    except Exception as exc:  # reported, not raised raw: the page is waiting on it
        log.exception("session %s: the search of step %d failed", s.id, s.step)
        raise HTTPException(500, f"the search for a new behaviour failed ({type(exc).__name__}); answer again") from exc
    try:  # the step is saved: whatever happens to this render, the answer was taken
        if shown is not None and svc.catalog.domain(s.domain).draws_clips:  # its data first: the page draws from it
            svc.clips.request(shown.key.data(), shown.source(), urgent=True)
        search.clip = None if shown is None else svc.clips.request(shown.key, shown.source(), urgent=True)
    except Exception:  # the page's clip request renders (or reports) it again
        log.exception("session %s: step %d is saved, but rendering ahead failed", s.id, s.step)
    return moving, search.clip


def _guess_after(svc: Services, feedback: Feedback, job: Future) -> None:
    """Once a step's job ended well: guess the next answers' clips (once the clip it made is rendered)."""
    if job.cancelled() or job.exception() is not None:
        return
    moving, clip = job.result()
    try:
        _after_step(svc, moving, feedback, clip)
    except Exception:
        log.exception("session %s: step %d is saved, but guessing ahead failed", moving.id, moving.step - 1)


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
