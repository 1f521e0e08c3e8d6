"""The app's long-lived parts in one object (``app.state.services``), shared by the routes.

Import direction (no cycles, function-level imports included): the server's folders are its layers, lowest first,
and a module imports only from its own layer and those below it (``tests/test_architecture.py`` checks it by folder):

0. ``server.common``: what every layer uses: the app's settings, the one error body, the rules of feedback;
1. ``server.db``: the SQL tables (``tables``, ``admin_tables``), the ``engine`` and the schema's ``migrations``;
2. ``server.runtime``: the long-lived parts: ``uploads``, ``transitions``, ``background``, ``prefetch``, ``catalog``,
   ``stored_labels`` (label data as the database and the upload folder hold it), ``processes`` (job processes that
   die with their server), ``job_runner`` (training processes, which read ``stored_labels`` and use
   ``processes``) and ``clip_sources`` (every rollout id resolved, over the catalog); then this module, which
   holds those parts and which none of them imports. The clip cache and the
   per-key locks are the library's (``rba.media.clip_cache``, ``rba.core.locks``), and so is the compute layer
   (``rba.compute``);
3. ``server.ops``: operations that take a ``Services``: ``model_versions``, ``session_searches``, ``views``,
   ``prerender``, ``session_steps``, ``label_admin``, ``training_jobs``, ``session_export``, ``text_feedback`` (each
   imports only those before it in this list);
4. ``server.api``: ``deps``, ``auth``, ``limits`` and ``routes.*``; then ``server.main``, which builds the app.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field

from sqlalchemy.engine import Engine

from rba.compute import Compute, make_compute
from rba.core.locks import KeyedLocks
from rba.core.store import Store
from rba.interact.free_text import load_in_background
from rba.media.clip_cache import ClipCache
from server.common.app_settings import Settings
from server.db.engine import make_engine
from server.runtime.background import Background
from server.runtime.catalog import Catalog
from server.runtime.clip_sources import ClipSources
from server.runtime.job_runner import JobRunner
from server.runtime.prefetch import Prefetcher
from server.runtime.stored_labels import sweep_uploads
from server.runtime.transitions import Transitions
from server.runtime.uploads import sweep_workspaces

log = logging.getLogger(__name__)
SEARCHERS = 4


@dataclass
class Services:
    settings: Settings
    engine: Engine
    catalog: Catalog
    compute: Compute  # where every simulation and render runs (never this process)
    clips: ClipCache
    sources: ClipSources  # every rollout id -> its clip's key and rollout (library or made): the one resolver
    transitions: Transitions
    thinker: Background | None  # works out what each possible next answer would show (agent copies)
    prefetch: Prefetcher  # feeds guessed renders to the compute layer, most needed first
    jobs: JobRunner  # retraining processes
    owns_compute: bool = True
    # generating sessions' steps: a thread each while it waits for the compute layer (SEARCHERS at once)
    searcher: Background = field(default_factory=lambda: Background(SEARCHERS, "rba-generate"))
    session_locks: KeyedLocks = field(default_factory=KeyedLocks)
    searches: dict = field(default_factory=dict)  # session id -> its latest server.ops.session_searches.Search
    search_lock: threading.Lock = field(default_factory=threading.Lock)
    prerendering: dict[str, int] = field(default_factory=dict)  # session id -> step being prerendered
    warming: threading.Thread | None = None  # the warm-up (server.ops.prerender.warm_up), while it runs
    reading: threading.Thread | None = None  # loads free text's sentence model and every domain's anchors

    @classmethod
    def start(cls, settings: Settings, compute: Compute | None = None) -> Services:
        """The app's parts; ``compute`` is shared when given (tests), else made from the settings and owned."""
        import torch

        torch.set_num_threads(settings.torch_threads)
        engine = make_engine(settings.db_url)
        catalog = Catalog(settings)
        sweep_uploads(engine, catalog.store)  # what uploads cut short by a crash left (never a live one's)
        sweep_workspaces()
        owns = compute is None
        compute = compute or make_compute(settings)
        clips = ClipCache(catalog.store.clips(), compute, settings.clip_width, settings.clip_height)
        busy = settings.prerender or settings.warm_start
        # Thinking keeps normal priority: it is what makes the next feedback request fast.
        thinker = Background(1, "rba-think") if busy else None
        jobs = JobRunner(settings, engine)
        jobs.recover()
        window = settings.prerender_window or compute.capacity
        sources = ClipSources(catalog, settings.clip_width, settings.clip_height, compute.simulate)
        prefetch = Prefetcher(clips, sources.guess, window, settings.background_nice)
        svc = cls(settings, engine, catalog, compute, clips, sources, Transitions(), thinker, prefetch, jobs, owns)
        prefetch.hold = svc.someone_waits  # the queue is made first: it has to exist in the Services
        if settings.warm_start:  # with the other models, in the background: the first sentence reads as fast
            names = sorted(catalog.names(), key=lambda n: n != settings.default_domain)
            svc.reading = load_in_background(catalog.domain(n) for n in names)
        return svc

    def someone_waits(self) -> bool:
        """Whether a person waits on a search now: simulating, or rendering the clip it made. (Not on any clip:
        with ten users someone nearly always waits for one, and guesses held then were missed more, so answers
        waited longer; there niceness alone serves better, ``api_load_cold.md``.)"""
        with self.search_lock:
            return any(search.waited_on() for search in self.searches.values())

    @property
    def store(self) -> Store:
        """Where the app's files live (the catalog's: one layout for the whole app)."""
        return self.catalog.store

    def wait_idle(self, timeout: float) -> bool:
        """True once no background work is queued or running (tests and benchmarks use it)."""
        if self.warming is not None:
            self.warming.join(timeout)
            if self.warming.is_alive():
                return False
        for _ in range(2):  # thinking queues renders, and a render's end may let more thinking start
            if not self.clips.wait_idle(timeout):
                return False
            if self.thinker is not None and not self.thinker.wait_idle(timeout):
                return False
            if not self.prefetch.wait_idle(timeout) or not self.searcher.wait_idle(timeout):
                return False
        return True

    @property
    def stopping(self) -> bool:
        return self.prefetch.stopping or (self.thinker is not None and self.thinker.stopping)

    def stop(self) -> None:
        self.jobs.stop()
        self.searcher.stop()
        if self.thinker is not None:
            self.thinker.stop()
        self.prefetch.stop()
        if self.owns_compute:
            self.compute.close()
        self.engine.dispose()
