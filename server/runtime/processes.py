"""Training processes that die with their server, and a record of each so a restart can kill an orphan.

Three guards, because one is not enough:

- the child puts itself in its own process group and asks Linux for ``SIGKILL`` when its parent
  dies (``prctl(PR_SET_PDEATHSIG)``). That signal fires when the *thread* that forked the child
  ends, not the process, so every job process is started from one ``Launcher`` thread that lives
  as long as the server (a request's thread-pool worker may be retired at any time);
- the child also watches its parent's pid (other systems, or a parent that died before the signal
  was set up) and kills its group when it changes;
- the server writes a ``ProcessRecord`` (pid, start time, host) per job; a restart kills the
  group of a recorded process that still runs on this host, after checking the start time so a
  reused pid is never killed.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import queue
import signal
import socket
import sys
import threading
import time
from concurrent.futures import Future
from dataclasses import asdict, dataclass
from multiprocessing.process import BaseProcess
from pathlib import Path

import psutil

from rba.compute.tasks import watch_parent
from rba.core.fileio import load_json, save_json

log = logging.getLogger(__name__)
PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
PARENT_POLL_SECONDS = 0.5
START_TIME_SLACK = 0.05  # seconds: psutil's create_time of one process read twice agrees far closer than this


class Launcher:
    """Starts processes from one long-lived thread, so a child's parent-death signal means the server died."""

    def __init__(self, name: str) -> None:
        self._requests: queue.SimpleQueue[tuple[BaseProcess, Future] | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._serve, name=name, daemon=True)
        self._thread.start()

    def start(self, proc: BaseProcess) -> None:
        """``proc.start()`` on the launcher's thread; raises what it raised."""
        done: Future[None] = Future()
        self._requests.put((proc, done))
        done.result()

    def _serve(self) -> None:
        while (item := self._requests.get()) is not None:
            proc, done = item
            try:
                proc.start()
                done.set_result(None)
            except BaseException as e:  # handed to the caller
                done.set_exception(e)

    def close(self) -> None:
        """End the thread (children still running then get their parent-death signal)."""
        self._requests.put(None)
        self._thread.join(timeout=10)


def tie_to_parent(parent_pid: int) -> None:
    """In a job's process, first thing: die with the server whose pid is ``parent_pid``."""
    with contextlib.suppress(OSError):  # a group of its own: a reaper kills what the job started too
        os.setpgid(0, 0)
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            log.warning("prctl(PR_SET_PDEATHSIG) failed (errno %d): only the parent watch guards", ctypes.get_errno())
    if os.getppid() != parent_pid:  # the server died before the signal was set up
        _kill_own_group()
    watch_parent(parent_pid, lambda: _parent_gone(parent_pid), PARENT_POLL_SECONDS)


def _parent_gone(parent_pid: int) -> None:
    log.error("the server (pid %d) is gone: stopping this job's processes", parent_pid)
    _kill_own_group()


def _kill_own_group() -> None:
    if os.getpgid(0) == os.getpid():
        os.killpg(os.getpid(), signal.SIGKILL)
    os.kill(os.getpid(), signal.SIGKILL)


@dataclass(frozen=True)
class ProcessRecord:
    """Which process runs a job: enough to find it again after a restart, and never to mistake another for it."""

    pid: int
    started: float  # psutil's create_time: tells a reused pid apart
    host: str  # pids mean nothing on another machine or container

    @classmethod
    def of(cls, pid: int) -> ProcessRecord:
        return cls(pid, psutil.Process(pid).create_time(), socket.gethostname())

    def save(self, path: Path) -> None:
        save_json(path, asdict(self))

    @classmethod
    def load(cls, path: Path) -> ProcessRecord | None:
        """The record at ``path``; None if it is missing or unreadable (a crash mid-write leaves no file)."""
        try:
            raw = load_json(path)
            return cls(int(raw["pid"]), float(raw["started"]), str(raw["host"]))
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def _process(self) -> psutil.Process | None:
        """The recorded process if it is still here: on this host, and not another that reused its pid."""
        if self.host != socket.gethostname():
            return None
        try:
            proc = psutil.Process(self.pid)
            return proc if abs(proc.create_time() - self.started) <= START_TIME_SLACK else None
        except psutil.NoSuchProcess:
            return None

    def running(self) -> bool:
        """Whether the recorded process still runs on this host (a zombie does not); one we may not inspect does."""
        try:
            proc = self._process()
            return proc is not None and proc.status() != psutil.STATUS_ZOMBIE
        except psutil.NoSuchProcess:
            return False
        except psutil.Error:
            return True

    def kill(self, timeout: float = 5.0) -> bool:
        """Kill the recorded process and its group if it is still here; True if it was running (not a zombie)."""
        try:
            proc = self._process()
            if proc is None:
                return False
            running = proc.status() != psutil.STATUS_ZOMBIE
            if os.getpgid(self.pid) == self.pid:  # a zombie leader's group may still have live members
                os.killpg(self.pid, signal.SIGKILL)
            else:
                proc.kill()
        except (psutil.NoSuchProcess, ProcessLookupError):
            return False
        except (psutil.Error, OSError) as exc:  # not ours to kill (another user's pid): leave it, say so
            log.warning("could not kill process %d: %s", self.pid, exc)
            return False
        _wait_gone(proc, timeout)
        return running


def _wait_gone(proc: psutil.Process, timeout: float) -> None:
    """Until ``proc`` is gone or a zombie (an orphan's zombie is its new parent's to reap, not ours)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if proc.status() == psutil.STATUS_ZOMBIE:
                return
        except psutil.NoSuchProcess:
            return
        time.sleep(0.05)
    log.warning("process %d did not die within %.0f s of SIGKILL", proc.pid, timeout)
