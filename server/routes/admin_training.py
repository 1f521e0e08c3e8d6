"""Admin training: start a retraining job, follow it, list model versions and switch the served one."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path
from sqlalchemy.exc import IntegrityError
from sqlmodel import select

from server import labelling
from server.admin_models import (
    BUILTIN_VERSION,
    FINISHED,
    ActiveModel,
    JobPublic,
    ModelVersion,
    TrainCreate,
    TrainJob,
    VersionPublic,
)
from server.auth import require_admin
from server.deps import DbDep, ServicesDep
from server.errors import conflict, invalid, not_found
from server.models import utcnow
from server.versions import active_version

router = APIRouter(prefix="/api/admin", tags=["admin"], dependencies=[Depends(require_admin)],
                   responses={401: {"description": "missing or wrong admin token"},
                              503: {"description": "admin disabled (RBA_ADMIN_TOKEN unset)"}})

JobId = Annotated[str, Path(max_length=64, description="the id POST /api/admin/train returned")]
Version = Annotated[str, Path(max_length=80, description="a version from GET /api/admin/models, or builtin")]


def job_public(job: TrainJob) -> JobPublic:
    progress = 1.0 if job.state == "succeeded" else (job.step / job.total if job.total else 0.0)
    return JobPublic(**job.model_dump(exclude={"busy_domain", "include_page_labels"}), progress=round(progress, 4))


def _job(db, job_id: str) -> TrainJob:
    job = db.get(TrainJob, job_id)
    if job is None:
        raise not_found(f"no training job {job_id!r}; start one with POST /api/admin/train")
    return job


@router.post("/train", status_code=202, response_model=JobPublic,
             responses={409: {"description": "a job for this domain is running"}},
             summary="Start retraining a domain's models in a separate process")
def start_training(body: TrainCreate, svc: ServicesDep, db: DbDep) -> JobPublic:
    if body.domain not in svc.catalog.names():
        raise invalid(f"unknown domain {body.domain!r}; valid: {', '.join(svc.catalog.names())}")
    if not svc.catalog.has_library(body.domain):
        raise invalid(f"{body.domain} has no skill library to train on; run `rba build {body.domain}`")
    labelling.check_datasets(db, body.domain, body.datasets)
    job = TrainJob(domain=body.domain, busy_domain=body.domain, method=body.method, rep=body.rep, preset=body.preset,
                   datasets=list(dict.fromkeys(body.datasets)), include_page_labels=body.include_page_labels)
    db.add(job)
    try:
        db.commit()
    except IntegrityError as e:
        db.rollback()
        running = db.exec(select(TrainJob).where(TrainJob.busy_domain == body.domain)).first()
        raise conflict(f"a training job for {body.domain} is already running ({running.id if running else '?'}); "
                       "wait for it or cancel it") from e
    db.refresh(job)
    svc.jobs.start(job.id)
    return job_public(job)


@router.get("/jobs", response_model=list[JobPublic], summary="Training jobs, newest first")
def list_jobs(db: DbDep, domain: str | None = None) -> list[JobPublic]:
    q = select(TrainJob)
    if domain:
        q = q.where(TrainJob.domain == domain)
    return [job_public(j) for j in db.exec(q.order_by(TrainJob.created_at.desc()).limit(50)).all()]  # type: ignore[attr-defined]


@router.get("/jobs/{job_id}", response_model=JobPublic, summary="A job: state, stage, step, loss, held-out numbers")
def read_job(job_id: JobId, db: DbDep) -> JobPublic:
    return job_public(_job(db, job_id))


@router.post("/jobs/{job_id}/cancel", response_model=JobPublic, summary="Stop a job; nothing it made is kept")
def cancel_job(job_id: JobId, svc: ServicesDep, db: DbDep) -> JobPublic:
    job = _job(db, job_id)
    if job.state in FINISHED:
        raise conflict(f"job {job_id} is {job.state} already")
    svc.jobs.cancel(job_id)
    db.refresh(job)
    return job_public(job)


@router.get("/models", response_model=list[VersionPublic], summary="A domain's model versions (and which is active)")
def list_versions(domain: str, svc: ServicesDep, db: DbDep) -> list[VersionPublic]:
    d = svc.catalog.domain(domain)
    active = active_version(db, d.name)
    out = [VersionPublic(version=BUILTIN_VERSION, domain=d.name, method=m, rep=r, attributes=list(d.attribute_names),
                         held_out={}, active=active == BUILTIN_VERSION, created_at=None)
           for m, r in svc.catalog.available(d.name)[:1]]
    rows = db.exec(select(ModelVersion).where(ModelVersion.domain == d.name).order_by(ModelVersion.created_at)).all()
    out += [VersionPublic(**r.model_dump(), active=r.version == active) for r in rows]
    return out


@router.post("/models/{version}/activate", response_model=VersionPublic,
             summary="Serve this version to new sessions (running sessions keep theirs)")
def activate_version(version: Version, svc: ServicesDep, db: DbDep, domain: str | None = None) -> VersionPublic:
    if version == BUILTIN_VERSION:  # back to the shipped models
        if not domain:
            raise invalid("say which domain goes back to its built-in models: "
                          "POST /api/admin/models/builtin/activate?domain=<name>")
        d = svc.catalog.domain(domain)
        current = db.get(ActiveModel, d.name)
        if current is not None:
            db.delete(current)
            db.commit()
        return VersionPublic(version=BUILTIN_VERSION, domain=d.name, method="global", rep="onehot",
                             attributes=list(d.attribute_names), held_out={}, active=True, created_at=None)
    row = db.get(ModelVersion, version)
    if row is None:
        have = db.exec(select(ModelVersion.version)).all()
        raise not_found(f"no model version {version!r}; versions: {', '.join(have) or 'none yet'}, builtin")
    if (row.method, row.rep) not in svc.catalog.available(row.domain, row.version):
        raise HTTPException(409, f"the files of version {version} are missing under "
                                 f"{svc.catalog.models_root(version)}; it cannot be served")
    current = db.get(ActiveModel, row.domain)
    if current is None:
        current = ActiveModel(domain=row.domain, version=version)
    current.version, current.updated_at = version, utcnow()
    db.add(current)
    db.commit()
    return VersionPublic(**row.model_dump(), active=True)
