"""Admin operations on training jobs: start one, read them, cancel one.

Import direction: above ``server.runtime.services`` (its ``JobRunner`` runs the processes) and
``server.ops.label_admin`` (which datasets exist); only the admin routes import it.
"""

from __future__ import annotations

import datetime as dt
import logging
import math
from dataclasses import dataclass

from fastapi import HTTPException
from sqlmodel import Session, select

from rba.core.methods import UnknownMethodError, get_method, trainable
from rba.core.store import ModelFiles
from rba.learn.curves import read_curves
from rba.learn.training import about_preset, get_preset, plan_steps, stage_name
from server.common.errors import conflict, invalid, not_found
from server.db.admin_tables import (
    FINISHED,
    CurvesPublic,
    JobPublic,
    JobState,
    ModelCurvePublic,
    PresetPublic,
    SeriesPublic,
    TrainCreate,
    TrainJob,
)
from server.db.engine import commit_or_conflict
from server.db.tables import as_utc, utcnow
from server.ops.label_admin import check_datasets
from server.runtime.services import Services

log = logging.getLogger(__name__)

JOBS_LISTED = 50  # newest first


@dataclass(frozen=True)
class Phase:
    """One stage of a job's plan: the model kind it fits, its gradient steps, what those typically take."""

    stage: str
    kind: str
    steps: int
    step_seconds: float  # typical, per step
    measure_seconds: float  # typical, after its last step


def job_plan(job: TrainJob) -> tuple[float, list[Phase]]:
    """The job's typical setup seconds and its stages in the order its method trains them; (0, []) for a method or
    preset whose stages are not known (a plugin's trainer may name stages of its own)."""
    try:
        kinds = get_method(job.method).model_kinds
        steps = plan_steps(job.preset, kinds, job.domain)
        typical = get_preset(job.preset).typical
        phases = [Phase(stage_name(k, job.rep), k, n, typical.step[k], typical.measure[k]) for k, n in steps.items()]
    except (UnknownMethodError, ValueError, KeyError):
        return 0.0, []
    return typical.setup, phases


def _rate(report: dict) -> float | None:
    """Seconds per step since a stage's previous report (the pace now: a shared machine's load changes, and a kind's
    first steps are slower), else since its first; None before its second report."""
    for key in ("before", "first"):
        steps = report["step"] - report.get(f"{key}_step", report["step"])
        if steps > 0:
            return (report["at"] - report[f"{key}_at"]) / steps
    return None


def _pace(phases: list[Phase], reports: dict[str, dict]) -> float:
    """How much slower (> 1) or faster this job's measured steps went than typical (the machine's load, the
    domain's size); 1 before any stage measured a rate."""
    took = typical = 0.0
    for ph in phases:
        r = reports.get(ph.stage)
        if r is not None and _rate(r) is not None:
            took += r["at"] - r["first_at"]
            typical += (r["step"] - r["first_step"]) * ph.step_seconds
    return took / typical if took > 0 and typical > 0 else 1.0


def seconds_left(job: TrainJob, now: dt.datetime) -> float | None:
    """Seconds the job has left: the current stage's remaining steps at its measured rate, then the typical
    durations of the phases not started, all scaled by ``_pace``, less the time since the last report;
    None when finished or its stages are unknown."""
    if job.state not in (JobState.queued, JobState.running):
        return None
    setup, phases = job_plan(job)
    if not phases:
        return None
    reports = {r["stage"]: r for r in job.stages or []}
    pace, current = _pace(phases, reports), (job.stages or [{}])[-1].get("stage")
    left = 0.0 if reports else setup * pace
    for ph in phases:
        r = reports.get(ph.stage)
        if r is not None and ph.stage != current:
            continue  # done: a later stage reported
        rate = (_rate(r) if r is not None else None) or ph.step_seconds * pace
        left += (ph.steps - (r["step"] if r is not None else 0)) * rate + ph.measure_seconds * pace
    if job.state == JobState.running:  # a queued job has not started its clock
        left -= (now - as_utc(job.updated_at)).total_seconds()
    return round(max(0.0, left), 1)


def overall_progress(job: TrainJob) -> float:
    """The whole job's share done, each phase weighed by its typical duration at the job's preset (a stage of
    ζσ weighs little at 'tiny' and much at 'default'); the current stage's own share of steps within it."""
    if job.state == JobState.succeeded:
        return 1.0
    setup, phases = job_plan(job)
    within = job.step / job.total if job.total else 0.0
    if not phases:
        return within
    reports = {r["stage"]: r for r in job.stages or []}
    current = (job.stages or [{}])[-1].get("stage")
    whole = setup + sum(ph.steps * ph.step_seconds + ph.measure_seconds for ph in phases)
    done = setup if reports else 0.0
    for ph in phases:
        if ph.stage in reports and ph.stage != current:
            done += ph.steps * ph.step_seconds + ph.measure_seconds
        elif ph.stage == current:
            done += min(reports[ph.stage]["step"], ph.steps) * ph.step_seconds
    return min(1.0, done / whole) if whole > 0 else within


def job_public(job: TrainJob) -> JobPublic:
    return JobPublic.model_validate(job, update={"progress": round(overall_progress(job), 4),
                                                 "eta_seconds": seconds_left(job, utcnow())})


def list_presets(domain: str) -> list[PresetPublic]:
    """Every trainable method's presets: what each trains, how many steps for ``domain``, how long it typically
    takes."""
    out = []
    for m in trainable():
        for name in m.presets:
            description, seconds = about_preset(name, m.model_kinds, domain)
            out.append(PresetPublic(method=m.name, preset=name, description=description, typical_seconds=seconds,
                                    steps=plan_steps(name, m.model_kinds, domain)))
    return out


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
    log.info("job %s (%s %s/%s) cancelled by an admin", job_id, job.domain, job.method, job.rep)
    db.refresh(job)
    return job_public(job)


def job_curves(svc: Services, db: Session, job_id: str) -> CurvesPublic:
    """The job's training curves, read from its event files: in the version it published, or in its staging folder
    while it runs (the curves so far). A failed or cancelled job kept nothing, so it has none."""
    job = load_job(db, job_id)
    if job.version is not None:
        folder = svc.store.models(job.version).curves(job.domain)
    elif job.state in FINISHED:
        folder = None
    else:
        folder = ModelFiles(svc.store.staging(job_id)).curves(job.domain)
    models = [ModelCurvePublic(model=c.model, series=[
        SeriesPublic(tag=s.tag, steps=s.steps, values=[v if math.isfinite(v) else None for v in s.values])
        for s in c.series]) for c in (read_curves(folder) if folder is not None else [])]
    return CurvesPublic(job_id=job.id, state=job.state, models=models)
