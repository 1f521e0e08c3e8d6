"""Job processes die with their server, and a process record kills exactly the process it names."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil
import pytest

from server.runtime import processes
from server.runtime.processes import Launcher, ProcessRecord, tie_to_parent

REPO = Path(__file__).resolve().parents[2]
linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")


def tied_child(parent_pid: int, break_death_signal: bool, tied=None) -> None:
    """A job process stand-in: tie itself to ``parent_pid`` (optionally without the parent-death signal), wait."""
    if break_death_signal:
        processes.PR_SET_PDEATHSIG = 0x7FFF  # not a prctl option: the call fails, only the parent watch is left
    tie_to_parent(parent_pid)
    if tied is not None:
        tied.set()
    time.sleep(60)


def alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def wait_dead(pid: int, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return not alive(pid)


PARENT = """
import multiprocessing, os, sys, time
from server.runtime.processes import Launcher
from tests.server.test_processes import tied_child
ctx = multiprocessing.get_context("spawn")
tied = ctx.Event()
proc = ctx.Process(target=tied_child, args=(os.getpid(), sys.argv[1] == "broken", tied))
Launcher("test-launcher").start(proc)
tied.wait(60)
print(proc.pid, flush=True)
time.sleep(60)
"""


@pytest.mark.parametrize("death_signal", ["working", "broken"])
def test_a_tied_process_dies_with_its_parent_killed_by_sigkill(death_signal):
    parent = subprocess.Popen([sys.executable, "-c", PARENT, death_signal], cwd=REPO, stdout=subprocess.PIPE,
                              env={**os.environ, "PYTHONPATH": str(REPO)}, text=True)
    try:
        child = int(parent.stdout.readline())  # once it is tied
        assert alive(child)
        assert os.getpgid(child) == child  # a group of its own: a reaper kills what it started too
        parent.send_signal(signal.SIGKILL)
        parent.wait(10)
        # the parent-death signal is at once; the watch (when the signal is broken) polls every 0.5 s
        assert wait_dead(child, 0.5 if death_signal == "working" else 3)
    finally:
        parent.kill()
        parent.wait(10)


@linux_only
def test_the_launcher_ties_children_to_itself_not_to_the_thread_that_asked():
    """PR_SET_PDEATHSIG fires when the forking *thread* ends: a request thread must not be the one forking."""
    ctx = multiprocessing.get_context("spawn")
    launcher = Launcher("test-launcher")
    tied = [ctx.Event(), ctx.Event()]
    via_launcher, direct = (ctx.Process(target=tied_child, args=(os.getpid(), False, t), daemon=True) for t in tied)

    def ask() -> None:  # a short-lived thread, as a request's worker thread may be
        launcher.start(via_launcher)
        direct.start()
        assert all(t.wait(60) for t in tied)

    asker = threading.Thread(target=ask)
    asker.start()
    asker.join()
    try:
        direct.join(10)  # the control: forked by the thread that ended, its parent-death signal killed it
        assert direct.exitcode == -signal.SIGKILL
        assert via_launcher.is_alive()
    finally:
        via_launcher.terminate()
        via_launcher.join(10)
        launcher.close()


def test_a_process_whose_parent_is_gone_before_it_is_tied_kills_itself():
    proc = multiprocessing.get_context("spawn").Process(target=tied_child, args=(1, False))  # "its parent": not us
    proc.start()
    proc.join(30)
    assert proc.exitcode == -signal.SIGKILL


@pytest.fixture
def orphan():
    """A process group standing for a training process and a worker it started: (leader, member) pids."""
    proc = subprocess.Popen(["sh", "-c", "sleep 60 & echo $!; wait"], stdout=subprocess.PIPE, text=True,
                            start_new_session=True)
    member = int(proc.stdout.readline())
    yield proc.pid, member
    for pid in (proc.pid, member):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    proc.wait(10)


def test_a_record_kills_the_process_group_it_names(orphan, tmp_path):
    leader, member = orphan
    path = tmp_path / "jobs" / "j.json"
    ProcessRecord.of(leader).save(path)
    record = ProcessRecord.load(path)
    assert record == ProcessRecord(leader, psutil.Process(leader).create_time(), socket.gethostname())
    assert record.kill() is True
    assert wait_dead(leader, 5) and wait_dead(member, 5)
    assert record.kill() is False  # gone already


def test_a_record_never_kills_a_reused_pid_or_another_hosts_process(orphan):
    leader, _ = orphan
    started = psutil.Process(leader).create_time()
    assert ProcessRecord(leader, started - 1.0, socket.gethostname()).kill() is False
    assert ProcessRecord(leader, started, "another-host").kill() is False
    assert alive(leader)


def test_an_unreadable_record_is_none(tmp_path):
    assert ProcessRecord.load(tmp_path / "missing.json") is None
    (tmp_path / "half.json").write_text('{"pid": 12')
    assert ProcessRecord.load(tmp_path / "half.json") is None
    (tmp_path / "odd.json").write_text('{"pid": "x", "started": 1, "host": "h"}')
    assert ProcessRecord.load(tmp_path / "odd.json") is None
