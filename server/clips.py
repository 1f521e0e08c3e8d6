"""The clip cache: MP4s rendered off-screen on first request and kept on disk.

A clip's key is (domain, library version, rollout id, size). File names are built from
validated parts and a hash of the key, never from user text. Each key has a lock, so two
requests for the same uncached clip render it once; a semaphore bounds how many requested
clips render at the same time, and background renders give way to them.
"""

from __future__ import annotations

import hashlib
import logging
import re
import threading
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rba.domains import get_domain
from rba.library import SkillLibrary
from rba.video import write_mp4
from server.locks import KeyedLocks

log = logging.getLogger(__name__)

_SAFE = re.compile(r"^[a-z0-9_]{1,64}$")
_HEX = re.compile(r"^[0-9a-f]{1,64}$")
STALE_TMP_SECONDS = 600
PAUSE_CHECK_SECONDS = 0.5  # a paused background render re-checks this often (and on every change)


@dataclass(frozen=True)
class ClipKey:
    domain: str
    version: str  # the serve library's content hash
    rollout_id: str  # already looked up in the library
    width: int
    height: int

    @property
    def digest(self) -> str:
        raw = f"{self.domain}\0{self.version}\0{self.rollout_id}\0{self.width}x{self.height}"
        return hashlib.sha256(raw.encode()).hexdigest()[:24]

    @property
    def etag(self) -> str:
        return f'"{self.digest}"'


class ClipCache:
    """Rendered clips under ``root/<domain>/<digest>.mp4``; ``get`` renders when missing.

    Renders a person is waiting for come first: a background (speculative) render pauses
    between frames while any requested render runs, unless someone is waiting for its clip.
    """

    def __init__(self, root: Path, width: int, height: int, concurrency: int = 2) -> None:
        self.root = root
        self.width, self.height = width, height
        self._locks = KeyedLocks()
        self._slots = threading.BoundedSemaphore(concurrency)
        self._cond = threading.Condition()
        self._urgent = 0  # requested renders running now
        self._wanted: Counter[ClipKey] = Counter()  # clips requests are waiting for
        self.renders = 0  # clips rendered by this process (tests and benchmarks read it)
        self.render_seconds = 0.0
        root.mkdir(parents=True, exist_ok=True)
        self._remove_stale_temporaries()

    def key(self, library: SkillLibrary, rollout_id: str) -> ClipKey:
        """The key of a rollout that is in ``library`` (KeyError otherwise)."""
        library.index_of(rollout_id)
        return ClipKey(library.domain, library.version, rollout_id, self.width, self.height)

    def path(self, key: ClipKey) -> Path:
        domain = key.domain if _SAFE.match(key.domain) else hashlib.sha256(key.domain.encode()).hexdigest()[:16]
        version = key.version if _HEX.match(key.version) else hashlib.sha256(key.version.encode()).hexdigest()[:12]
        return self.root / domain / f"{version}-{key.digest}-{key.width}x{key.height}.mp4"

    def cached(self, key: ClipKey) -> bool:
        return self.path(key).exists()

    def get(self, key: ClipKey, library: SkillLibrary, background: bool = False) -> Path:
        """The clip's file, rendering it first if needed (once per key, however many ask)."""
        path = self.path(key)
        if path.exists():
            return path
        if not background:
            self._want(key, 1)
        try:
            with self._locks(key):
                if path.exists():  # rendered while we waited for the lock
                    return path
                if background:
                    self._render(key, library, path, pausable=True)
                else:
                    with self._slots, self._running_urgent():
                        self._render(key, library, path, pausable=False)
        finally:
            if not background:
                self._want(key, -1)
        return path

    def _render(self, key: ClipKey, library: SkillLibrary, path: Path, pausable: bool) -> None:
        start = time.perf_counter()
        domain = get_domain(key.domain)
        rollout = library.rollout(library.index_of(key.rollout_id))
        frames = domain.render(rollout, key.width, key.height)
        count = write_mp4(self._yielding(key, frames) if pausable else frames, path, domain.frame_rate)
        seconds = time.perf_counter() - start
        with self._cond:
            self.renders += 1
            self.render_seconds += seconds
        log.info("rendered %s/%s (%d frames%s) in %.2f s", key.domain, key.rollout_id, count,
                 ", background" if pausable else "", seconds)

    def _yielding(self, key: ClipKey, frames: Iterator[np.ndarray]) -> Iterator[np.ndarray]:
        """Pass frames on, pausing while a requested render runs and nobody waits for this clip."""
        for frame in frames:
            with self._cond:
                while self._urgent and not self._wanted[key]:
                    self._cond.wait(PAUSE_CHECK_SECONDS)
            yield frame

    def _want(self, key: ClipKey, delta: int) -> None:
        with self._cond:
            self._wanted[key] += delta
            if self._wanted[key] <= 0:
                del self._wanted[key]
            self._cond.notify_all()

    @contextmanager
    def _running_urgent(self) -> Iterator[None]:
        with self._cond:
            self._urgent += 1
        try:
            yield
        finally:
            with self._cond:
                self._urgent -= 1
                self._cond.notify_all()

    def _remove_stale_temporaries(self) -> None:
        """Renders cut short by a crash leave ``.<name>.*.tmp`` files; old ones are garbage."""
        cutoff = time.time() - STALE_TMP_SECONDS
        for tmp in self.root.glob("*/.*.tmp"):
            try:
                if tmp.stat().st_mtime < cutoff:
                    tmp.unlink()
            except OSError:
                pass
