"""The compute layer's interface (docs/architecture.md §9): jobs, tasks and the ``Compute`` backend contract."""

from __future__ import annotations

import itertools
import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import CancelledError, Future
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rba.domains import Rollout, domain_target


@dataclass(frozen=True)
class SimJob:
    """Simulate one rollout: ``load_domain(target).rollout(params, seed)``."""

    target: str  # the domain's "module:Class"
    params: dict[str, float]
    seed: int


# A generated clip is rendered and encoded in this many parts, each on its own worker, then joined
# (``rba.media.video.concat_mp4``): someone always waits for it (right after its search), and so it renders on both
# cores of a 2-core machine. A library clip renders whole: most are rendered ahead as guesses, where parts cost
# throughput (a second encoder and the join: with ten users fewer clips were ready in time, ``api_load_cold.md``).
# Fixed per kind of clip, never by the machine or the urgency: the parts decide the bytes, and a clip's ETag promises
# them.
CLIP_PARTS = 2
SIM_CHUNK = 4  # rollouts per task at most when simulating a library


def sim_chunk(jobs: int, workers: int) -> int:
    """Rollouts per task for ``jobs`` simulations on ``workers``: up to ``SIM_CHUNK`` for a library, where each
    task's round trip would cost a share of a ~50 ms rollout (on Ray, the scheduler shares the cores); 1 for a
    search's few candidates, whose simulations differ in length (a chunk of slow ones on one worker would keep
    the other idle)."""
    return max(1, min(SIM_CHUNK, jobs // (SIM_CHUNK * workers)))


@dataclass(frozen=True)
class RenderJob:
    """Render one rollout's replay (or its rows ``rows``: a part of the clip) to MP4 bytes at ``width`` x ``height``."""

    target: str
    rollout: Rollout  # only ``replay`` (and the ids) are read; ``for_render`` drops the states
    width: int
    height: int
    rows: tuple[int, int] | None = None  # [start, stop) of the replay's rows; None: all of them
    split: int = 1  # parts the clip is rendered in (CLIP_PARTS for a generated clip)

    @classmethod
    def of(cls, domain: str, rollout: Rollout, width: int, height: int, split: int = 1) -> RenderJob:
        return cls(domain_target(domain), for_render(rollout), int(width), int(height), split=split)

    def parts(self) -> list[RenderJob]:
        """The clip in ``split`` consecutive parts of (nearly) equal length; fewer if it has fewer frames."""
        frames = len(self.rollout.replay)
        n = max(1, min(self.split, frames))
        cuts = [frames * i // n for i in range(n + 1)]
        return [replace(self, rows=(a, b)) for a, b in itertools.pairwise(cuts)]


@dataclass(frozen=True)
class DataJob:
    """Describe a clip as data the page draws itself (``rba.media.clip_data``), as gzipped JSON bytes: one
    rollout's per-frame poses, or the domain's scene (``rollout`` None) for clips ``width`` x ``height``."""

    target: str
    width: int
    height: int
    rollout: Rollout | None = None  # only ``replay``, ``proxies`` and the ids are read (``for_render``)

    @classmethod
    def of(cls, domain: str, rollout: Rollout | None, width: int, height: int) -> DataJob:
        return cls(domain_target(domain), int(width), int(height), None if rollout is None else for_render(rollout))


def for_render(rollout: Rollout) -> Rollout:
    """The rollout without what rendering never reads (states): less to ship to a worker."""
    return Rollout(rollout.id, rollout.domain, dict(rollout.params), rollout.seed,
                   np.zeros((0, 0), np.float32), np.ascontiguousarray(rollout.replay), dict(rollout.proxies),
                   rollout.success)


@dataclass
class Task:
    """A submitted job: its result as a ``concurrent.futures.Future`` and a way to drop it if not started."""

    future: Future
    cancel: Callable[[], bool]
    running: Callable[[], bool] | None = None  # started on a worker (None: the backend cannot tell)


def joined(parts: list[Task], join: Callable[[list], Task]) -> Task:
    """One task of several: once every part is in, ``join(results)`` (a task itself) makes the result.

    It fails with the first part that fails (the others are dropped if not started), and is cancelled if a
    part is: cancelling it cancels every part, and the join, not yet started (True if any was), so a clip is
    never joined from fewer parts than it has. Its future is settled outside any lock of ours: its callbacks
    (the clip cache's) take their own locks, and a canceller may hold those already.
    """
    if len(parts) == 1:
        return parts[0]
    outer: Future = Future()
    lock = threading.Lock()
    decided: list[bool] = []  # one entry once the outcome is someone's to set
    tail: list[Task] = []  # the join's task, once submitted

    def claim() -> bool:
        with lock:
            first = not decided
            decided.append(True)
            return first

    def part_done(_: Future) -> None:
        futures = [p.future for p in parts]
        if any(f.cancelled() for f in futures):
            if claim():
                outer.cancel()
        elif failed := next((f.exception() for f in futures if f.done() and f.exception() is not None), None):
            if claim():
                outer.set_exception(failed)
                for p in parts:
                    p.cancel()
        elif all(f.done() for f in futures) and claim():
            try:
                tail.append(join([f.result() for f in futures]))
            except CancelledError:  # a part was cancelled after the check above
                outer.cancel()
                return
            except Exception as exc:
                outer.set_exception(exc)
                return
            tail[0].future.add_done_callback(lambda f: settle(f, outer))

    for part in parts:
        part.future.add_done_callback(part_done)
    return Task(outer, lambda: any([t.cancel() for t in [*parts, *tail]]),  # a list: try every one
                lambda: any(t.running is None or t.running() for t in [*parts, *tail]))


def settle(source: Future, target: Future, result: Callable[[Any], Any] = lambda x: x) -> None:
    """``target`` ends as the finished ``source`` did: cancelled, failed, or with ``result`` of its result."""
    if source.cancelled():
        target.cancel()
    elif source.exception() is not None:
        target.set_exception(source.exception())
    else:
        target.set_result(result(source.result()))


class Compute(ABC):
    """Where rollouts are simulated and clips rendered."""

    name: str
    prioritised: bool  # urgent renders overtake guesses that have not started (a guess can be moved up)

    @property
    @abstractmethod
    def capacity(self) -> int:
        """How many tasks run at once (worker processes, or the cluster's CPUs)."""

    @abstractmethod
    def simulate(self, jobs: Iterable[SimJob]) -> Iterator[Rollout]:
        """Each job's rollout, in the jobs' order, as they finish (a library build streams through this). A backend
        may take the jobs only as it has room for them (``LocalCompute``: a search's), so an iterator of jobs that
        stops early (a search out of time) starts no more."""

    @abstractmethod
    def render(self, job: RenderJob, urgent: bool = True) -> Task:
        """Start rendering; the future's result is the MP4's bytes. ``urgent``: a person is waiting for it."""

    @abstractmethod
    def clip_data(self, job: DataJob, urgent: bool = True) -> Task:
        """Start describing a clip as data; the future's result is its gzipped JSON. ``urgent``: a person waits."""

    @abstractmethod
    def warm(self, target: str) -> None:
        """Start workers and import the domain at ``target`` in them, not waiting (the first clip comes sooner)."""

    @abstractmethod
    def close(self) -> None:
        """Stop the workers (a Ray cluster itself keeps running)."""

    def __enter__(self) -> Compute:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
