"""Training jobs across API replicas on one database: who owns a job, heartbeats, and who may fail it.

Each runner here stands for one replica's process (its own engine, its own replica name). Jobs are
rows written directly, and "processes" are stand-ins, so nothing trains: the rules under test are
those of the rows.
"""

from __future__ import annotations

import datetime as dt
import os
import shutil
import subprocess
import threading
import time

import psutil
import pytest
from sqlalchemy.exc import IntegrityError
from sqlmodel import Session, select

from server.common.app_settings import Settings
from server.db.admin_tables import JobState, ModelVersion, TrainJob
from server.db.engine import make_engine
from server.db.tables import as_utc, utcnow
from server.runtime.job_runner import STAGING_GRACE_SECONDS, JobLost, JobRunner, _record_success, update_job
from server.runtime.processes import ProcessRecord
from tests.conftest import own_copy
from tests.server.test_processes import alive, wait_dead

REPLICA_TOKEN = "replica-test-t0ken"

# The heartbeat tests' timings. A live job must look alive however busy the machine: 20 beats may be missed
# before another replica may fail it (with 6, one CI run saw a live job go 0.6 s without a heartbeat).
BEAT, STALE = 0.1, 2.0
PAST_STALE = STALE + 0.4


class StandInProcess:
    """What ``JobRunner`` asks of a training process: alive until terminated."""

    def __init__(self) -> None:
        self.stopped = threading.Event()
        self.exitcode: int | None = None

    def is_alive(self) -> bool:
        return not self.stopped.is_set()

    def terminate(self) -> None:
        self.exitcode = -15
        self.stopped.set()

    def join(self, timeout: float | None = None) -> None:
        self.stopped.wait(timeout)


@pytest.fixture
def replica(make_settings, database_url, tmp_path):
    """replica(name, **settings) -> a JobRunner of its own, on the shared database and models folder."""
    runners: list[JobRunner] = []

    def make(name: str, **overrides) -> JobRunner:
        settings = make_settings(database_url=database_url, data_dir=tmp_path / "data", models_dir=tmp_path / "models",
                                 replica=name, **overrides)
        runner = JobRunner(settings, make_engine(settings.db_url))
        runners.append(runner)
        return runner

    yield make
    for runner in runners:
        runner.stop()
        runner.engine.dispose()


def add_job(runner: JobRunner, domain: str, owner: str | None, beat_age: float | None,
            updated_age: float = 0.0) -> str:
    """A running job row of ``domain``, last heartbeat ``beat_age`` seconds ago, with a staging folder."""
    now = utcnow()
    job = TrainJob(domain=domain, busy_domain=domain, method="global", rep="onehot", preset="tiny", datasets=[],
                   state=JobState.running.value, owner=owner, updated_at=now - dt.timedelta(seconds=updated_age),
                   heartbeat_at=None if beat_age is None else now - dt.timedelta(seconds=beat_age))
    with Session(runner.engine) as db:
        db.add(job)
        db.commit()
        db.refresh(job)
    runner.store.staging(job.id).mkdir(parents=True)
    return job.id


def run_here(runner: JobRunner, job_id: str) -> StandInProcess:
    """Register a stand-in process for ``job_id``, as ``JobRunner.start`` does for a real one."""
    proc = StandInProcess()
    with runner._lock:
        runner._procs[job_id] = proc
    return proc


def row(runner: JobRunner, job_id: str) -> TrainJob:
    with Session(runner.engine) as db:
        return db.get(TrainJob, job_id)


def test_a_starting_replica_fails_only_jobs_no_live_server_runs(replica):
    a = replica("a")
    live = add_job(a, "toy", a.owner, beat_age=1)  # replica a's job, heartbeat fresh
    dead = add_job(a, "walker", "c#0badc0de", beat_age=120)  # replica c died two minutes ago
    legacy = add_job(a, "snake", None, beat_age=None, updated_age=120)  # from a server without heartbeats
    b_before = add_job(a, "manipulator", "b#01d1ce00", beat_age=1)  # b's previous process: fresh, but gone
    b = replica("b")
    b.recover()

    kept = row(b, live)
    assert (kept.state, kept.busy_domain, kept.error) == ("running", "toy", None)
    assert b.store.staging(live).is_dir()  # the live job's models in progress are not touched
    for job_id, error in [(dead, "the server running the job (c#0badc0de) stopped: no heartbeat for 30 s"),
                          (legacy, "the server running the job (unknown) stopped: no heartbeat for 30 s"),
                          (b_before, "the server stopped while the job ran")]:
        failed = row(b, job_id)
        assert (failed.state, failed.busy_domain, failed.error) == ("failed", None, error)
        assert not b.store.staging(job_id).exists()


def test_only_a_restarted_replica_fails_its_own_fresh_jobs_at_once(replica):
    a = replica("a")
    job = add_job(a, "toy", "b#01d1ce00", beat_age=1)
    assert a.reap(restarted=True) == []  # another replica's fresh job
    assert replica("b").reap() == []  # b's own previous process, but not at start-up: wait for the heartbeat
    assert replica("b").reap(restarted=True) == [job]


def test_heartbeat_keeps_a_job_alive_and_its_absence_lets_another_replica_fail_it(replica):
    a = replica("a", job_heartbeat_seconds=BEAT, job_stale_seconds=STALE)
    b = replica("b", job_heartbeat_seconds=BEAT, job_stale_seconds=STALE)
    job = add_job(a, "toy", a.owner, beat_age=0)
    proc = run_here(a, job)
    a.recover()  # starts a's keeper: a heartbeat every BEAT seconds
    time.sleep(PAST_STALE)
    assert b.reap() == [] and row(b, job).state == "running"
    assert (utcnow() - as_utc(row(b, job).heartbeat_at)).total_seconds() < STALE

    a._halt.set()  # replica a dies: its keeper stops, nothing records an end
    a._keeper.join(5)
    time.sleep(PAST_STALE)
    assert b.reap() == [job]
    assert row(b, job).state == "failed" and row(b, job).busy_domain is None
    a.heartbeat()  # were a only slow, not dead: its next beat stops the process of the job it lost
    assert not proc.is_alive()


def test_a_job_cancelled_through_another_replica_is_stopped_by_its_owner(replica):
    a, b = replica("a"), replica("b")
    job = add_job(a, "toy", a.owner, beat_age=0)
    proc = run_here(a, job)
    b.cancel(job)  # the admin's request reached replica b; the process runs on a
    assert row(b, job).state == "cancelled" and proc.is_alive()
    a.heartbeat()
    assert not proc.is_alive()


def test_one_job_per_domain_holds_across_replicas(replica):
    a, b = replica("a"), replica("b")
    add_job(a, "toy", a.owner, beat_age=0)
    with pytest.raises(IntegrityError):
        add_job(b, "toy", b.owner, beat_age=0)


def test_train_route_on_two_replicas(make_settings, database_url, tmp_path, monkeypatch):
    """Through the API: the second replica's request is a 409 while the first's job lives; once its server
    is gone (no heartbeat), the next request on the other replica reaps it and starts."""
    import shutil

    from fastapi.testclient import TestClient

    from server.main import create_app

    monkeypatch.setattr(JobRunner, "start", lambda runner, job_id: run_here(runner, job_id))
    auth = {"Authorization": f"Bearer {REPLICA_TOKEN}"}
    data, models = tmp_path / "data", tmp_path / "models"
    shutil.copytree(make_settings().data_dir, data)
    shutil.copytree(make_settings().models_dir, models)

    def app(name: str):
        return TestClient(create_app(make_settings(database_url=database_url, admin_token=REPLICA_TOKEN, replica=name,
                                                   data_dir=data, models_dir=models, job_heartbeat_seconds=BEAT,
                                                   job_stale_seconds=STALE)))

    with app("a") as a, app("b") as b:
        first = a.post("/api/admin/train", headers=auth, json={"domain": "toy", "preset": "tiny"})
        assert first.status_code == 202, first.text
        time.sleep(PAST_STALE)  # a's heartbeats keep its job alive past the staleness limit
        busy = b.post("/api/admin/train", headers=auth, json={"domain": "toy", "preset": "tiny"})
        assert busy.status_code == 409
        assert busy.json()["detail"] == (f"a training job for toy is already running ({first.json()['id']}); "
                                         "wait for it or cancel it")
        runner = a.app.state.services.jobs
        runner._halt.set()  # replica a's process hangs: no more heartbeats
        runner._keeper.join(5)
        time.sleep(PAST_STALE)
        second = b.post("/api/admin/train", headers=auth, json={"domain": "toy", "preset": "tiny"})
        assert second.status_code == 202, second.text
        jobs = {j["id"]: j for j in b.get("/api/admin/jobs", headers=auth).json()}
        assert jobs[first.json()["id"]]["state"] == "failed"
        assert f"stopped: no heartbeat for {STALE:g} s" in jobs[first.json()["id"]]["error"]
        assert jobs[second.json()["id"]]["state"] == "queued"


@pytest.fixture
def sleepers():
    """sleepers() -> a new process in a group of its own, standing for a training process a crash left."""
    procs: list[subprocess.Popen] = []

    def make() -> int:
        procs.append(subprocess.Popen(["sleep", "60"], start_new_session=True))
        return procs[-1].pid

    yield make
    for proc in procs:
        proc.kill()
        proc.wait(10)


def test_a_restart_kills_what_its_previous_process_left_and_sweeps_what_no_live_job_owns(replica, sleepers):
    a = replica("a")
    orphaned = add_job(a, "toy", "a#0ld0ld00", beat_age=1)  # a's previous process ran it, and was killed
    ProcessRecord.of(orphan := sleepers()).save(a.store.job_record(orphaned))
    finished = add_job(a, "snake", "a#0ld0ld00", beat_age=1)  # failed by another replica; its process ran on
    update_job(a.engine, finished, state=JobState.failed.value, error="the server running the job stopped")
    ProcessRecord.of(survivor := sleepers()).save(a.store.job_record(finished))
    elsewhere = add_job(a, "walker", "b#11ve11ve", beat_age=1)  # replica b's live job, on another machine
    ProcessRecord(sleepers(), 0.0, "b-host").save(a.store.job_record(elsewhere))
    unknown, foreign = "0123456789abcdef", "fedcba9876543210"  # staging folders no job row here knows
    a.store.staging(unknown).mkdir()
    age(a.store.staging(unknown), STAGING_GRACE_SECONDS + 60)  # untouched for longer than the grace period
    a.store.staging(foreign).mkdir()  # another database's job, training now

    restarted = replica("a")
    restarted.recover()
    assert wait_dead(orphan, 0.5) and wait_dead(survivor, 0.5)
    assert (row(a, orphaned).state, row(a, orphaned).error) == ("failed", "the server stopped while the job ran")
    assert (row(a, elsewhere).state, row(a, elsewhere).busy_domain) == ("running", "walker")
    assert a.store.staged_jobs() == sorted([elsewhere, foreign])  # models in progress stay, and so does a record
    assert a.store.recorded_jobs() == [elsewhere]


def test_a_restart_removes_a_published_version_no_row_names_unless_its_job_is_live(replica):
    """Killed between renaming its folder into place and committing its row, a job leaves a version nobody lists."""
    a = replica("a")
    live = add_job(a, "walker", "b#11ve11ve", beat_age=1)  # replica b, recording its version right now
    dead = add_job(a, "toy", "b#11ve11ve", beat_age=1)  # failed while recording its version
    update_job(a.engine, dead, state=JobState.failed.value, error="the server running the job stopped")
    for name in (f"toy-20260101-000000-{dead[:6]}", f"walker-20260101-000000-{live[:6]}",
                 "toy-20260101-000000-beef00", "toy-20260101-000000-f0e1d2", "toy-by-hand"):
        (a.store.versions_dir / name).mkdir(parents=True)
    with Session(a.engine) as db:
        db.add(ModelVersion(version="toy-20260101-000000-beef00", domain="toy", method="global", rep="onehot",
                            attributes=["pace"], held_out={}, job_id="beef00"))
        db.commit()
    replica("a").recover()
    assert a.store.published() == ["toy-20260101-000000-beef00", "toy-20260101-000000-f0e1d2",  # no row: not ours
                                   "toy-by-hand", f"walker-20260101-000000-{live[:6]}"]


def test_a_server_on_another_database_leaves_the_first_ones_versions_jobs_and_processes(
        make_settings, toy_roots, tmp_path, sleepers):
    """Two servers, one models (and data) folder, two databases: the second's start-up sweep knows nothing of the
    first's version, its job in progress or that job's process, so it leaves them all."""
    from fastapi.testclient import TestClient

    from server.main import create_app

    data, models = own_copy(toy_roots, tmp_path)

    def app(db: str) -> TestClient:
        return TestClient(create_app(make_settings(data_dir=data, models_dir=models,
                                                   database_url=f"sqlite:///{tmp_path / db}")))

    with app("first.db") as first:
        runner = first.app.state.services.jobs
        published = add_job(runner, "toy", runner.owner, beat_age=0)
        version = f"toy-20260101-000000-{published[:6]}"
        runner.store.publish(published, version)
        with Session(runner.engine) as db:
            db.add(ModelVersion(version=version, domain="toy", method="global", rep="onehot", attributes=["pace"],
                                held_out={}, job_id=published))
            db.commit()
        update_job(runner.engine, published, state=JobState.succeeded.value, version=version)
        training = add_job(runner, "walker", runner.owner, beat_age=0)
        run_here(runner, training)
        ProcessRecord.of(pid := sleepers()).save(runner.store.job_record(training))
        age(runner.store.staging(training), STAGING_GRACE_SECONDS + 60)  # a long job: its live process vouches
        with app("second.db") as second:
            assert second.get("/healthz").status_code == 200
        assert runner.store.published() == [version]
        assert runner.store.staged_jobs() == [training] and runner.store.recorded_jobs() == [training]
        assert alive(pid)


def age(path, seconds: float) -> None:
    """Set ``path``'s modification time ``seconds`` into the past."""
    then = time.time() - seconds
    os.utime(path, (then, then))


def test_a_record_whose_pid_was_reused_kills_nothing(replica, sleepers):
    a = replica("a")
    job = add_job(a, "toy", "a#0ld0ld00", beat_age=1)
    ProcessRecord(other := sleepers(), 12.0, ProcessRecord.of(other).host).save(a.store.job_record(job))
    replica("a").recover()
    assert alive(other) and row(a, job).state == "failed"
    assert a.store.recorded_jobs() == [] and a.store.staged_jobs() == []


def test_a_job_taken_from_its_server_writes_nothing_and_records_no_version(replica):
    a = replica("a")
    job = add_job(a, "toy", "a#0ld0ld00", beat_age=0)  # owned by a's previous process
    mine = TrainJob.owner == a.owner
    assert update_job(a.engine, job, mine, step=7) is False
    with pytest.raises(JobLost):
        _record_success(a.engine, a.settings, job, mine, "toy-20260101-000000-abcdef", {}, "")
    assert (row(a, job).state, row(a, job).step, row(a, job).version) == ("running", 0, None)
    with Session(a.engine) as db:
        assert db.exec(select(ModelVersion)).all() == []


def test_a_training_process_whose_job_was_taken_stops_by_itself(replica, toy_roots, tmp_path):
    """Failed by another replica (or a restart) while it trains: at its next progress report it stops,
    writing nothing more. No heartbeat runs here, so nothing else stops it."""
    shutil.copytree(toy_roots[0], tmp_path / "data")
    a = replica("a")
    job = add_job(a, "toy", a.owner, beat_age=0)
    update_job(a.engine, job, preset="default")  # minutes of training if nothing stopped it
    a.start(job)
    proc = a._procs[job]
    deadline = time.monotonic() + 120
    while row(a, job).step == 0 and proc.is_alive() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert row(a, job).state == "running" and row(a, job).step > 0, row(a, job)
    assert psutil.Process(proc.pid).nice() == os.nice(0) + a.settings.train_nice  # requests go first
    assert update_job(a.engine, job, state=JobState.failed.value, error="taken by another replica")
    taken = row(a, job)
    # Its next report is 50 steps on: a second or two, unless the machine is crowded. The server's watch thread
    # joins the process too, and whichever thread reaps it first sets the exit code: poll it, do not join.
    deadline = time.monotonic() + 180
    while proc.exitcode is None and time.monotonic() < deadline:
        time.sleep(0.1)
    assert proc.exitcode == 0  # it returned: no one killed it
    after = row(a, job)
    assert (after.state, after.error, after.step, after.updated_at) == ("failed", "taken by another replica",
                                                                         taken.step, taken.updated_at)
    assert not a.store.staging(job).exists()
    deadline = time.monotonic() + 5
    while a.store.recorded_jobs() and time.monotonic() < deadline:  # the watch removes the record on exit
        time.sleep(0.05)
    assert a.store.recorded_jobs() == []


def test_jobs_past_the_cap_wait_queued_alive_and_start_as_one_ends(replica, sleepers, monkeypatch):
    a = replica("a", train_max_jobs=1)
    spawned: dict[str, StandInProcess] = {}

    def spawn(runner: JobRunner, job_id: str) -> StandInProcess:
        spawned[job_id] = proc = StandInProcess()
        proc.pid = sleepers()  # what the process record names
        return proc

    monkeypatch.setattr(JobRunner, "_spawn", spawn)
    first, second, third = (add_job(a, domain, a.owner, beat_age=0) for domain in ("toy", "walker", "snake"))
    for job_id in (second, third):
        update_job(a.engine, job_id, state=JobState.queued.value, heartbeat_at=utcnow() - dt.timedelta(seconds=20))
    for job_id in (first, second, third):
        a.start(job_id)
    assert list(spawned) == [first]
    waiting = row(a, second)
    assert (waiting.state, waiting.stage) == ("queued", "waiting for one of 1 training slots (RBA_TRAIN_MAX_JOBS)")
    a.heartbeat()  # a queued job is kept alive: no replica fails it while it waits
    assert (utcnow() - as_utc(row(a, second).heartbeat_at)).total_seconds() < 10
    a.cancel(third)

    spawned[first].terminate()  # the first job's process ends: the next queued one starts
    deadline = time.monotonic() + 30
    while second not in spawned and time.monotonic() < deadline:
        time.sleep(0.02)
    assert list(spawned) == [first, second]
    spawned[second].terminate()
    a.wait(second, 30)
    assert list(spawned) == [first, second] and row(a, third).state == "cancelled"


def test_heartbeat_must_be_well_inside_the_staleness_limit():
    with pytest.raises(ValueError, match=r"job_stale_seconds \(10\) must exceed twice job_heartbeat_seconds \(5\)"):
        Settings(job_heartbeat_seconds=5, job_stale_seconds=10)

