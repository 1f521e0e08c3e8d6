"""The compute layer (docs/architecture.md §9): every simulation and every render runs here, never in the API process.

One small interface, :class:`Compute`, with two backends:

- ``LocalCompute`` (the default): process pools on this machine, niced below the API, one pool for
  what a person waits for and one, niced further, for guesses (prerender, ``rba cache``);
- ``RayCompute`` (``RBA_RAY_ADDRESS`` / ``--ray ADDRESS``): Ray tasks on a cluster. Ray's scheduler,
  object store and retries do the distribution; a task whose worker dies is run again.

Both run the same task functions (``rba.compute.tasks``), so the same job gives byte-identical
rollouts and clips on either backend. Jobs name their domain by import path (``"module:Class"``),
so domains registered at run time work in any worker.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

from rba.compute.base import Compute, DataJob, RenderJob, SimJob, Task, for_render
from rba.core.settings import LibrarySettings

__all__ = ["Compute", "DataJob", "RenderJob", "SimJob", "Task", "for_render", "make_compute", "simulation_pool"]


def make_compute(settings: LibrarySettings | None = None, ray_address: str | None = None) -> Compute:
    """The backend ``settings`` ask for (``ray_address`` overrides theirs, as ``--ray`` does): Ray when an
    address is given (``auto``: the running cluster; ``local``: a private Ray on this machine; ``host:port``
    or ``ray://host:port``: that cluster), else the local pools."""
    s = settings or LibrarySettings()
    address = ray_address or s.ray_address
    if address:
        from rba.compute.ray_backend import RayCompute

        return RayCompute(address)
    from rba.compute.local import LocalCompute

    return LocalCompute(s.compute_workers, s.compute_nice, s.background_nice)


@contextmanager
def simulation_pool(workers: int) -> Iterator[Callable | None]:
    """``Compute.simulate`` of ``workers`` local processes for a search's candidates (closed on exit), or None for
    one worker: the caller simulates in its own process. Benchmarks' ``--gen-workers``; the rows do not depend on it."""
    if workers < 2:
        yield None
        return
    compute = make_compute(LibrarySettings(compute_workers=workers))
    try:
        yield compute.simulate
    finally:
        compute.close()
