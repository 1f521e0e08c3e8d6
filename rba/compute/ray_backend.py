"""The distributed backend: the same tasks as Ray remote functions on a cluster.

Ray does the distribution: its scheduler places tasks on nodes with a free CPU, results travel
through its object store, and a task whose worker or node dies is run again (``max_retries``).
Clips come back as bytes and the caller stores them (atomically, content-addressed), so workers
need the code and the libraries' replay data they are sent, not the clip volume.
"""

from __future__ import annotations

import logging
import os
import sys
from collections import deque
from collections.abc import Iterable, Iterator

from rba.compute import tasks
from rba.compute.base import Compute, DataJob, RenderJob, SimJob, Task, sim_chunk
from rba.domains import Rollout

log = logging.getLogger(__name__)
MAX_RETRIES = 3  # runs of a task after its worker died
SIM_WINDOW = 256  # simulations in flight at once: a 100,000-rollout build does not submit everything at once
FORWARDED_ENV = ("MUJOCO_GL", "SDL_VIDEODRIVER", "HF_HUB_OFFLINE")


def worker_env() -> dict[str, str]:
    """What a worker needs from this process's environment: settings (``RBA_*``), renderers, import path."""
    env = {k: v for k, v in os.environ.items() if k.startswith("RBA_") or k in FORWARDED_ENV}
    env.setdefault("MUJOCO_GL", "egl")
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p and os.path.isdir(p))
    return env


class RayCompute(Compute):
    name = "ray"
    prioritised = False  # Ray runs tasks in the order they can be placed

    def __init__(self, address: str) -> None:
        import ray

        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        self._ray = ray
        if not ray.is_initialized():
            ray.init(address=None if address == "local" else address, log_to_driver=False,
                     runtime_env={"env_vars": worker_env()}, logging_level=logging.WARNING)
        remote = ray.remote(num_cpus=1, max_retries=MAX_RETRIES)
        self._simulate = remote(tasks.simulate_many)
        self._render = remote(tasks.render_clip)
        self._join = remote(tasks.join_clips)
        self._data = remote(tasks.clip_data)
        self._warm = remote(tasks.warm)
        log.info("compute: Ray cluster with %d CPUs", self.capacity)

    @property
    def capacity(self) -> int:
        return max(int(self._ray.cluster_resources().get("CPU", 1)), 1)

    def simulate(self, jobs: Iterable[SimJob]) -> Iterator[Rollout]:
        """In order, in tasks of ``sim_chunk`` rollouts, keeping at most ``SIM_WINDOW`` rollouts in flight (the
        object store holds their results)."""
        jobs = list(jobs)
        size = sim_chunk(len(jobs), self.capacity)
        pending: deque = deque()
        for i in range(0, len(jobs), size):
            chunk = jobs[i:i + size]
            pending.append(self._simulate.remote([j.target for j in chunk], [j.params for j in chunk],
                                                 [j.seed for j in chunk]))
            if len(pending) * size >= SIM_WINDOW:
                yield from self._ray.get(pending.popleft())
        for ref in pending:
            yield from self._ray.get(ref)

    def render(self, job: RenderJob, urgent: bool = True) -> Task:
        """Ray has no task priorities: callers keep guesses few in flight, so a person's clip is next in line."""
        parts = [self._render.remote(p.target, p.rollout, p.width, p.height, p.rows) for p in job.parts()]
        ref = self._join.remote(*parts) if len(parts) > 1 else parts[0]  # Ray hands it the parts' bytes
        future = ref.future()

        def cancel() -> bool:  # a pending task is dropped; a running one is interrupted (its future then fails)
            for r in [*parts, ref]:
                self._ray.cancel(r)
            return True

        return Task(future, cancel)

    def clip_data(self, job: DataJob, urgent: bool = True) -> Task:
        ref = self._data.remote(job.target, job.width, job.height, job.rollout)
        return Task(ref.future(), lambda: self._ray.cancel(ref) or True)

    def warm(self, target: str) -> None:
        for _ in range(self.capacity):
            self._warm.remote(target)

    def close(self) -> None:
        if self._ray.is_initialized():
            self._ray.shutdown()
