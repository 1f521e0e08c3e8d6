"""Admin operations on training jobs: start one, read them, cancel one.

Import direction: above ``server.runtime.services`` (its ``JobRunner`` runs the processes) and
``server.ops.label_admin`` (which datasets exist); only the admin routes import it.
"""

from __future__ import annotations

import datetime as dt
import logging
import statistics

from fastapi import HTTPException
from sqlmodel import Session, select

from rba.core.methods import UnknownMethodError, get_method
from rba.learn.training import stage_name
from server.common.errors import conflict, invalid, not_found
from server.db.admin_tables import BUILTIN_VERSION, FINISHED, JobPublic, JobState, TrainCreate, TrainJob
from server.db.engine import commit_or_conflict
from server.db.tables import as_utc, utcnow
from server.ops.label_admin import check_datasets
from server.runtime.services import Services

log = logging.getLogger(__name__)

JOBS_LISTED = 50  # newest first
ETA_FROM = 0.02  # below this share done, elapsed time says too little to estimate the rest


def stage_weights(svc: Services, job: TrainJob) -> dict[str, float]:
    """Each stage's share of the whole job (summing to 1), in the order the method trains its models.

    A stage weighs what fitting its model took for the domain's shipped models (their cards'
    training seconds): rθ takes several times as long as ζσ, so equal shares would make the bar
    rush and then crawl. A stage without a shipped card weighs the mean of the others.
    """
    try:
        kinds = get_method(job.method).model_kinds
    except UnknownMethodError:
        return {}
    seconds: dict[str, float] = {}
    for kind in kinds:
        card = svc.catalog.card(job.domain, kind, job.rep, BUILTIN_VERSION) or {}
        took = (card.get("training") or {}).get("seconds")
        if isinstance(took, int | float) and took > 0:
            seconds[kind] = float(took)
    fallback = statistics.fmean(seconds.values()) if seconds else 1.0
    weights = {stage_name(kind, job.rep): seconds.get(kind, fallback) for kind in kinds}
    total = sum(weights.values())
    return {stage: w / total for stage, w in weights.items()}


def overall_progress(job: TrainJob, weights: dict[str, float]) -> float:
    """The whole job's share done: the stages before this one, plus this one's steps at its weight."""
    if job.state == JobState.succeeded:
        return 1.0
    within = job.step / job.total if job.total else 0.0
    if job.stage not in weights:  # loading (nothing done yet), or a trainer naming stages of its own
        return within
    stages = list(weights)
    before = sum(weights[s] for s in stages[: stages.index(job.stage)])
    return min(1.0, before + weights[job.stage] * within)


def eta_seconds(job: TrainJob, progress: float, now: dt.datetime) -> float | None:
    """Seconds left if the rest goes as fast as what is done (elapsed since the job was queued); None when
    finished or too early to tell."""
    if job.state not in (JobState.queued, JobState.running) or progress < ETA_FROM:
        return None
    elapsed = (now - as_utc(job.created_at)).total_seconds()
    return round(max(0.0, elapsed * (1 - progress) / progress), 1)


def job_public(svc: Services, job: TrainJob) -> JobPublic:
    progress = overall_progress(job, stage_weights(svc, job))
    return JobPublic.model_validate(job, update={"progress": round(progress, 4),
                                                 "eta_seconds": eta_seconds(job, progress, utcnow())})


def load_job(db: Session, job_id: str) -> TrainJob:
    job = db.get(TrainJob, job_id)
    if job is None:
        raise not_found(f"no training job {job_id!r}; start one with POST /api/admin/train")
    return job


def start_job(svc: Services, db: Session, body: TrainCreate) -> JobPublic:
    """Record the job (one per domain at a time, across replicas: 409 while another runs) and start its process."""
    if not svc.catalog.has_library(body.domain):
        raise invalid(f"{body.domain} has no skill library to train on; run `rba build {body.domain}`")
    check_datasets(db, body.domain, body.datasets)
    svc.jobs.reap(body.domain)  # a job whose replica died holds the domain only until its heartbeat is stale
    job = TrainJob(domain=body.domain, busy_domain=body.domain, method=body.method, rep=body.rep, preset=body.preset,
                   datasets=list(dict.fromkeys(body.datasets)), include_page_labels=body.include_page_labels,
                   owner=svc.jobs.owner, heartbeat_at=utcnow())
    db.add(job)

    def busy() -> str:
        running = db.exec(select(TrainJob).where(TrainJob.busy_domain == body.domain)).first()
        return (f"a training job for {body.domain} is already running ({running.id if running else '?'}); "
                "wait for it or cancel it")

    commit_or_conflict(db, busy)
    db.refresh(job)
    try:
        svc.jobs.start(job.id)  # on failure it marks the job failed, so the domain is free again
    except Exception as exc:
        raise HTTPException(503, f"the training process could not start ({type(exc).__name__}: {exc}); "
                                 "the job is marked failed: try again") from exc
    return job_public(svc, job)


def list_jobs(svc: Services, db: Session, domain: str | None) -> list[JobPublic]:
    q = select(TrainJob)
    if domain:
        q = q.where(TrainJob.domain == domain)
    rows = db.exec(q.order_by(TrainJob.created_at.desc()).limit(JOBS_LISTED)).all()  # type: ignore[attr-defined]
    return [job_public(svc, j) for j in rows]


def cancel_job(svc: Services, db: Session, job_id: str) -> JobPublic:
    job = load_job(db, job_id)
    if job.state in FINISHED:
        raise conflict(f"job {job_id} is {job.state} already")
    svc.jobs.cancel(job_id)
    log.info("job %s (%s %s/%s) cancelled by an admin", job_id, job.domain, job.method, job.rep)
    db.refresh(job)
    return job_public(svc, job)
