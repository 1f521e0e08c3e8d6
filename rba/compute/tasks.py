"""What runs inside a compute worker (a pool process or a Ray worker): simulate, render, and the worker's set-up.

Workers are long-lived: a domain is imported once per worker (``load_domain`` caches it) and its
off-screen renderers are made once per worker thread and reused for every clip.
"""

from __future__ import annotations

import contextlib
import functools
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from rba.domains import Rollout, load_domain
from rba.domains.base import ALL_FRAMES, Domain

if TYPE_CHECKING:
    from rba.compute.base import RenderJob

TEMP_PREFIX = "rba-clip-"
STALE_TEMP_SECONDS = 600  # a render takes seconds: older temporaries were left by a killed worker
PARENT_POLL_SECONDS = 1.0  # how often a worker checks that the process that started it is alive
_ready = False  # this process was set up as a worker


def init_worker(nice: int = 0, render_threads: int = 1) -> None:
    """Lower this worker's priority below the API's, render off-screen, and fix the worker's thread counts.

    One thread for torch and BLAS, and ``render_threads`` for Mesa's software rasteriser: guesses and
    Ray tasks run one worker per CPU, so more threads would only fight over the cores; the pool for the
    clip a person waits for shares the cores among its workers (a clip's parts render on all of them).
    Rendered pixels do not depend on the rasteriser's thread count, and the encoder's is fixed
    (``rba.media.video``), so clips are identical whatever the machine.
    """
    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    os.environ.setdefault("LP_NUM_THREADS", str(render_threads))  # Mesa llvmpipe
    global _ready
    lower_priority(nice)
    sweep_temporaries()
    # a pool killed outright (SIGKILL, OOM) never shuts its workers down: they would idle on, holding their models
    watch_parent(os.getppid(), lambda: os._exit(0), PARENT_POLL_SECONDS)
    _ready = True


def lower_priority(nice: int) -> None:
    """Raise this process's niceness by ``nice``: its work then yields the CPU to the API's requests."""
    if nice:
        with contextlib.suppress(OSError):  # not allowed to lower it further: run as we are
            os.nice(nice)


def watch_parent(parent_pid: int, on_gone: Callable[[], None], poll: float) -> None:
    """Call ``on_gone`` (in a daemon thread) once ``parent_pid`` is no longer this process's parent: it died and
    this process was handed to another. Compute workers exit so; the server's training jobs stop their group."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(poll)
        on_gone()

    threading.Thread(target=watch, name="rba-parent-watch", daemon=True).start()


def _prepare() -> None:
    """Ray workers run no initializer: the first task of each does it."""
    if not _ready:
        init_worker()


def sweep_temporaries(older_than: float = STALE_TEMP_SECONDS) -> int:
    """Remove what killed workers left in the temp folder; returns how many folders went."""
    cutoff, removed = time.time() - older_than, 0
    for folder in Path(tempfile.gettempdir()).glob(f"{TEMP_PREFIX}*"):
        try:
            if folder.stat().st_mtime < cutoff:
                shutil.rmtree(folder)
                removed += 1
        except OSError:
            pass
    return removed


def simulate(target: str, params: dict[str, float], seed: int) -> Rollout:
    _prepare()
    return load_domain(target).rollout(params, seed)


def simulate_many(targets: list[str], params: list[dict[str, float]], seeds: list[int]) -> list[Rollout]:
    """Several rollouts in one task (a chunk of a library: ``sim_chunk``), in order."""
    return [simulate(t, p, s) for t, p, s in zip(targets, params, seeds, strict=True)]


def render_clip(target: str, rollout: Rollout, width: int, height: int, rows: tuple[int, int] | None = None) -> bytes:
    """The MP4 of ``rollout`` (or of its replay rows [start, stop): a part, ``RenderJob.parts``), as bytes (H.264,
    see ``rba.media.video``): the caller stores it where it belongs."""
    _prepare()
    return _encode(load_domain(target), rollout, width, height, ALL_FRAMES if rows is None else slice(*rows))


def join_clips(*parts: bytes) -> bytes:
    """One clip of its parts' MP4s, in order (``rba.media.video.concat_mp4``)."""
    from rba.media.video import concat_mp4

    _prepare()
    return concat_mp4(list(parts))


def render_here(job: RenderJob) -> bytes:
    """A whole job in this process, part after part, joined: the bytes a backend gives for it (``Compute.render``),
    for a process that caches clips under the app's keys without a compute layer (``rba export``)."""
    return join_clips(*(render_clip(p.target, p.rollout, p.width, p.height, p.rows) for p in job.parts()))


def _encode(domain: Domain, rollout: Rollout, width: int, height: int, frames: slice) -> bytes:
    from rba.media.video import encode_mp4

    folder = Path(tempfile.mkdtemp(prefix=TEMP_PREFIX))
    try:
        path = folder / "clip.mp4"
        encode_mp4(domain.render(rollout, width, height, frames), path, domain.frame_rate)
        return path.read_bytes()
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def clip_data(target: str, width: int, height: int, rollout: Rollout | None = None) -> bytes:
    """The gzipped JSON of ``rollout``'s clip data, or of the domain's scene when ``rollout`` is None
    (``rba.media.clip_data``); ``NoClipData`` for a domain whose clips are MP4s only."""
    _prepare()
    return describe(target, width, height, rollout)


def describe(target: str, width: int, height: int, rollout: Rollout | None = None) -> bytes:
    """``clip_data`` in this process as it is (no worker set-up): for a process without a compute layer."""
    from rba.media import clip_data as data

    scene = _scene(target, width, height)
    return data.encode(scene if rollout is None else data.clip(load_domain(target), rollout, scene["version"]))


@functools.cache
def _scene(target: str, width: int, height: int) -> dict:
    """The domain's scene, once per worker: every clip of it names the scene's version."""
    from rba.media import clip_data as data

    return data.scene(load_domain(target), width, height)


def warm(target: str) -> float:
    """Import ``target`` in this worker (the simulator's import is most of a cold worker's first task)."""
    start = time.perf_counter()
    _prepare()
    load_domain(target)
    return time.perf_counter() - start
