"""Admin operations on training jobs: start one, read them, cancel one.

Import direction: above ``server.services`` (its ``JobRunner`` runs the processes) and
``server.labelling`` (which datasets exist); only the admin routes import it.
"""

from __future__ import annotations

from sqlmodel import Session, select

from server.admin_models import FINISHED, JobPublic, JobState, TrainCreate, TrainJob
from server.db import commit_or_conflict
from server.errors import conflict, invalid, not_found
from server.labelling import check_datasets
from server.models import utcnow
from server.services import Services

JOBS_LISTED = 50  # newest first


def job_public(job: TrainJob) -> JobPublic:
    progress = 1.0 if job.state == JobState.succeeded else (job.step / job.total if job.total else 0.0)
    return JobPublic.model_validate(job, update={"progress": round(progress, 4)})


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
    svc.jobs.start(job.id)
    return job_public(job)


def list_jobs(db: Session, domain: str | None) -> list[JobPublic]:
    q = select(TrainJob)
    if domain:
        q = q.where(TrainJob.domain == domain)
    rows = db.exec(q.order_by(TrainJob.created_at.desc()).limit(JOBS_LISTED)).all()  # type: ignore[attr-defined]
    return [job_public(j) for j in rows]


def cancel_job(svc: Services, db: Session, job_id: str) -> JobPublic:
    job = load_job(db, job_id)
    if job.state in FINISHED:
        raise conflict(f"job {job_id} is {job.state} already")
    svc.jobs.cancel(job_id)
    db.refresh(job)
    return job_public(job)
