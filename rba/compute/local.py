"""The embedded backend: two process pools on this machine, separate from the API process and niced below it.

``urgent`` renders (someone is waiting) and simulations run at ``nice``; guesses (prerender, the
library cache) run in their own pool at ``background_nice``, so the kernel gives a waiting person's
clip the CPU first while guesses use what is left. Pools start their processes on first use;
``warm`` starts them early. A pool whose worker died (killed, out of memory) is replaced and the
task runs again, as Ray does for its workers.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sized
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from rba.compute import tasks
from rba.compute.base import Compute, DataJob, RenderJob, SimJob, Task, joined, sim_chunk
from rba.domains import Rollout

log = logging.getLogger(__name__)
MAX_RENDER_THREADS = 4  # rasteriser threads of an urgent worker at most
RETRIES = 2  # runs after a worker died, as Ray's default task retries


class _Pool:
    """A process pool that replaces itself when broken; ``submit`` retries a task cut short by that."""

    def __init__(self, workers: int, nice: int, render_threads: int = 1) -> None:
        self.workers, self.nice, self.render_threads = workers, nice, render_threads
        self._lock = threading.Lock()
        self._closed = False
        self.executor = self._new()

    def _new(self) -> ProcessPoolExecutor:  # spawn, not fork: EGL contexts and threads do not survive a fork
        return ProcessPoolExecutor(self.workers, mp.get_context("spawn"), tasks.init_worker,
                                   (self.nice, self.render_threads))

    def submit(self, fn: Callable, *args: object) -> Task:
        outer: Future = Future()
        state = {"inner": None}

        def attempt(left: int) -> None:
            executor = self.executor
            try:
                inner = executor.submit(fn, *args)
            except BrokenProcessPool as exc:  # broke between tasks: replace it and submit again
                if not left or self._closed:
                    outer.set_exception(exc)
                    return
                self._replace(executor)
                attempt(left - 1)
                return
            except RuntimeError as exc:  # shut down
                outer.set_exception(exc)
                return
            state["inner"] = inner
            inner.add_done_callback(lambda f: finish(f, executor, left))

        def finish(inner: Future, executor: ProcessPoolExecutor, left: int) -> None:
            if outer.done():
                return
            if inner.cancelled():
                outer.cancel()
            elif isinstance(inner.exception(), BrokenProcessPool) and left and not self._closed:
                log.warning("a compute worker died; running %s again", getattr(fn, "__name__", fn))
                self._replace(executor)
                attempt(left - 1)
            elif inner.exception() is not None:
                outer.set_exception(inner.exception())
            else:
                outer.set_result(inner.result())

        attempt(RETRIES)  # ``outer`` stays pending until the result is in, so cancelling it works until then
        return Task(outer, lambda: bool(state["inner"] and state["inner"].cancel()),  # ``finish`` cancels ``outer``
                    lambda: bool(state["inner"] and state["inner"].running()))

    def _replace(self, broken: ProcessPoolExecutor) -> None:
        with self._lock:
            if self.executor is broken:
                self.executor = self._new()
        broken.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        self._closed = True
        self.executor.shutdown(wait=True, cancel_futures=True)


class LocalCompute(Compute):
    name = "local"
    prioritised = True

    def __init__(self, workers: int = 2, nice: int = 5, background_nice: int = 15) -> None:
        self.workers = workers
        cores = len(os.sched_getaffinity(0))
        # someone waits: a clip's parts run on every worker at once, and the workers share the cores (one rasteriser
        # thread each on 2 cores: a walker clip 0.76-0.79 s against 0.87-1.00 s with two); more than 4 threads
        # only fight over a 320x240 frame
        self._urgent = _Pool(workers, nice, min(max(cores // workers, 1), MAX_RENDER_THREADS))
        self._background = _Pool(workers, background_nice)

    @property
    def capacity(self) -> int:
        return self.workers

    def simulate(self, jobs: Iterable[SimJob]) -> Iterator[Rollout]:
        """In order: a library's many jobs in chunks of ``sim_chunk`` rollouts per round trip; a search's few (or
        jobs given as an iterator) one per worker at a time (``_one_per_worker``)."""
        if isinstance(jobs, Sized) and (chunk := sim_chunk(len(jobs), self.workers)) > 1:
            jobs = list(jobs)
            yield from self._urgent.executor.map(tasks.simulate, [j.target for j in jobs], [j.params for j in jobs],
                                                 [j.seed for j in jobs], chunksize=chunk)
        else:
            yield from self._one_per_worker(iter(jobs))

    def _one_per_worker(self, jobs: Iterator[SimJob]) -> Iterator[Rollout]:
        """At most one simulation per worker in flight, the next job taken from ``jobs`` only when a worker is free.

        Why: a search out of time stops taking jobs and closes the stream; jobs handed to the pool before then
        ran anyway (the pool queues one more than it has workers, beyond cancelling), and the clip the search
        made, rendered next on the same workers, waited for them (decision 0005).
        """
        window: deque[Task] = deque()

        def running() -> list[Future]:
            return [t.future for t in window if not t.future.done()]

        def fill() -> None:
            while len(running()) < self.workers and (job := next(jobs, None)) is not None:
                window.append(self._urgent.submit(tasks.simulate, job.target, job.params, job.seed))

        try:
            fill()
            while window:
                while not window[0].future.done():
                    wait(running(), return_when=FIRST_COMPLETED)
                    fill()
                rollout = window.popleft().future.result()
                yield rollout
                fill()
        finally:
            for task in window:  # queued behind a render, not started: dropped (a started one runs to its end)
                task.cancel()

    def render(self, job: RenderJob, urgent: bool = True) -> Task:
        """The clip's parts on the pool's workers at once, joined on one of them."""
        pool = self._urgent if urgent else self._background
        parts = [pool.submit(tasks.render_clip, p.target, p.rollout, p.width, p.height, p.rows) for p in job.parts()]
        return joined(parts, lambda clips: pool.submit(tasks.join_clips, *clips))

    def clip_data(self, job: DataJob, urgent: bool = True) -> Task:
        return (self._urgent if urgent else self._background).submit(tasks.clip_data, job.target, job.width,
                                                                      job.height, job.rollout)

    def warm(self, target: str) -> None:
        """Start the urgent workers, importing ``target`` in each: the first clip's parts render on all of them
        (submitted together, the tasks start one process each; the guess pool starts when needed)."""
        for _ in range(self.workers):
            self._urgent.submit(tasks.warm, target)

    def close(self) -> None:
        for pool in (self._urgent, self._background):
            pool.close()
