"""`kill -9` of a real server (a subprocess on SQLite, the toy domain) during a feedback burst and a training job.

After a restart nothing acknowledged is lost, every session is consistent, the killed server's training
process is gone (not still training, writing progress or recreating its staging folder), its job is
failed with a message, and the next job runs, one per domain at a time.
"""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import psutil
import pytest

from server.runtime.job_runner import STAGING_GRACE_SECONDS
from tests.conftest import own_copy
from tests.server.test_serve import REPO, free_port

TOKEN = "crash-test-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
FINISHED = ("succeeded", "failed", "cancelled")
SERVE = "from rba.domains import register; register('toy', 'tests.toy:Toy'); from server.main import run; run()"
START_SECONDS = 120  # a limit, not the usual: a start takes ~5 s of CPU, far longer on a crowded machine


class Server:
    """``rba serve`` (with the tests' toy domain registered) in a subprocess that the test may SIGKILL."""

    def __init__(self, root: Path) -> None:
        self.root, self.port = root, free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.env = {**os.environ, "RBA_DATA_DIR": str(root / "data"), "RBA_MODELS_DIR": str(root / "models"),
                    "RBA_CACHE_DIR": str(root / "clips"), "RBA_DATABASE_URL": f"sqlite:///{root / 'rba.db'}",
                    "RBA_ADMIN_TOKEN": TOKEN, "RBA_HOST": "127.0.0.1", "RBA_PORT": str(self.port),
                    "RBA_REPLICA": "crash-test", "RBA_WARM_START": "false", "RBA_PRERENDER": "false",
                    "RBA_PRERENDER_LIBRARY": "false", "RBA_LOG_LEVEL": "warning", "PYTHONPATH": str(REPO)}
        self.proc: subprocess.Popen | None = None
        self.log = root / "server.log"

    def start(self) -> None:
        with self.log.open("a") as out:
            self.proc = subprocess.Popen([sys.executable, "-c", SERVE], cwd=REPO, env=self.env, stdout=out,
                                         stderr=subprocess.STDOUT)
        deadline = time.monotonic() + START_SECONDS
        while time.monotonic() < deadline and self.proc.poll() is None:
            try:
                if httpx.get(f"{self.url}/healthz", timeout=1).status_code == 200:
                    return
            except httpx.TransportError:
                time.sleep(0.2)
        self.stop()
        raise AssertionError(f"the server did not start in {START_SECONDS} s:\n{self.log.read_text()[-3000:]}")

    def descendants(self) -> list[psutil.Process]:
        return psutil.Process(self.proc.pid).children(recursive=True)

    def kill(self) -> None:
        """SIGKILL: no lifespan shutdown, no cancelling, nothing recorded."""
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)


@pytest.fixture(scope="module")
def server(toy_roots, tmp_path_factory) -> Iterator[Server]:
    """One server for the module (each test kills and restarts it: a start costs seconds of CPU)."""
    root = tmp_path_factory.mktemp("crash")
    own_copy(toy_roots, root)
    s = Server(root)
    try:
        s.start()
        yield s
    finally:
        s.stop()


def gone(procs: list[psutil.Process], timeout: float) -> list[psutil.Process]:
    """The processes of ``procs`` still running (zombies count as gone) after up to ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        alive = []
        for p in procs:
            try:
                if p.status() != psutil.STATUS_ZOMBIE:
                    alive.append(p)
            except psutil.NoSuchProcess:
                pass
        if not alive or time.monotonic() > deadline:
            return alive
        time.sleep(0.1)


# -- a feedback burst -------------------------------------------------------------------------------

SESSIONS = 6
KILL_AFTER = 40  # acknowledged feedbacks, over all sessions


def burst(url: str, session_id: str, acked: list[tuple[int, str, str]], count: threading.Semaphore,
          stop: threading.Event, errors: list[str]) -> None:
    """Answer ``session_id`` step after step until the server dies; ``acked`` gets (step, attribute, next clip)."""
    with httpx.Client(base_url=url, timeout=10) as c:
        step = 0
        while not stop.is_set():
            attribute = ("amplitude", "pace")[step % 2]
            try:
                r = c.post(f"/api/sessions/{session_id}/feedback",
                           json={"step": step, "feedback": [{"attribute": attribute, "direction": "more"}]})
            except httpx.TransportError:
                return
            if r.status_code != 200:
                errors.append(f"{r.status_code} {r.text}")
                return
            acked.append((step, attribute, r.json()["clip"]["rollout_id"]))
            count.release()
            step += 1


def test_kill_during_a_feedback_burst_loses_nothing_acknowledged(server):
    with httpx.Client(base_url=server.url, timeout=10) as c:
        ids = []
        for _ in range(SESSIONS):
            r = c.post("/api/sessions", json={"domain": "toy", "method": "global", "rep": "onehot"})
            assert r.status_code == 201, r.text
            ids.append(r.json()["id"])
    acked: dict[str, list[tuple[int, str, str]]] = {i: [] for i in ids}
    count, stop, errors = threading.Semaphore(0), threading.Event(), []
    threads = [threading.Thread(target=burst, args=(server.url, i, acked[i], count, stop, errors)) for i in ids]
    for t in threads:
        t.start()
    for _ in range(KILL_AFTER):
        assert count.acquire(timeout=30), "the burst stalled"
    server.kill()  # requests are in flight now
    stop.set()
    for t in threads:
        t.join(15)
    assert errors == []
    server.start()

    with httpx.Client(base_url=server.url, timeout=10) as c:
        for session_id, answers in acked.items():
            r = c.get(f"/api/sessions/{session_id}")
            assert r.status_code == 200, r.text
            s = r.json()
            history = s["history"]
            assert s["step"] == len(history) >= len(answers)  # an unanswered in-flight request may have landed too
            assert [h["step"] for h in history] == list(range(len(history)))
            for (step, attribute, after), h in zip(answers, history, strict=False):
                assert (h["step"], h["feedback"], h["rollout_after"]) == (
                    step, [{"attribute": attribute, "direction": "more"}], after)
            for before, after in itertools.pairwise(history):  # each step starts where the last ended
                assert after["rollout_before"]["rollout_id"] == before["rollout_after"]
            assert history[-1]["rollout_after"] == s["clip"]["rollout_id"]
            r = c.post(f"/api/sessions/{session_id}/feedback",  # and the session goes on
                       json={"step": s["step"], "feedback": [{"attribute": "pace", "direction": "less"}]})
            assert r.status_code == 200 and r.json()["step"] == s["step"] + 1, r.text
    assert sum(len(a) for a in acked.values()) >= KILL_AFTER


# -- a training job ---------------------------------------------------------------------------------

def wait_job(c: httpx.Client, job_id: str, until, timeout: float) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        job = c.get(f"/api/admin/jobs/{job_id}", headers=AUTH).json()
        if until(job) or time.monotonic() > deadline:
            return job
        time.sleep(0.2)


def test_kill_during_training_kills_the_job_and_a_restart_fails_it_and_sweeps(server):
    versions = server.root / "models" / "versions"
    with httpx.Client(base_url=server.url, timeout=10) as c:
        r = c.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "preset": "default"})
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        job = wait_job(c, job_id, lambda j: j["step"] > 0 or j["state"] in FINISHED, 120)
        assert job["state"] == "running" and job["step"] > 0, job  # training: the kill lands mid-run
    children = server.descendants()
    assert any("spawn_main" in " ".join(p.cmdline()) for p in children), [p.cmdline() for p in children]
    server.kill()
    left = gone(children, 5)
    assert not left, [(p.pid, p.cmdline()) for p in left]

    # staging folders of jobs this database never knew: another database's job may still train into a fresh one;
    # one untouched for longer than the grace period with no process is abandoned
    (versions / ".tmp-0123456789abcdef").mkdir(parents=True)
    (versions / ".tmp-fedcba9876543210").mkdir(parents=True)
    old = time.time() - STAGING_GRACE_SECONDS - 60
    os.utime(versions / ".tmp-0123456789abcdef", (old, old))
    server.start()
    with httpx.Client(base_url=server.url, timeout=10) as c:
        job = c.get(f"/api/admin/jobs/{job_id}", headers=AUTH).json()
        assert (job["state"], job["error"], job["version"]) == ("failed", "the server stopped while the job ran", None)
        assert sorted(p.name for p in versions.iterdir()) == [".tmp-fedcba9876543210"]
        assert not list((server.root / "data" / "jobs").glob("*"))
        step = job["step"]
        time.sleep(1.5)  # nothing writes to the failed job any more
        assert c.get(f"/api/admin/jobs/{job_id}", headers=AUTH).json()["step"] == step

        r = c.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "preset": "tiny"})
        assert r.status_code == 202, r.text
        again = c.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "preset": "tiny"})
        assert again.status_code == 409, again.text
        assert f"a training job for toy is already running ({r.json()['id']})" in again.json()["detail"]
        new = wait_job(c, r.json()["id"], lambda j: j["state"] in FINISHED, 300)  # a limit; ~5 s on a calm machine
        assert new["state"] == "succeeded", new
    assert sorted(p.name for p in versions.iterdir()) == [".tmp-fedcba9876543210", new["version"]]
