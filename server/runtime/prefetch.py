"""The guess queue: one thread that keeps a few guessed renders in flight on the compute layer, most needed first.

The compute layer runs what it is given; this decides what to give it next. Three tiers, always
taking from the highest that has work (``server.ops.prerender`` says what goes in each):

1. ``offer(session, clips)``: a session's possible next clips, most likely first (a newer offer
   replaces the session's older one); taken round-robin over the sessions, the newest offer first;
2. and 3. ``extend(clips)``: lazy sources (the shared trees, then the libraries), drained in order.

Each guess's data (the page draws a clip from it, ``rba.media.clip_data``) is asked for beside its MP4.

Only ``window`` guesses are in flight at once, so a clip a person asks for is never queued behind
hundreds of guesses, and a guess nobody needs any more costs at most one render. While ``hold()`` says
someone waits on a search (or the clip it made), no new guess starts: beside niced guesses a
generated walker clip rendered in up to 2.7 s on 2 cores, without them in 1.0-1.5 s.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future

from rba.domains import get_domain
from rba.media.clip_cache import ClipCache, ClipKey, Source

log = logging.getLogger(__name__)

HOLD_POLL_SECONDS = 0.05  # how often a held queue looks again whether anyone still waits
OFFER_TTL_SECONDS = 120.0  # a person answers within seconds; an older offer is for a session that moved on elsewhere
Resolve = Callable[[object], tuple[ClipKey, Source]]  # a clip reference -> its key and what it renders from


class Prefetcher:
    """Feeds guessed renders to ``clips`` from its tiers, ``window`` at a time, on one niced thread."""

    def __init__(self, clips: ClipCache, resolve: Resolve, window: int, nice: int = 0,
                 hold: Callable[[], bool] = lambda: False) -> None:
        self.clips, self.resolve, self.window, self.nice, self.hold = clips, resolve, window, nice, hold
        self._cond = threading.Condition()
        self._offers: OrderedDict[str, deque] = OrderedDict()
        self._offered_at: dict[str, float] = {}
        self._sources: deque[Iterator] = deque()
        self._inflight = 0
        self._held: object | None = None  # a guess worked out while someone began to wait: started first after
        self._stopping = False
        self.submitted = 0
        self.failed = 0
        self._thread = threading.Thread(target=self._run, name="rba-prefetch", daemon=True)
        self._thread.start()

    def offer(self, session_id: str, clips: list) -> None:
        """Queue a session's next clips (most likely first) ahead of everything else."""
        with self._cond:
            self._offers.pop(session_id, None)
            self._offers[session_id] = deque(clips)
            self._offers.move_to_end(session_id, last=False)
            self._offered_at[session_id] = time.monotonic()
            self._cond.notify_all()

    def withdraw(self, session_id: str) -> None:
        with self._cond:
            self._offers.pop(session_id, None)
            self._offered_at.pop(session_id, None)

    def extend(self, clips: Iterator) -> None:
        """Queue a lazy source behind the sessions' offers and the sources before it."""
        with self._cond:
            self._sources.append(iter(clips))
            self._cond.notify_all()

    def idle(self) -> bool:
        with self._cond:
            return not self._inflight and not self._has_work()

    def wait_idle(self, timeout: float) -> bool:
        """True once nothing is queued or in flight (tests and benchmarks use it)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._inflight or self._has_work():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(min(left, 0.5))
        return True

    def stop(self, timeout: float = 2.0) -> None:
        with self._cond:
            self._stopping = True
            self._offers.clear()
            self._sources.clear()
            self._held = None
            self._cond.notify_all()
        self._thread.join(timeout)

    @property
    def stopping(self) -> bool:
        return self._stopping

    def _run(self) -> None:
        if self.nice:  # thinking for the trees runs here: below the API's threads
            try:
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), self.nice)
            except OSError:
                log.debug("could not lower the prefetch thread's priority")
        while True:
            with self._cond:
                while not self._stopping and (self._inflight >= self.window or not self._has_work()):
                    self._cond.wait()
                if self._stopping:
                    return
            if self.hold():  # asked outside our lock: it takes the clip cache's, which calls back into ours
                with self._cond:
                    self._cond.wait(HOLD_POLL_SECONDS)
                continue
            ref, self._held = self._held or self._next(), None
            if ref is None:
                continue
            if self.hold():  # working the guess out (a tree's thinking) took a while: a search may have begun
                self._held = ref
                continue
            self._start(ref)

    def _expire(self) -> None:
        """Drop offers older than ``OFFER_TTL_SECONDS``: that session's next answer went to another replica
        (or its person left), and this replica will never hear of it."""
        now = time.monotonic()
        for session_id in [sid for sid, at in self._offered_at.items() if now - at > OFFER_TTL_SECONDS]:
            self._offers.pop(session_id, None)
            self._offered_at.pop(session_id, None)

    def _has_work(self) -> bool:
        return self._held is not None or bool(self._sources) or any(self._offers.values())

    def _next(self) -> object | None:
        """The next clip reference to consider: a session's (round-robin), else the first source's."""
        with self._cond:
            self._expire()
            for session_id, queue in self._offers.items():
                if queue:  # round-robin: every session's most likely clip before anyone's second guess
                    self._offers.move_to_end(session_id)
                    return queue.popleft()
            source = self._sources[0] if self._sources else None
        if source is None:
            return None
        try:
            return next(source)  # may think (trees): outside the lock
        except StopIteration:
            with self._cond:
                if self._sources and self._sources[0] is source:
                    self._sources.popleft()
                self._cond.notify_all()
        except Exception:
            log.exception("a prerender source failed; dropping it")
            with self._cond:
                if self._sources and self._sources[0] is source:
                    self._sources.popleft()
        return None

    def _start(self, ref: object) -> None:
        try:
            key, source = self.resolve(ref)
        except Exception:  # e.g. a library rebuilt under us, a made clip forgotten: skip the guess
            log.debug("cannot prerender %r", ref, exc_info=True)
            return
        self._describe(key, source)
        if self.clips.cached(key) or self.clips.pending(key):
            return
        with self._cond:
            self._inflight += 1
            self.submitted += 1
        self.clips.request(key, source, urgent=False).add_done_callback(self._finished)

    def _describe(self, key: ClipKey, source: Source) -> None:
        """The guessed clip's data too, where its domain has any: about 1 % of its MP4's CPU
        (``benchmarks/results/clip_data.md``), so it is not counted in the window."""
        data = key.data()
        if get_domain(key.domain).draws_clips and not self.clips.cached(data) and not self.clips.pending(data):
            self.clips.request(data, source, urgent=False)

    def _finished(self, done: Future) -> None:
        with self._cond:
            self._inflight -= 1
            if not done.cancelled() and done.exception() is not None:
                self.failed += 1
            self._cond.notify_all()
