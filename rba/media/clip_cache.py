"""The clip cache: MP4s rendered on the compute layer, stored content-addressed and atomically in a ``ClipStore``.

A clip's data (``rba.media.clip_data``: the poses the page draws itself) is cached alike under the same key of
another ``kind``, and a domain's scene, which every clip's data names, is kept in memory once made.

A clip's key is (domain, library version, rollout id, size); the store names its file from the
key's hash, so any number of API replicas can share one cache folder: a clip two of them render
at once is written twice with the same bytes, and readers never see half a file. Within one
process each key renders once however many ask (``request`` returns the render in flight).
"""

from __future__ import annotations

import hashlib
import logging
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import Future, wait
from dataclasses import dataclass, field, replace
from pathlib import Path

from rba.compute import Compute, DataJob, RenderJob, Task
from rba.compute.base import settle
from rba.core.store import ClipStore
from rba.data.library import SkillLibrary
from rba.domains import Rollout
from rba.media.clip_data import DATA_VERSION, decode

log = logging.getLogger(__name__)

STALE_TMP_SECONDS = 600
# Part of every clip's key: bump it when rendering or encoding changes what a clip looks like, so a cache
# filled before never mixes old clips with new ones (2: snake floor without reflection, one x264 thread). Not
# bumped for generated clips encoded in ``rba.compute.base.CLIP_PARTS`` parts: the same frames, and library clips,
# nearly all of a cache, are the same bytes as before.
RENDERER_VERSION = 2
MP4, DATA = "mp4", "data"  # the kinds of a clip's files (``ClipKey.kind``)
CLAIM_TTL_SECONDS = 120  # a guess claimed longer ago than this was left by a crashed process: render it here
Source = SkillLibrary | Rollout  # what a clip is rendered from: a library holding the rollout, or the rollout


@dataclass(frozen=True)
class ClipKey:
    """A clip's name in the store. Keys are made by ``server.runtime.clip_sources`` (and ``ClipCache.key`` for a
    library's clips): what a rollout id names is decided there, never here."""

    domain: str
    version: str  # the serve library's content hash, or the made clips' own version (their ids hash what makes them)
    rollout_id: str  # already looked up where it comes from
    width: int
    height: int
    # parts its render is split into on separate workers (a clip someone waits for); not in the digest: a key's
    # parts never change, and the joined MP4 differs from one encoded whole, so one key is always rendered alike
    parts: int = 1
    kind: str = MP4  # MP4: the video; DATA: the clip's data (gzipped JSON), computed not rendered

    @property
    def digest(self) -> str:
        raw = f"{self.domain}\0{self.version}\0{self.rollout_id}\0{self.width}x{self.height}\0{RENDERER_VERSION}"
        if self.kind != MP4:  # an MP4's digest is as it always was: stores keep their files
            raw += f"\0{self.kind}\0{DATA_VERSION}"
        return hashlib.sha256(raw.encode()).hexdigest()[:24]

    @property
    def suffix(self) -> str:
        return ".mp4" if self.kind == MP4 else ".json.gz"

    def data(self) -> ClipKey:
        """The key of this clip's data."""
        return replace(self, kind=DATA, parts=1)

    @property
    def etag(self) -> str:
        return f'"{self.digest}"'


@dataclass(frozen=True)
class ClipStatus:
    """Where a clip is, for a person waiting on it: coarse, but real."""

    state: str  # "ready" (stored), "queued" (waiting for a worker), "rendering", or "absent" (nobody asked yet)
    elapsed: float | None = None  # seconds since the render was submitted
    typical: float | None = None  # mean seconds of this domain's renders in this process (None before the first)


@dataclass
class _Render:
    """A render in flight: the compute task and the future of the stored file."""

    task: Task
    urgent: bool
    done: Future = field(default_factory=Future)
    started: float = field(default_factory=time.perf_counter)
    path: Path | None = None  # set once the clip is stored
    error: BaseException | None = None  # storing it failed


def render_job(key: ClipKey, source: Source) -> RenderJob:
    """What renders ``key``'s clip: in ``key.parts`` parts. The parts' joined MP4 differs in bytes from one encoded
    whole, so whatever caches under a key renders this."""
    return RenderJob.of(key.domain, _rollout(key, source), key.width, key.height, split=key.parts)


def _rollout(key: ClipKey, source: Source) -> Rollout:
    return source if isinstance(source, Rollout) else source.rollout(source.index_of(key.rollout_id))


@dataclass(frozen=True)
class Scene:
    """A domain's scene for the page (``rba.media.clip_data.scene``): its gzipped JSON and its version."""

    body: bytes
    version: str


class ClipCache:
    """Rendered clips in a ``ClipStore``; ``request`` renders what is missing on ``compute``."""

    def __init__(self, store: ClipStore, compute: Compute, width: int, height: int) -> None:
        self.store, self.compute = store, compute
        self.width, self.height = width, height
        self._lock = threading.RLock()  # a cancelled render's callback runs in the canceller's thread
        self._inflight: dict[ClipKey, _Render] = {}
        self.renders = 0  # clips rendered for this process (tests and benchmarks read it)
        self.described = 0  # clips' data computed for this process
        self._scenes: dict[str, Future] = {}  # domain -> its Scene, made once per process
        self.render_seconds = 0.0
        self._domain_seconds: dict[str, tuple[int, float]] = {}  # domain -> (renders, seconds): the typical time
        store.sweep(STALE_TMP_SECONDS)  # renders cut short by a crash leave temporaries; old ones are garbage

    def key(self, library: SkillLibrary, rollout_id: str) -> ClipKey:
        """The key of a rollout that is in ``library`` (KeyError otherwise)."""
        library.index_of(rollout_id)
        return ClipKey(library.domain, library.version, rollout_id, self.width, self.height)

    def path(self, key: ClipKey) -> Path:
        return self.store.path(key)

    def cached(self, key: ClipKey) -> bool:
        return self.store.exists(key)

    def pending(self, key: ClipKey) -> bool:
        with self._lock:
            return key in self._inflight

    def typical_seconds(self, domain: str) -> float | None:
        """Mean seconds a clip of ``domain`` took from submission to stored, in this process."""
        with self._lock:
            n, total = self._domain_seconds.get(domain, (0, 0.0))
        return total / n if n else None

    def status(self, key: ClipKey) -> ClipStatus:
        """Stored, queued or rendering (with elapsed and typical seconds), or absent."""
        typical = self.typical_seconds(key.domain)
        with self._lock:
            render = self._inflight.get(key)
        if render is None:
            return ClipStatus("ready" if self.store.exists(key) else "absent", typical=typical)
        running = render.task.running
        state = "rendering" if running is None or running() else "queued"
        return ClipStatus(state, time.perf_counter() - render.started, typical)

    def wait_idle(self, timeout: float) -> bool:
        """True once no render of this cache is in flight (tests and benchmarks use it)."""
        with self._lock:
            futures = [r.done for r in self._inflight.values()]
        return not wait(futures, timeout).not_done

    def request(self, key: ClipKey, source: Source | None, urgent: bool = True) -> Future:
        """A future of the clip's stored file: done at once if cached, else the render in flight or a new one.
        ``source`` may be None only for a key known to be stored (a made clip's rollout is not simulated for it).

        An urgent request for a clip queued as a guess moves it to the urgent queue when the backend has one.
        A guess (``urgent=False``) another process sharing the store has claimed resolves to ``None`` at once:
        replicas split the guesses instead of rendering each twice.
        """
        done: Future = Future()
        if self.store.exists(key):
            done.set_result(self.store.path(key))
            return done
        with self._lock:
            if not urgent and key not in self._inflight and not self.store.claim(key, CLAIM_TTL_SECONDS):
                done.set_result(None)  # another process sharing the store renders this guess
                return done
            render = self._inflight.get(key)
            upgrade = render is not None and urgent and not render.urgent and self.compute.prioritised
            if upgrade and render.task.cancel():
                render = None  # dropped before it started: submit it again as urgent
            if render is None:
                render = self._submit(key, source, urgent)
            return render.done

    def _submit(self, key: ClipKey, source: Source, urgent: bool) -> _Render:
        if key.kind == DATA:
            task = self.compute.clip_data(DataJob.of(key.domain, _rollout(key, source), key.width, key.height), urgent)
        else:
            task = self.compute.render(render_job(key, source), urgent)
        render = _Render(task, urgent)
        self._inflight[key] = render
        render.task.future.add_done_callback(lambda f: self._finish(key, render, f))
        return render

    def _finish(self, key: ClipKey, render: _Render, result: Future) -> None:
        try:
            self._store_result(key, render, result)
        finally:  # only now, with the file written, may a new request for the key miss the render in flight
            with self._lock:
                if self._inflight.get(key) is render:
                    del self._inflight[key]
            if not render.urgent:
                self.store.release(key)
        self._settle(key, render, result)

    def _store_result(self, key: ClipKey, render: _Render, result: Future) -> None:
        if result.cancelled() or result.exception() is not None:
            return
        data = result.result()
        try:
            self.store.write(key, lambda tmp: tmp.write_bytes(data))
        except Exception as exc:  # reported to every waiter by _settle
            render.error = exc
            return
        render.path = self.store.path(key)
        seconds = time.perf_counter() - render.started
        if key.kind == DATA:
            with self._lock:
                self.described += 1
            return
        with self._lock:
            self.renders += 1
            self.render_seconds += seconds
            n, total = self._domain_seconds.get(key.domain, (0, 0.0))
            self._domain_seconds[key.domain] = (n + 1, total + seconds)
        log.info("rendered %s/%s (%d kB%s) in %.2f s", key.domain, key.rollout_id, len(data) // 1024,
                 "" if render.urgent else ", background", seconds)

    @staticmethod
    def _settle(key: ClipKey, render: _Render, result: Future) -> None:
        """Tell every waiter: the stored file, the render's failure, or cancelled."""
        if result.cancelled():
            render.done.cancel()
            return
        error = result.exception() or render.error
        if error is not None:  # the render's failure is the requester's: every waiter sees it
            log.warning("render of %s/%s failed: %s", key.domain, key.rollout_id, error)
            render.done.set_exception(error)
        else:
            render.done.set_result(render.path)

    def scene(self, domain: str) -> Future:
        """A future of the domain's ``Scene``, computed once on the compute layer (again after a failure)."""
        with self._lock:
            made = self._scenes.get(domain)
            if made is not None and not (made.done() and (made.cancelled() or made.exception() is not None)):
                return made
            scene: Future = Future()
            self._scenes[domain] = scene
        task = self.compute.clip_data(DataJob.of(domain, None, self.width, self.height))
        task.future.add_done_callback(lambda f: settle(f, scene, lambda body: Scene(body, decode(body)["version"])))
        return scene

    def fill(self, keys: Iterable[tuple[ClipKey, SkillLibrary]], window: int | None = None,
             stop: Callable[[], bool] = lambda: False, on_done: Callable[[ClipKey, bool], None] = lambda k, r: None,
             ) -> int:
        """Render every uncached clip of ``keys`` as guesses, at most ``window`` at a time (default: the
        backend's capacity), in order; ``on_done(key, rendered)`` after each. Returns how many were rendered."""
        window = window or self.compute.capacity
        running: dict[Future, ClipKey] = {}
        rendered = 0

        def drain(until: str) -> None:
            nonlocal rendered
            done, _ = wait(list(running), return_when=until)
            for f in done:
                key = running.pop(f)
                ok = not f.cancelled() and f.exception() is None and f.result() is not None
                rendered += ok
                on_done(key, ok)

        for key, library in keys:
            if stop():
                break
            if self.store.exists(key) and not self.pending(key):
                on_done(key, False)
                continue
            running[self.request(key, library, urgent=False)] = key
            while len(running) >= window:
                drain("FIRST_COMPLETED")
        if running:
            drain("ALL_COMPLETED")
        return rendered
