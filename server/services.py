"""The app's long-lived parts in one object (``app.state.services``), shared by the routes.

Import direction (no cycles, function-level imports included), lowest first:

1. tables, rules and tools: ``settings``, ``errors``, ``feedback``, ``models``, ``admin_models``,
   ``db``, ``uploads``, ``transitions``, ``background``, ``catalog``; ``labeldata`` (stored label
   data) and ``jobs`` (training processes, which read ``labeldata``); the clip cache and the
   per-key locks are the library's (``rba.clips``, ``rba.locks``);
2. this module, which holds those parts and imports nothing above it;
3. operations that take a ``Services``: ``versions``, ``views``, ``prerender``, ``sessions``,
   ``labelling``, ``training`` (each imports only those before it in this list);
4. ``deps``, ``auth`` and ``routes.*``; then ``main``.

Nothing in 1 imports this module or anything in 3-4 (``tests/test_architecture.py`` checks it).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import anyio
from sqlalchemy.engine import Engine

from rba.clips import ClipCache
from rba.locks import KeyedLocks
from rba.store import Store
from server.background import Background
from server.catalog import Catalog
from server.db import make_engine
from server.jobs import JobRunner
from server.settings import Settings
from server.transitions import Transitions

log = logging.getLogger(__name__)
CLIP_WAITERS = 32  # clip requests that may wait for a render at once, beside (not out of) AnyIO's 40 API threads


@dataclass
class Services:
    settings: Settings
    engine: Engine
    catalog: Catalog
    clips: ClipCache
    transitions: Transitions
    thinker: Background | None  # works out what each possible next answer would show (agent copies)
    renderer: Background | None  # renders those clips (prerender_workers threads, 1 by default, niced)
    clip_limiter: anyio.CapacityLimiter  # its own limiter: waiting for renders never takes the API's threads
    jobs: JobRunner  # retraining processes
    session_locks: KeyedLocks = field(default_factory=KeyedLocks)
    prerendering: dict[str, int] = field(default_factory=dict)  # session id -> step being prerendered

    @classmethod
    def start(cls, settings: Settings) -> Services:
        """Call inside the event loop (the lifespan): the clip limiter belongs to it."""
        import torch

        torch.set_num_threads(settings.torch_threads)
        engine = make_engine(settings.db_url)
        catalog = Catalog(settings)
        clips = ClipCache(catalog.store.clips(), settings.clip_width, settings.clip_height,
                          settings.render_concurrency)
        busy = settings.prerender or settings.warm_start
        # Thinking keeps normal priority: it is what makes the next feedback request fast.
        thinker = Background(1, "rba-think") if busy else None
        renderer = Background(settings.prerender_workers, "rba-render", settings.background_nice) if busy else None
        jobs = JobRunner(settings, engine)
        jobs.recover()
        return cls(settings, engine, catalog, clips, Transitions(), thinker, renderer,
                   anyio.CapacityLimiter(CLIP_WAITERS), jobs)

    @property
    def store(self) -> Store:
        """Where the app's files live (the catalog's: one layout for the whole app)."""
        return self.catalog.store

    def wait_idle(self, timeout: float) -> bool:
        """True once no background work is queued or running (tests and benchmarks use it)."""
        workers = [w for w in (self.thinker, self.renderer) if w is not None]
        return all(w.wait_idle(timeout) for w in workers) and all(w.wait_idle(timeout) for w in workers)

    @property
    def stopping(self) -> bool:
        return any(w is not None and w.stopping for w in (self.thinker, self.renderer))

    def stop(self) -> None:
        self.jobs.stop()
        for worker in (self.thinker, self.renderer):
            if worker is not None:
                worker.stop()
        self.engine.dispose()
