"""Retraining jobs: each runs in its own (spawned) process so the API stays responsive.

The child writes its progress (stage, step, loss, log tail) to the job's row and its models
into ``models/versions/.tmp-<job>``; only a finished run renames that folder to the version's
name and records the version, in one transaction with the job's success. A failed or
cancelled job leaves nothing that could be served.

Several API replicas may share the database. Each job row names the server process that runs it
(``owner``) and carries a heartbeat that process refreshes; a replica fails only jobs whose
heartbeat went stale (their server died) or that it ran itself before a restart, never a live
job of another replica. A job cancelled through another replica is stopped by its owner at the
next heartbeat. The database's unique ``busy_domain`` keeps one job per domain across replicas.

A job's process dies with its server (``server.runtime.processes``). A restart fails the jobs its previous
process ran, kills their processes if they still run, and sweeps the staging folders, process records
and versions of jobs its database knows are dead (``JobRunner.sweep``). A process whose job was taken
away (failed by a restart or another replica, cancelled) writes nothing more: every write of the child
is conditional on its server still owning an unfinished job, and its models become a version only in
the transaction that records its success.
"""

from __future__ import annotations

import collections
import contextlib
import datetime as dt
import logging
import multiprocessing
import os
import re
import socket
import threading
import time
import uuid

import psutil
from sqlalchemy import func, update
from sqlalchemy.exc import SQLAlchemyError
from sqlmodel import Session, select

from rba.compute.tasks import lower_priority
from rba.core.store import Store
from server.common.app_settings import Settings
from server.db.admin_tables import FINISHED, ActiveModel, JobState, ModelVersion, TrainJob
from server.db.tables import as_utc, utcnow
from server.runtime.processes import Launcher, ProcessRecord, tie_to_parent

log = logging.getLogger(__name__)
JOB_VERSION = re.compile(r".+-\d{8}-\d{6}-(?P<job>[0-9a-f]{6})")  # how a job names the version it publishes
LOG_LINES = 40  # lines of the child's log kept in the job row
STOP_SECONDS = 10.0  # how long a stopping server waits for its cancelled jobs' processes
RECORD_WRITE_SECONDS = 60.0  # a process record's temporary file older than this was left by a crash
STAGING_GRACE_SECONDS = 24 * 3600.0  # a job no row here names may be another database's, still training


def update_job(engine, job_id: str, *where, **changes) -> bool:
    """Change an unfinished job in one statement, if ``where`` holds too; a finished state releases the domain.

    False if nothing changed: the job is finished or gone, or ``where`` failed (another server took it).
    """
    values = {**changes, "updated_at": utcnow()}
    if changes.get("state") in FINISHED:
        values["busy_domain"] = None
    with Session(engine) as db:
        result = db.exec(update(TrainJob)
                         .where(TrainJob.id == job_id, TrainJob.busy_domain.is_not(None), *where)  # type: ignore[union-attr]
                         .values(**values))
        db.commit()
    return result.rowcount == 1


class JobRunner:
    """Starts, watches and cancels the training processes of one server, and keeps their rows alive."""

    def __init__(self, settings: Settings, engine) -> None:
        self.settings, self.engine = settings, engine
        self.store = Store.from_settings(settings)
        self.replica = settings.replica_name
        self.owner = f"{self.replica}#{uuid.uuid4().hex[:8]}"  # this process: a restart is a new owner
        self._procs: dict[str, multiprocessing.process.BaseProcess] = {}
        self._waiting: collections.deque[str] = collections.deque()  # queued for a free slot (train_max_jobs)
        self._lock = threading.Lock()
        self._starting = threading.Lock()  # one start at a time: the slot count holds
        self._stopped = False
        self._halt = threading.Event()
        self._keeper: threading.Thread | None = None
        self._launcher = Launcher("rba-jobs-launcher")

    def recover(self) -> None:
        """At start-up: fail the jobs no server runs any more, kill and sweep what they left, then keep this
        server's jobs alive (a thread)."""
        self.reap(restarted=True)
        self.sweep()
        self._keeper = threading.Thread(target=self._keep, name="rba-jobs-keeper", daemon=True)
        self._keeper.start()

    def reap(self, domain: str | None = None, restarted: bool = False) -> list[str]:
        """Fail the unfinished jobs (of ``domain``, or all) whose server is gone; returns their ids.

        Gone means: no heartbeat for ``job_stale_seconds``, or (with ``restarted``) run by this
        replica's previous process. Each is failed by a conditional update, so a heartbeat that
        lands first, or another replica reaping it too, makes it a no-op. The reaper then kills the
        job's process if it still runs on this machine, and removes its staging folder.
        """
        stale = self.settings.job_stale_seconds
        cutoff = utcnow() - dt.timedelta(seconds=stale)
        with Session(self.engine) as db:
            q = select(TrainJob).where(TrainJob.busy_domain.is_not(None))  # type: ignore[union-attr]
            jobs = db.exec(q if domain is None else q.where(TrainJob.busy_domain == domain)).all()
        with self._lock:
            running_here = set(self._procs) | set(self._waiting)
        reaped = []
        for job in jobs:
            if job.id in running_here:
                continue
            if restarted and job.owner is not None and job.owner.rpartition("#")[0] == self.replica:
                still, error = TrainJob.owner == job.owner, "the server stopped while the job ran"
            elif as_utc(job.heartbeat_at or job.updated_at) < cutoff:
                still = func.coalesce(TrainJob.heartbeat_at, TrainJob.updated_at) < cutoff
                error = f"the server running the job ({job.owner or 'unknown'}) stopped: no heartbeat for {stale:g} s"
            else:
                continue
            if update_job(self.engine, job.id, still, state=JobState.failed.value, error=error):
                log.warning("job %s: %s", job.id, error)
                self._remove_leftovers(job.id)
                reaped.append(job.id)
        return reaped

    def sweep(self) -> None:
        """Kill recorded processes and remove staging folders and versions of jobs this database knows are dead.

        Another server may use the same models folder with another database (a staging server beside a live one,
        a benchmark): its jobs and versions have no rows here, and what this database does not know is not known
        dead. So a version goes only when its job's row here ended without recording it, and leftovers of a job
        no row here names (another database's, or one since replaced) only when no process of it runs on this
        host and nothing of it changed for ``STAGING_GRACE_SECONDS``. Sweeping by knowledge rather than refusing
        to start on a shared folder keeps replicas (one database, one folder) and such neighbours working, and
        needs no lock that a network volume might not honour.

        The folders are listed before the jobs are read: a job's row is written before its folder, so a job
        starting meanwhile is seen as live.
        """
        staged, recorded, published = self.store.staged_jobs(), self.store.recorded_jobs(), self.store.published()
        with Session(self.engine) as db:
            known = dict(db.exec(select(TrainJob.id, TrainJob.busy_domain)).all())
            versions = set(db.exec(select(ModelVersion.version)).all())
        live = {job for job, busy in known.items() if busy is not None}
        for job_id in sorted((set(staged) | set(recorded)) - live):
            if job_id in known or self._abandoned(job_id):
                log.warning("job %s: no server runs it; removing what it left", job_id)
                self._remove_leftovers(job_id)
        for version in published:  # renamed into place, then killed before its row was committed
            made = JOB_VERSION.fullmatch(version)  # a job's name for it: folders put there by hand are not ours
            jobs = [job for job in known if made and job.startswith(made["job"])]
            if jobs and version not in versions and not set(jobs) & live:
                log.warning("version %s: no row names it (its job died while recording it); removing it", version)
                self.store.unpublish(version)
        self.store.sweep_job_records(older_than=RECORD_WRITE_SECONDS)

    def _abandoned(self, job_id: str) -> bool:
        """Whether a job no row here names left its files for good: no process of it runs on this host and nothing
        of it changed within the grace period (a job on another host is known alive by nothing else)."""
        record = ProcessRecord.load(self.store.job_record(job_id))
        if record is not None and record.running():
            return False
        touched = self.store.job_touched(job_id)
        return touched is not None and touched < time.time() - STAGING_GRACE_SECONDS

    def _remove_leftovers(self, job_id: str) -> None:
        """Kill the job's recorded process (if it still runs on this machine), then remove its files."""
        path = self.store.job_record(job_id)
        record = ProcessRecord.load(path)
        if record is not None and record.kill():
            log.warning("job %s: killed its process %d, left running by a server that stopped", job_id, record.pid)
        if record is None or record.host == socket.gethostname():  # another host's record is that host's to act on
            path.unlink(missing_ok=True)
        self.store.discard(job_id)

    def _keep(self) -> None:
        """Every ``job_heartbeat_seconds``: mark this server's jobs alive, and reap those of dead replicas."""
        while not self._halt.wait(self.settings.job_heartbeat_seconds):
            try:
                self.heartbeat()
                self.reap()
            except Exception:  # the database may be restarting, a process may be gone: try again at the next beat
                log.exception("training job heartbeat failed")

    def heartbeat(self) -> None:
        """Mark the jobs this server runs alive; stop the processes of jobs finished elsewhere (cancelled)."""
        with self._lock:
            live, waiting = dict(self._procs), list(self._waiting)
        ids = [*live, *waiting]  # a queued job is alive too: its server will start it
        if not ids:
            return
        with Session(self.engine) as db:
            db.exec(update(TrainJob)
                    .where(TrainJob.id.in_(ids), TrainJob.owner == self.owner,  # type: ignore[attr-defined]
                           TrainJob.busy_domain.is_not(None))  # type: ignore[union-attr]
                    .values(heartbeat_at=utcnow()))
            db.commit()
            ended = db.exec(select(TrainJob.id).where(TrainJob.id.in_(ids),  # type: ignore[attr-defined]
                                                      TrainJob.busy_domain.is_(None))).all()  # type: ignore[union-attr]
        for job_id in ended:
            self._unqueue(job_id)
            if job_id in live and live[job_id].is_alive():
                log.info("job %s was finished by another server: stopping its process", job_id)
                live[job_id].terminate()

    def start(self, job_id: str) -> None:
        """Start the job's process, or queue the job while ``train_max_jobs`` of this server's run: training takes
        every core it is given, so more at once only slows each and the requests; the next starts as one ends."""
        cap = self.settings.train_max_jobs
        with self._starting:
            with self._lock:
                full = len(self._procs) >= cap
                if full:
                    self._waiting.append(job_id)
            if full:
                log.info("job %s waits: %d training jobs run on this server (RBA_TRAIN_MAX_JOBS)", job_id, cap)
                update_job(self.engine, job_id, stage=f"waiting for one of {cap} training slots (RBA_TRAIN_MAX_JOBS)")
                return
            self._launch(job_id)

    def _start_next(self) -> None:
        """Start queued jobs while slots are free (a failed start is recorded on its job: the next is tried)."""
        with self._starting:
            while True:
                with self._lock:
                    if self._stopped or not self._waiting or len(self._procs) >= self.settings.train_max_jobs:
                        return
                    job_id = self._waiting.popleft()
                try:
                    self._launch(job_id)
                except Exception:
                    log.exception("job %s: its training process could not start", job_id)

    def _unqueue(self, job_id: str) -> None:
        with self._lock, contextlib.suppress(ValueError):
            self._waiting.remove(job_id)

    def _launch(self, job_id: str) -> None:
        """Start the job's process, record it and watch it; on failure mark the job failed and raise."""
        try:
            proc = self._spawn(job_id)
        except Exception as exc:  # no process: release the domain at once rather than when the heartbeat goes stale
            update_job(self.engine, job_id, state=JobState.failed.value,
                       error=f"the training process could not start: {type(exc).__name__}: {exc}")
            raise
        with self._lock:
            self._procs[job_id] = proc
        with contextlib.suppress(psutil.NoSuchProcess):  # it ended already: the watch below records how
            ProcessRecord.of(proc.pid).save(self.store.job_record(job_id))
        threading.Thread(target=self._watch, args=(job_id, proc), name=f"rba-watch-{job_id[:8]}", daemon=True).start()

    def _spawn(self, job_id: str) -> multiprocessing.process.BaseProcess:
        """The job's process, started on the launcher's thread (see ``server.runtime.processes``)."""
        ctx = multiprocessing.get_context("spawn")
        from rba.core.methods import method_targets
        from rba.domains import domain_targets

        registry, method_registry = domain_targets(), method_targets()  # plugins registered at run time too
        proc = ctx.Process(target=run_job, args=(job_id, self.owner, os.getpid(), self.settings.model_dump(mode="json"),
                                                 registry, method_registry),
                           name=f"rba-train-{job_id[:8]}", daemon=True)
        self._launcher.start(proc)
        return proc

    def _watch(self, job_id: str, proc) -> None:
        proc.join()
        self.store.job_record(job_id).unlink(missing_ok=True)
        with self._lock:
            self._procs.pop(job_id, None)
            if self._stopped:  # the server is shutting down (and may have closed its database)
                return
        try:  # a no-op when the job recorded its own end
            update_job(self.engine, job_id, state=JobState.failed.value,
                       error=f"the training process exited with code {proc.exitcode} before finishing")
        except SQLAlchemyError:
            log.exception("could not record the end of job %s", job_id)
        self.store.discard(job_id)
        self._start_next()

    def cancel(self, job_id: str) -> None:
        update_job(self.engine, job_id, state=JobState.cancelled.value, error="cancelled by an admin")
        self._unqueue(job_id)
        with self._lock:
            proc = self._procs.get(job_id)
        if proc is not None and proc.is_alive():
            proc.terminate()

    def wait(self, job_id: str, timeout: float) -> None:
        with self._lock:
            proc = self._procs.get(job_id)
        if proc is not None:
            proc.join(timeout)

    def stop(self) -> None:
        """Cancel this server's jobs and wait (briefly) for their processes; the launcher's end kills the rest."""
        self._halt.set()
        if self._keeper is not None:
            self._keeper.join(timeout=10)
        with self._lock:
            procs, waiting = dict(self._procs), list(self._waiting)
        for job_id in [*procs, *waiting]:
            self.cancel(job_id)
        deadline = time.monotonic() + STOP_SECONDS
        for proc in procs.values():
            proc.join(max(0.0, deadline - time.monotonic()))
        with self._lock:
            self._stopped = True
        self._launcher.close()


class _Tail(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.lines: collections.deque[str] = collections.deque(maxlen=LOG_LINES)
        self.setFormatter(logging.Formatter("%(asctime)s %(message)s", "%H:%M:%S"))

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(self.format(record))


class JobLost(RuntimeError):
    """The job was taken from this process (failed by a restart or another replica, or cancelled)."""


def run_job(job_id: str, owner: str, parent_pid: int, settings_json: dict, registry: dict[str, str],
            method_registry: dict[str, str]) -> None:
    """The child process: train from the job's label sources, then publish the version, while ``owner`` owns it."""
    tie_to_parent(parent_pid)
    os.environ.setdefault("MUJOCO_GL", "egl")
    from rba.core import methods
    from rba.domains import register

    for name, target in registry.items():
        register(name, target)
    for name, target in method_registry.items():
        methods.register(name, target)
    from server.db.engine import make_engine

    settings = Settings(**settings_json)
    lower_priority(settings.train_nice)  # training yields the cores to the requests its server answers
    tail = _Tail()
    logging.basicConfig(level=logging.INFO, handlers=[tail])
    engine = make_engine(settings.db_url)
    store = Store.from_settings(settings)
    mine = TrainJob.owner == owner
    try:
        if not update_job(engine, job_id, mine, state=JobState.running.value, stage="loading"):
            raise JobLost(job_id)
        _train_and_publish(engine, store, settings, job_id, mine, tail)
    except JobLost:
        logging.getLogger(__name__).warning("job %s was taken from this process: it stops, writing nothing", job_id)
        store.discard(job_id)
    except Exception as e:
        logging.getLogger(__name__).exception("job %s failed", job_id)
        store.discard(job_id)
        update_job(engine, job_id, mine, state=JobState.failed.value, error=f"{type(e).__name__}: {e}",
                   log_tail="\n".join(tail.lines))


def _train_and_publish(engine, store: Store, settings: Settings, job_id: str, mine, tail: _Tail) -> None:
    """Train into the staging folder, then rename it to the version's name and record both, or raise."""
    from rba.learn.training import StageClock
    from server.runtime.stored_labels import job_sources

    clock = StageClock()  # each stage's rate, for the estimate of the time left

    def progress(stage: str, step: int, total: int, loss: float) -> None:
        if not update_job(engine, job_id, mine, stage=stage, step=step, total=total, loss=float(loss),
                          stages=clock.mark(stage, step, total), log_tail="\n".join(tail.lines)):
            raise JobLost(job_id)

    with Session(engine) as db:
        job = db.get(TrainJob, job_id)
        domain, method, rep, preset = job.domain, job.method, job.rep, job.preset
        sources = job_sources(db, store.uploads(domain), domain, list(job.datasets), job.include_page_labels)
    store.discard(job_id)
    from rba.core import methods

    metrics = methods.get_method(method).trainer(domain, rep, preset, data_root=store.data_dir,
                                                 models_root=store.staging(job_id), sources=sources,
                                                 on_progress=progress)
    version = f"{domain}-{dt.datetime.now(dt.UTC):%Y%m%d-%H%M%S}-{job_id[:6]}"  # matches JOB_VERSION
    with Session(engine) as db:  # what serves the domain now: its other methods' models go along with the new ones
        serving = db.get(ActiveModel, domain)
        source = serving.version if serving is not None else None  # None: the built-in set
    carried = store.carry_over(job_id, domain, source)
    log.info("the other models of %s carried over into %s: %s", source or "the built-in set", version,
             ", ".join(carried) or "none")
    store.publish(job_id, version)
    try:
        _record_success(engine, settings, job_id, mine, version, metrics, "\n".join(tail.lines))
    except BaseException:
        store.unpublish(version)
        raise


def _record_success(engine, settings: Settings, job_id: str, mine, version: str, metrics: dict,
                    log_tail: str) -> None:
    """The job's success and its version in one transaction, only while this process still owns the job."""
    from server.runtime.catalog import Catalog

    with Session(engine) as db:
        job = db.get(TrainJob, job_id)
        result = db.exec(update(TrainJob)
                         .where(TrainJob.id == job_id, TrainJob.busy_domain.is_not(None), mine)  # type: ignore[union-attr]
                         .values(state=JobState.succeeded.value, busy_domain=None, version=version, held_out=metrics,
                                 stage="done", step=TrainJob.total, log_tail=log_tail, updated_at=utcnow()))
        if job is None or result.rowcount != 1:  # cancelled or taken meanwhile: publish nothing
            db.rollback()
            raise JobLost(job_id)
        names = [a["name"] for a in Catalog(settings).card_attributes(job.domain, job.method, job.rep, version)]
        db.add(ModelVersion(version=version, domain=job.domain, method=job.method, rep=job.rep, job_id=job_id,
                            attributes=names, held_out=metrics))
        db.commit()
