"""The prerender scheduler: while a person watches a clip, work out and render what each answer would show.

Import direction: above ``server.services`` (its workers, transitions and clip cache), below
``server.sessions`` (which schedules and stops it) and ``server.main`` (the warm-up); it never
imports either.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from rba.interact import SATISFIED, AttributeFeedback, Feedback
from server.admin_models import BUILTIN_VERSION
from server.models import SessionStatus, TuningSession
from server.services import Services

log = logging.getLogger(__name__)


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


def _first_steps(svc: Services) -> list[tuple[tuple[str, str, str, str], dict]]:
    """Every available model's first clip, rendered; returns each (context key, first state)."""
    starts = []
    for name in svc.catalog.names():
        for method, rep in svc.catalog.available(name):
            if svc.stopping:
                return starts
            try:
                ctx = svc.catalog.context(name, method, rep)
                rollout_id, state = svc.transitions.first(ctx, method)
                render_clips(svc, name, [rollout_id], lambda: svc.stopping)
                starts.append(((name, method, rep, BUILTIN_VERSION), state))
            except Exception:
                log.exception("warm-up of %s/%s/%s failed", name, method, rep)
    return starts


def warm_up(svc: Services) -> None:
    """Load every available model and render every first clip, then the clips one answer away from them.

    Every session starts in the same state, so this is the prerender of every new session's first step.
    """
    starts = _first_steps(svc)
    if svc.stopping:
        return
    if svc.settings.prerender:
        for key, state in starts:
            render_clips(svc, key[0], next_clips(svc, key, state, None, lambda: svc.stopping), lambda: svc.stopping)
    if svc.settings.prerender_library:
        for name in dict.fromkeys(key[0] for key, _ in starts):
            render_clips(svc, name, list(svc.catalog.library(name).ids), lambda: svc.stopping)

