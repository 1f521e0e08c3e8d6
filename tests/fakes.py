"""Test doubles behind the library's small interfaces."""

from __future__ import annotations

import threading
import time
from concurrent.futures import Future

from rba.compute import Compute, DataJob, RenderJob, SimJob, Task
from rba.compute.tasks import describe
from rba.generate.cma import in_process


class FakeCompute(Compute):
    """Records render jobs; the test completes their futures by hand (``submitted``: (urgent, future))."""

    name = "fake"
    prioritised = True

    def __init__(self) -> None:
        self.submitted: list[tuple[bool, Future]] = []
        self.jobs: list[RenderJob] = []
        self.data_jobs: list[tuple[DataJob, Future, str]] = []  # clip data asked for: job, future, asking thread
        self._cond = threading.Condition()

    @property
    def capacity(self) -> int:
        return 1

    def simulate(self, jobs):
        raise NotImplementedError

    def render(self, job: RenderJob, urgent: bool = True) -> Task:
        future: Future = Future()
        with self._cond:
            self.submitted.append((urgent, future))
            self.jobs.append(job)
            self._cond.notify_all()
        return Task(future, future.cancel, future.running)  # a test starts it: set_running_or_notify_cancel

    def next_rollout(self, timeout: float) -> str:
        """Wait for the next job after those already seen by this method; its rollout id."""
        with self._cond:
            seen = getattr(self, "_seen", 0)
            if not self._cond.wait_for(lambda: len(self.jobs) > seen, timeout):
                raise TimeoutError("no render was submitted")
            self._seen = seen + 1
            return self.jobs[seen].rollout.id

    def clip_data(self, job: DataJob, urgent: bool = True) -> Task:
        future: Future = Future()
        self.data_jobs.append((job, future, threading.current_thread().name))
        return Task(future, future.cancel, future.running)

    def warm(self, target: str) -> None:
        pass

    def close(self) -> None:
        pass


class InstantCompute(FakeCompute):
    """Every render is done at once (a few bytes stand for the MP4): nothing waits for a render."""

    CLIP = b"\x00\x00\x00\x18ftypmp42 not a real clip"

    def render(self, job: RenderJob, urgent: bool = True) -> Task:
        task = super().render(job, urgent)
        task.future.set_result(self.CLIP)
        return task

    def clip_data(self, job: DataJob, urgent: bool = True) -> Task:
        """The real data, computed at once in this process (``NoClipData`` for a domain without any)."""
        task = super().clip_data(job, urgent)
        try:
            task.future.set_result(describe(job.target, job.width, job.height, job.rollout))
        except Exception as exc:
            task.future.set_exception(exc)
        return task


class InProcessCompute(InstantCompute):
    """Simulates in this process, ``delay`` seconds a batch (searches for new behaviours run as slowly as a test
    needs to watch them); renders at once (``InstantCompute``), or real clips on ``renders``."""

    def __init__(self, delay: float = 0.0, renders: Compute | None = None) -> None:
        super().__init__()
        self.delay, self.renders = delay, renders
        self.batches = 0

    def render(self, job: RenderJob, urgent: bool = True) -> Task:
        return super().render(job, urgent) if self.renders is None else self.renders.render(job, urgent)

    def simulate(self, jobs):
        from rba.generate.cma import in_process

        self.batches += 1
        time.sleep(self.delay)
        return list(in_process(jobs))


def recording_simulator(jobs: list[SimJob]):
    """A simulator (``rba.generate.cma.Simulate``) that records every job it is given: what a search really asked
    for."""
    def simulate(batch):
        batch = list(batch)
        jobs.extend(batch)
        return in_process(batch)
    return simulate
