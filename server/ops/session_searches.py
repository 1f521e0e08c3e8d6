"""Generating sessions (``TuningSession.generate``): the searches their answers start, and the clips they make.

An answer to such a session runs the agent's step as a job on ``Services.searcher`` (a future) with the
compute layer's ``simulate``; the request awaits that job until it ends or starts simulating (``answer``). A
step that simulates nothing (a serve clip is near the target, or the memo knew the step) answers the request
as any session's would; one that starts simulating is a CMA-ES search of seconds to minutes, so the request
returns 202 and the page polls ``GET /api/sessions/{id}/generation`` (``Search``: generation k of K, the job's
outcome once it ends). The step, and the row of the clip it made (``GeneratedClip``), are then one
transaction (``server.ops.session_steps``).

Searches live in this process's memory only: after a restart the session is still at its step, its
search is gone (the progress route says so) and the person answers again.

Import direction: above ``server.runtime.services``, below ``server.ops.views``, ``server.ops.prerender`` and
``server.ops.session_steps``.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, InvalidStateError, wait
from dataclasses import dataclass, field, replace

from fastapi import HTTPException
from sqlmodel import Session

from rba.compute import SimJob
from rba.domains import Rollout
from rba.interact.generating_agent import GenerationContext, made_clip
from server.common.errors import not_found
from server.db.engine import dialect_insert
from server.db.tables import GeneratedClip, GenerationPublic, TuningSession
from server.runtime.clip_sources import ClipRef, ResolvedClip
from server.runtime.services import Services

log = logging.getLogger(__name__)
KEPT_ENDED = 1024  # ended searches kept for their pages' last polls; older ones are forgotten


ANSWER_POLL_SECONDS = 1.0  # how often a request waiting on its step looks whether the server is stopping


@dataclass
class Search:
    """One step of a generating session, run as a job on the searcher: its progress and how it ended."""

    step: int
    generations: int
    seconds_at_most: float | None = None  # the search's time bound (SearchConfig.seconds)
    started: float = field(default_factory=time.monotonic)
    ended: float | None = None
    generation: int = 0
    state: str = "searching"  # then "done" or "failed"
    error: HTTPException | None = None  # why it failed, as the request would have said it
    job: Future | None = None  # the step's job (``follow``): its result the step's outcome, or the HTTPException
    simulated: Future = field(default_factory=Future)  # done once the step starts simulating: a search
    clip: Future | None = None  # the render of the clip the step made, which the person waits for

    @property
    def simulating(self) -> bool:
        return self.simulated.done()

    def progress(self, k: int, of: int) -> None:
        self.generation, self.generations = k, of

    def begin_simulating(self) -> None:
        with contextlib.suppress(InvalidStateError):  # a search simulates in many batches: only the first tells
            self.simulated.set_result(None)

    def follow(self, job: Future) -> None:
        """Take the outcome of the step's ``job``: done, or failed with its HTTPException (503: the server stopped
        before it ran)."""
        self.job = job
        job.add_done_callback(self.settle)

    def settle(self, job: Future) -> None:
        """Its state from the ended ``job`` (once: the job's callback, or a request that saw it end first)."""
        if self.ended is not None:
            return
        if job.cancelled():
            self.end(HTTPException(503, "the server is stopping; answer again once it is back"))
        else:
            error = job.exception()
            self.end(error if isinstance(error, HTTPException) or error is None else HTTPException(500, str(error)))

    def end(self, error: HTTPException | None = None) -> None:
        self.state, self.error = ("failed", error) if error is not None else ("done", None)
        self.ended = time.monotonic()

    def waited_on(self) -> bool:
        """Whether a person waits on it now: simulating, or rendering the clip it made (``Services.someone_waits``)."""
        return (self.state == "searching" and self.simulating) or (self.clip is not None and not self.clip.done())

    def public(self) -> GenerationPublic:
        elapsed = (self.ended or time.monotonic()) - self.started
        return GenerationPublic(step=self.step, state=self.state, generation=self.generation,
                                generations=self.generations, elapsed_seconds=round(elapsed, 3),
                                seconds_at_most=self.seconds_at_most,
                                detail=None if self.error is None else str(self.error.detail))


def answer(svc: Services, search: Search) -> bool:
    """Await the search's job until the request can answer: True once it simulates (a search: it goes on), False
    once it ended well; its failure is raised (503 once the server stops)."""
    job = search.job
    while not wait([job, search.simulated], ANSWER_POLL_SECONDS, return_when=FIRST_COMPLETED).done:
        if svc.searcher.stopping:
            raise HTTPException(503, "the server is stopping; answer again once it is back")
    if not job.done():
        return True
    search.settle(job)  # before the answer: the page's next request must find the search ended
    if job.cancelled():
        raise HTTPException(503, "the server is stopping; answer again once it is back")
    if job.exception() is not None:
        raise job.exception()
    return False


def step_context(svc: Services, key: tuple[str, str, str, str], search: Search | None) -> GenerationContext:
    """The generating context of ``key`` (domain, method, rep, model set), simulating on the compute layer for
    ``search`` (it reports to it); without a search (guesses), a step that would search raises ``WouldSearch``.

    The serve clip a search falls back to, unless stored, is rendered beside it, as urgently: a search that fell
    short kept the person waiting for that render after it, and as a guess (niced below the search) it was slower
    still (``benchmarks/results/generation_latency.md``).
    """
    gctx = svc.catalog.context(*key, generate=True)

    def simulate(jobs: Iterable[SimJob]) -> Iterator[Rollout]:
        if search is None:  # a guard: the agent calls on_search before any simulation, and that raises first
            raise WouldSearch(None)
        search.begin_simulating()
        return svc.compute.simulate(jobs)

    def before_search(fallback: str) -> None:
        if search is None:
            raise WouldSearch(fallback)
        try:  # a head start on a render: the search must not fail for it (the page asks for the clip again)
            svc.clips.request(*svc.sources.guess(ClipRef(key[0], fallback)), urgent=True)
        except Exception:
            log.warning("session search: the fallback clip %s of %s could not be requested", fallback, key[0],
                        exc_info=True)

    return replace(gctx, simulate=simulate, remake=svc.compute.simulate,  # a clip made again is no search
                   on_progress=None if search is None else search.progress, on_search=before_search)


class WouldSearch(Exception):
    """A guessed step would start a search: guesses never spend the compute layer on one. ``fallback``: the serve
    clip that step shows if its search falls short (None: not known), which a guess can render ahead."""

    def __init__(self, fallback: str | None) -> None:
        super().__init__(fallback)
        self.fallback = fallback


def begin(svc: Services, s: TuningSession) -> Search:
    """A new search for the session's current step, registered so the progress route finds it."""
    gctx = svc.catalog.context(s.domain, s.method, s.rep, s.model_set, generate=True)
    search = Search(s.step, gctx.generations, gctx.config.seconds)
    with svc.search_lock:
        svc.searches.pop(s.id, None)  # to the end: the dict runs oldest first
        svc.searches[s.id] = search
        ended = [k for k, v in svc.searches.items() if v.state != "searching"]
        for k in ended[:max(len(ended) - KEPT_ENDED, 0)]:
            del svc.searches[k]
    return search


def running(svc: Services, session_id: str) -> Search | None:
    with svc.search_lock:
        search = svc.searches.get(session_id)
    return search if search is not None and search.state == "searching" else None


def latest(svc: Services, s: TuningSession) -> GenerationPublic:
    """The session's last search in this process; 404 saying when there is none."""
    with svc.search_lock:
        search = svc.searches.get(s.id)
    if search is None:
        raise not_found(f"session {s.id} has no search in this server: only an answer that needs a new behaviour "
                        "starts one (and a restart forgets it: answer again)")
    return search.public()


def current(svc: Services, s: TuningSession) -> GenerationPublic | None:
    """The search of the session's current step (running, or failed: answer again), for the session's view."""
    with svc.search_lock:
        search = svc.searches.get(s.id)
    return search.public() if search is not None and search.step == s.step and search.state != "done" else None


def generated_row(svc: Services, db: Session, domain: str, rollout_id: str, state: dict) -> GeneratedClip | None:
    """The row a step that shows ``rollout_id`` must add: None unless its agent (``state``) made that clip and no
    row holds it yet."""
    made = made_clip(state, rollout_id)
    if made is None or db.get(GeneratedClip, rollout_id) is not None:
        return None
    rollout = svc.catalog.generated_store(domain).rollout(domain, rollout_id, made["params"], made["seed"],
                                                          svc.compute.simulate)
    return GeneratedClip(id=rollout_id, domain=domain, params=made["params"], seed=made["seed"],
                         proxies={k: float(v) for k, v in rollout.proxies.items()})


def made_shown(svc: Services, db: Session, domain: str, rollout_id: str, state: dict) -> ResolvedClip | None:
    """The clip a step shows if its agent (``state``) made it (someone waits for its render), else None."""
    return None if made_clip(state, rollout_id) is None else svc.sources.resolve(db, domain, rollout_id)


def add_generated(db: Session, row: GeneratedClip) -> None:
    """Insert ``row`` in the caller's transaction unless its id is there already (ids are content: equal rows)."""
    db.exec(dialect_insert(db, GeneratedClip).values(**row.model_dump()).on_conflict_do_nothing(index_elements=["id"]))
