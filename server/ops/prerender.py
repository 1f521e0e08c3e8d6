"""Clips before they are asked for: which clips to render as guesses, in the order people will need them.

Every session of a context (domain, method, rep, model version) starts from the same clip and
branches on a few answers, so the clips anyone can reach form one tree that all sessions share.
Guesses are rendered in three tiers (the ``Prefetcher`` keeps the compute layer's guess queue
short and always takes from the highest tier first):

1. each active session's possible next clips: every answer combination, most likely first;
2. the shared trees, best-first by how likely a session is to reach each node: answer
   probabilities are what earlier sessions answered there (counted from the feedback table,
   plus one per answer, so an unvisited tree is walked breadth-first);
3. the rest of each serve library.

Import direction: above ``server.runtime.services`` (its transitions, catalog, clip cache and prefetcher),
below ``server.ops.session_steps`` and ``server.main``; it never imports either.
"""

from __future__ import annotations

import heapq
import itertools
import logging
from collections import Counter, defaultdict
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from dataclasses import dataclass

from sqlmodel import Session, select

from rba.core.methods import get_method
from rba.domains import domain_names, domain_target
from rba.interact import SATISFIED, AttributeFeedback, Feedback
from server.db.admin_tables import BUILTIN_VERSION
from server.db.tables import FeedbackEvent, SessionStatus, TuningSession
from server.ops import session_searches
from server.runtime.clip_sources import ClipRef
from server.runtime.services import Services
from server.runtime.transitions import FeedbackKey, feedback_key

log = logging.getLogger(__name__)

ContextKey = tuple[str, str, str, str]  # (domain, method, rep, model version)
FIRST_CLIP_WAIT_SECONDS = 120
MAX_ANSWER_ATTRIBUTES = 2  # answers name at most this many attributes at once (the page names one)


def answer_order(attributes: tuple[str, ...], last: Feedback | None) -> list[list[AttributeFeedback]]:
    """Every answer a person can give, most likely first: single answers (the last one repeated first, then
    the same attribute the other way), then combinations of two attributes."""
    singles = [AttributeFeedback(a, d) for a in attributes for d in (1, -1)]
    if last and last != SATISFIED:
        asked = {(fb.attribute, fb.direction) for fb in last}
        singles.sort(key=lambda fb: 0 if (fb.attribute, fb.direction) in asked
                     else 1 if any(fb.attribute == a for a, _ in asked) else 2)
    answers = [[fb] for fb in singles]
    for k in range(2, min(MAX_ANSWER_ATTRIBUTES, len(attributes)) + 1):
        for names in itertools.combinations(attributes, k):
            for dirs in itertools.product((1, -1), repeat=k):
                answers.append([AttributeFeedback(a, d) for a, d in zip(names, dirs, strict=True)])
    return answers


def next_clips(svc: Services, key: ContextKey, generate: bool, state: dict, last: Feedback | None,
               stale: Callable[[], bool]) -> list[str]:
    """The clip each possible next answer would show, most likely first (computed on copies, memoised).

    A generating session's answer that would start a search gives the serve clip that search falls back to: a
    guess never spends the compute layer on a search (the step renders what it made), but the fallback is the clip
    a person waits longest for when the search falls short. An answer that shows a made clip without a search (a
    runner-up of an earlier search, ``rba.interact.generating_agent``'s pool) gives that clip: it was simulated with its
    search, and rendered ahead it plays at once (``ClipSources.guess`` resolves it while the domain's store keeps it).
    """
    ctx = svc.catalog.context(*key)
    step_ctx = session_searches.step_context(svc, key, None) if generate else ctx
    form = get_method(key[1]).form(generate)
    nexts: list[str] = []
    for answer in answer_order(ctx.attribute_names, last):
        if stale():
            break
        try:
            rollout_id = svc.transitions.advance(step_ctx, form, state, answer)[0]
        except session_searches.WouldSearch as exc:
            if exc.fallback is None:
                continue
            rollout_id = exc.fallback
        nexts.append(rollout_id)
    return list(dict.fromkeys(nexts))


def schedule_prerender(svc: Services, s: TuningSession, last: Feedback | None, after: Future | None = None) -> None:
    """While the person watches: work out what every possible answer would show, and queue those clips first.

    The thinker keeps only a session's newest job: an answer given before the guesses were worked out
    replaces them. The clips go to the prefetcher's first tier as they are found, most likely first.
    ``after``: the render of the clip the person waits for; the thinking starts once it is done, since beside
    it, it slowed that render (the step counts as scheduled meanwhile: ``resume_prerender`` leaves it).
    """
    if svc.thinker is None or not svc.settings.prerender:
        return
    session_id, step, shown = s.id, s.step, s.current_rollout_id
    key, generate, state = (s.domain, s.method, s.rep, s.model_set), s.generate, s.agent_state
    svc.prerendering[session_id] = step

    def stale() -> bool:
        return svc.stopping or svc.prerendering.get(session_id) != step

    def think() -> None:
        # the shown clip first (the prefetcher skips it when it is stored or rendering: a step's made clip is)
        clips = [shown, *next_clips(svc, key, generate, state, last, stale)]
        if not stale():
            svc.prefetch.offer(session_id, [ClipRef(key[0], rid) for rid in clips])

    if after is None:
        svc.thinker.submit(session_id, think)
    else:
        after.add_done_callback(lambda _: None if stale() else svc.thinker.submit(session_id, think))


def stop_prerender(svc: Services, session_id: str) -> None:
    svc.prerendering.pop(session_id, None)
    if svc.thinker is not None:
        svc.thinker.cancel(session_id)
    svc.prefetch.withdraw(session_id)


def resume_prerender(svc: Services, s: TuningSession) -> None:
    """After a restart (or a missed step) nothing is queued for an active session: queue it."""
    if s.status == SessionStatus.active and svc.prerendering.get(s.id) != s.step:
        schedule_prerender(svc, s, None)


# -- the shared trees -------------------------------------------------------------------------

@dataclass
class AnswerCounts:
    """How many sessions of each context gave each answer after each answer path (from the feedback table)."""

    sessions: Counter  # context -> sessions started
    after: dict  # (context, path) -> Counter(answer -> sessions)

    @classmethod
    def load(cls, svc: Services) -> AnswerCounts:
        sessions: Counter = Counter()
        after: dict = defaultdict(Counter)
        paths: dict[str, list[FeedbackKey]] = defaultdict(list)
        with Session(svc.engine) as db:
            contexts = {s.id: (s.domain, s.method, s.rep, s.model_set) for s in db.exec(select(TuningSession))}
            rows = db.exec(select(FeedbackEvent).order_by(FeedbackEvent.session_id, FeedbackEvent.step)).all()
        for sid in contexts:
            sessions[contexts[sid]] += 1
        for row in rows:
            if row.session_id in contexts and row.feedback != SATISFIED:
                path = paths[row.session_id]
                answer = tuple(sorted((f["attribute"], 1 if f["direction"] == "more" else -1) for f in row.feedback))
                after[contexts[row.session_id], tuple(path)][answer] += 1
                path.append(answer)
        return cls(sessions, after)

    def share(self, context: ContextKey, contexts: int) -> float:
        """The share of new sessions expected in ``context`` (add-one smoothing over ``contexts``)."""
        return (self.sessions[context] + 1) / (sum(self.sessions.values()) + contexts)

    def answer_share(self, context: ContextKey, path: tuple, answer: FeedbackKey, answers: int) -> float:
        counts = self.after.get((context, path), Counter())
        return (counts[answer] + 1) / (sum(counts.values()) + answers)


def tree_clips(svc: Services, counts: AnswerCounts, starts: list[tuple[ContextKey, str, dict]],
               min_share: float, stop: Callable[[], bool]) -> Iterator[ClipRef]:
    """Clips of every context's tree, most likely to be reached first, down to ``min_share`` of sessions."""
    heap: list[tuple[float, int, ContextKey, tuple, dict]] = []
    order = itertools.count()
    for context, first, state in starts:
        share = counts.share(context, len(starts))
        yield ClipRef(context[0], first)
        heapq.heappush(heap, (-share, next(order), context, (), state))
    while heap and not stop():
        neg_share, _, context, path, state = heapq.heappop(heap)
        ctx = svc.catalog.context(*context)
        answers = answer_order(ctx.attribute_names, None)
        for answer in answers:
            share = -neg_share * counts.answer_share(context, path, feedback_key(answer), len(answers))
            if share < min_share or stop():
                continue
            rollout_id, child = svc.transitions.advance(ctx, get_method(context[1]), state, answer, memo=False)
            yield ClipRef(context[0], rollout_id)
            heapq.heappush(heap, (-share, next(order), context, (*path, feedback_key(answer)), child))


def library_clips(svc: Services, domains: list[str]) -> Iterator[ClipRef]:
    for name in domains:
        for rid in svc.catalog.library(name).ids:
            yield ClipRef(name, rid)


def first_clip(svc: Services, ref: ClipRef) -> None:
    """Make the clip the first person will ask for, urgently, and wait for it.

    Where the page draws the domain's clips, that is the domain's scene and the clip's data (both a small
    part of an MP4's CPU), and the MP4 follows as a guess; elsewhere the page plays the MP4.
    """
    key, source = svc.sources.guess(ref)
    if not svc.catalog.domain(ref.domain).draws_clips:
        svc.clips.request(key, source, urgent=True).result(FIRST_CLIP_WAIT_SECONDS)
        return
    scene = svc.clips.scene(ref.domain)
    svc.clips.request(key.data(), source, urgent=True).result(FIRST_CLIP_WAIT_SECONDS)
    scene.result(FIRST_CLIP_WAIT_SECONDS)
    svc.clips.request(key, source, urgent=False)


def first_steps(svc: Services) -> list[tuple[ContextKey, str, dict]]:
    """Every available context's first clip and state (a new session's step 0), made.

    The default domain's first context comes first and its clip is made urgently and waited for
    (``first_clip``) before the other contexts load: on a cold machine that is the clip the first
    person will ask for. The others are guesses, so they never hold up a clip someone asked for.
    """
    names = sorted(svc.catalog.names(), key=lambda n: n != svc.settings.default_domain)
    starts = []
    for name in names:
        for method, rep in svc.catalog.available(name):
            if svc.stopping:
                return starts
            try:
                ctx = svc.catalog.context(name, method, rep)
                rollout_id, state = svc.transitions.first(ctx, get_method(method))
                if not starts:  # the default domain's: urgent, and waited for; the others are guesses
                    first_clip(svc, ClipRef(name, rollout_id))
                else:
                    svc.clips.request(*svc.sources.guess(ClipRef(name, rollout_id)), urgent=False)
            except Exception:
                log.exception("warm-up of %s/%s/%s failed", name, method, rep)
                continue
            starts.append(((name, method, rep, BUILTIN_VERSION), rollout_id, state))
    return starts


def warm_up(svc: Services) -> None:
    """Make the first clips now (``first_steps``), then queue the shared trees and (if asked) the whole libraries."""
    if svc.settings.default_domain in domain_names():
        svc.compute.warm(domain_target(svc.settings.default_domain))
    starts = first_steps(svc)
    if svc.stopping or not svc.settings.prerender:
        return
    counts = AnswerCounts.load(svc)
    svc.prefetch.extend(tree_clips(svc, counts, starts, svc.settings.prerender_tree_min_share,
                                   lambda: svc.stopping))
    if svc.settings.prerender_library:
        svc.prefetch.extend(library_clips(svc, list(dict.fromkeys(start[0][0] for start in starts))))
