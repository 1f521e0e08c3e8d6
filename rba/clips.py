"""The clip cache: MP4s rendered off-screen on first request and kept in the store.

A clip's key is (domain, library version, rollout id, size); the store (``rba.store.ClipStore``)
names its file. Each key has a lock, so two requests for the same uncached clip render it once;
a semaphore bounds how many requested clips render at the same time, and background renders
give way to them.
"""

from __future__ import annotations

import hashlib
import logging
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
from rba.locks import KeyedLocks
from rba.store import ClipStore
from rba.video import encode_mp4

log = logging.getLogger(__name__)

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
    """Rendered clips in a ``ClipStore``; ``get`` renders when missing.

    Renders a person is waiting for come first: a background (speculative) render pauses
    between frames while any requested render runs, unless someone is waiting for its clip.
    """

    def __init__(self, store: ClipStore, width: int, height: int, concurrency: int = 2) -> None:
        self.store = store
        self.width, self.height = width, height
        self._locks = KeyedLocks()
        self._slots = threading.BoundedSemaphore(concurrency)
        self._cond = threading.Condition()
        self._urgent = 0  # requested renders running now
        self._wanted: Counter[ClipKey] = Counter()  # clips requests are waiting for
        self.renders = 0  # clips rendered by this process (tests and benchmarks read it)
        self.render_seconds = 0.0
        store.sweep(STALE_TMP_SECONDS)  # renders cut short by a crash leave temporaries; old ones are garbage

    def key(self, library: SkillLibrary, rollout_id: str) -> ClipKey:
        """The key of a rollout that is in ``library`` (KeyError otherwise)."""
        library.index_of(rollout_id)
        return ClipKey(library.domain, library.version, rollout_id, self.width, self.height)

    def path(self, key: ClipKey) -> Path:
        return self.store.path(key)

    def cached(self, key: ClipKey) -> bool:
        return self.store.exists(key)

    def get(self, key: ClipKey, library: SkillLibrary, background: bool = False) -> Path:
        """The clip's file, rendering it first if needed (once per key, however many ask)."""
        if self.store.exists(key):
            return self.store.path(key)
        if not background:
            self._want(key, 1)
        try:
            with self._locks(key):
                if self.store.exists(key):  # rendered while we waited for the lock
                    return self.store.path(key)
                if background:
                    self._render(key, library, pausable=True)
                else:
                    with self._slots, self._running_urgent():
                        self._render(key, library, pausable=False)
        finally:
            if not background:
                self._want(key, -1)
        return self.store.path(key)

    def _render(self, key: ClipKey, library: SkillLibrary, pausable: bool) -> None:
        start = time.perf_counter()
        domain = get_domain(key.domain)
        rollout = library.rollout(library.index_of(key.rollout_id))
        frames = domain.render(rollout, key.width, key.height)
        frames = self._yielding(key, frames) if pausable else frames
        count = self.store.write(key, lambda tmp: encode_mp4(frames, tmp, domain.frame_rate))
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
