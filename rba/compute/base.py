"""The compute layer's interface (ARCHITECTURE §9): jobs, tasks and the ``Compute`` backend contract."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future
from dataclasses import dataclass

import numpy as np

from rba.domains import Rollout, domain_target


@dataclass(frozen=True)
class SimJob:
    """Simulate one rollout: ``load_domain(target).rollout(params, seed)``."""

    target: str  # the domain's "module:Class"
    params: dict[str, float]
    seed: int


@dataclass(frozen=True)
class RenderJob:
    """Render one rollout's replay to MP4 bytes at ``width`` x ``height``."""

    target: str
    rollout: Rollout  # only ``replay`` (and the ids) are read; ``for_render`` drops the states
    width: int
    height: int

    @classmethod
    def of(cls, domain: str, rollout: Rollout, width: int, height: int) -> RenderJob:
        return cls(domain_target(domain), for_render(rollout), int(width), int(height))


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
        """Each job's rollout, in the jobs' order, as they finish (a library build streams through this)."""

    @abstractmethod
    def render(self, job: RenderJob, urgent: bool = True) -> Task:
        """Start rendering; the future's result is the MP4's bytes. ``urgent``: a person is waiting for it."""

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
