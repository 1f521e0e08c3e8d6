"""Admin training: start a retraining job, follow it, list model versions and switch the served one."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Path

from server.api.auth import ADMIN_ERRORS, require_admin
from server.api.deps import DbDep, ServicesDep
from server.common.errors import responses
from server.db.admin_tables import CurvesPublic, JobPublic, PresetPublic, TrainCreate, VersionPublic
from server.db.tables import DomainName
from server.ops import model_versions, training_jobs

router = APIRouter(prefix="/api/admin", tags=["admin"], dependencies=[Depends(require_admin)],
                   responses=responses(*ADMIN_ERRORS))

JobId = Annotated[str, Path(max_length=64, description="the id POST /api/admin/train returned")]
Version = Annotated[str, Path(max_length=80, description="a version from GET /api/admin/models, or builtin")]


@router.post("/train", status_code=202, response_model=JobPublic,
             responses=responses(409, said={409: "a job for this domain is running"}),
             summary="Start retraining a domain's models in a separate process")
def start_training(body: TrainCreate, svc: ServicesDep, db: DbDep) -> JobPublic:
    return training_jobs.start_job(svc, db, body)


@router.get("/jobs", response_model=list[JobPublic], summary="Training jobs, newest first")
def list_jobs(db: DbDep, domain: DomainName | None = None) -> list[JobPublic]:
    return training_jobs.list_jobs(db, domain)


@router.get("/jobs/{job_id}", response_model=JobPublic, responses=responses(404, said={404: "no such job"}),
            summary="A job: state, stage, step, loss, progress, time left, held-out numbers")
def read_job(job_id: JobId, db: DbDep) -> JobPublic:
    return training_jobs.job_public(training_jobs.load_job(db, job_id))


@router.get("/jobs/{job_id}/curves", response_model=CurvesPublic, responses=responses(404, said={404: "no such job"}),
            summary="A job's training curves: each model's loss and held-out measures per step (so far, while it runs)")
def read_curves(job_id: JobId, svc: ServicesDep, db: DbDep) -> CurvesPublic:
    return training_jobs.job_curves(svc, db, job_id)


@router.post("/jobs/{job_id}/cancel", response_model=JobPublic,
             responses=responses(404, 409, said={404: "no such job", 409: "the job has finished already"}),
             summary="Stop a job; nothing it made is kept")
def cancel_job(job_id: JobId, svc: ServicesDep, db: DbDep) -> JobPublic:
    return training_jobs.cancel_job(svc, db, job_id)


@router.get("/presets", response_model=list[PresetPublic],
            summary="Training presets: what each trains, its steps for the domain, its typical duration")
def list_presets(domain: DomainName) -> list[PresetPublic]:
    return training_jobs.list_presets(domain)


@router.get("/models", response_model=list[VersionPublic], summary="A domain's model versions (and which is active)")
def list_versions(domain: DomainName, svc: ServicesDep, db: DbDep) -> list[VersionPublic]:
    return model_versions.list_versions(svc, db, domain)


@router.post("/models/{version}/activate", response_model=VersionPublic,
             responses=responses(404, 409, said={404: "no such version", 409: "the version's files are missing"}),
             summary="Serve this version to new sessions (running sessions keep theirs)")
def activate_version(version: Version, svc: ServicesDep, db: DbDep, domain: DomainName | None = None) -> VersionPublic:
    return model_versions.activate_version(svc, db, version, domain)
