"""Background work while people watch: a small pool that keeps only each key's latest job.

A session submits one job per step (work out the clips its possible next answers would show).
When the person answers before the job ran, the job is replaced, not queued behind: a guess
about a clip nobody can see any more is wasted CPU on a 2-core machine. Each job's outcome is a
future (cancelled if the job is dropped unrun), so a request can await a job with a timeout.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

log = logging.getLogger(__name__)


class Background:
    """``workers`` daemon threads running the newest job per key, oldest key first."""

    def __init__(self, workers: int = 1, name: str = "rba-think") -> None:
        self._cond = threading.Condition()
        self._pending: OrderedDict[str, tuple[Callable[[], Any], Future]] = OrderedDict()
        self._running = 0
        self._stopping = False
        self.done = 0
        self.failed = 0
        self.workers = [threading.Thread(target=self._work, name=f"{name}-{i}", daemon=True) for i in range(workers)]
        for t in self.workers:
            t.start()

    def submit(self, key: str, job: Callable[[], Any]) -> Future:
        """Queue ``job`` under ``key``, replacing a not-yet-started job with that key; the future of its result."""
        done: Future = Future()
        with self._cond:
            if self._stopping:
                done.cancel()
                return done
            self._drop(key)
            self._pending[key] = (job, done)
            self._cond.notify()
        return done

    def cancel(self, key: str) -> None:
        with self._cond:
            self._drop(key)

    def _drop(self, key: str) -> None:
        """Forget ``key``'s job if it has not started (its future is cancelled); the caller holds the lock."""
        dropped = self._pending.pop(key, None)
        if dropped is not None:
            dropped[1].cancel()

    def wait_idle(self, timeout: float) -> bool:
        """True once no job is queued or running (tests and benchmarks use it)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._pending or self._running:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
        return True

    def stop(self, timeout: float = 2.0) -> None:
        """Drop queued jobs; give a running one ``timeout`` seconds (threads are daemons)."""
        with self._cond:
            self._stopping = True
            for key in list(self._pending):
                self._drop(key)
            self._cond.notify_all()
        deadline = time.monotonic() + timeout
        for t in self.workers:
            t.join(max(deadline - time.monotonic(), 0))

    def _work(self) -> None:
        while True:
            with self._cond:
                while not self._pending and not self._stopping:
                    self._cond.wait()
                if self._stopping:
                    return
                key, (job, done) = self._pending.popitem(last=False)
                self._running += 1
            try:
                if done.set_running_or_notify_cancel():
                    self._run(key, job, done)
            finally:
                with self._cond:
                    self._running -= 1
                    self._cond.notify_all()

    def _run(self, key: str, job: Callable[[], Any], done: Future) -> None:
        try:
            result = job()
        except Exception as exc:  # a failed prerender only costs a later on-demand render
            self.failed += 1
            log.exception("background job %s failed", key)
            done.set_exception(exc)
        else:
            self.done += 1
            done.set_result(result)

    @property
    def stopping(self) -> bool:
        return self._stopping
