"""SQL tables and API models of the admin side: datasets, labels, attributes, training jobs, model versions.

One family per entity, as SQLModel's template has it: ``XBase`` holds the fields the table and
the API share; ``X(XBase, table=True)`` adds the keys and bookkeeping columns; ``XPublic(XBase)``
adds what the API shows beyond them (and ``XCreate`` is the request body). Column names and
types are those the tables always had, so existing SQLite and PostgreSQL databases keep working.
"""

from __future__ import annotations

import datetime as dt
import enum
import uuid
from typing import Annotated, Any

from pydantic import BaseModel, WithJsonSchema, field_validator, model_validator
from pydantic import Field as BodyField  # sqlmodel's Field is for tables
from pydantic_core import PydanticCustomError
from sqlalchemy import JSON, Column, DateTime, Text, UniqueConstraint
from sqlmodel import Field, SQLModel

from rba.core.methods import get_method, train_presets, trainable
from rba.data.labels import Comparison, LocalChange, NewAttribute, Ordering
from server.db.tables import STRICT_BODY, DomainName, OneOf, RepName, as_utc, utcnow

BUILTIN_VERSION = "builtin"  # the models shipped under models/<domain>/


def _time_column() -> Any:
    return Field(default_factory=utcnow, sa_column=Column(DateTime(timezone=True), nullable=False))


# -- datasets -------------------------------------------------------------------------------------

class DatasetBase(SQLModel):
    domain: str = Field(max_length=64, index=True)
    filename: str = Field(max_length=200, description="the uploader's file name, for display only")
    trajectories: int
    labels: int
    new_attributes: list[str] = Field(sa_column=Column(JSON, nullable=False))


class Dataset(DatasetBase, table=True):
    """An uploaded .npz of trajectories + JSON of labels, stored as data/uploads/<domain>/<id>.{npz,json}."""

    __tablename__ = "rba_dataset"

    id: str = Field(primary_key=True, max_length=40, description="content hash of the two files")
    created_at: dt.datetime = _time_column()


class DatasetPublic(DatasetBase):
    id: str
    created_at: dt.datetime
    duplicate: bool = False

    _utc = field_validator("created_at")(as_utc)


# -- attributes admins added ----------------------------------------------------------------------

class AttributeDefBase(SQLModel):
    domain: str = Field(max_length=64, index=True)
    name: str = Field(max_length=32)
    description: str = Field(max_length=300)


class AttributeDef(AttributeDefBase, table=True):
    """An attribute an admin added to a domain (the domain's own ones live in its module)."""

    __tablename__ = "rba_attribute"
    __table_args__ = (UniqueConstraint("domain", "name", name="uq_attribute_domain_name"),)

    id: int | None = Field(default=None, primary_key=True)
    created_at: dt.datetime = _time_column()


class AttributeCreate(NewAttribute):
    """Body of POST /api/admin/attributes (the library's rules for a new attribute's name and description)."""

    model_config = STRICT_BODY

    domain: DomainName


class AttributeDefPublic(SQLModel):
    """One attribute of a domain, as the admin page lists them."""

    name: str
    description: str
    added: bool = Field(description="added by an admin (else the domain's own)")


class AttributeAddedPublic(AttributeDefPublic):
    """Response of POST /api/admin/attributes."""

    domain: str


class AttributesPublic(SQLModel):
    domain: str
    attributes: list[AttributeDefPublic]


# -- labels made on the page ----------------------------------------------------------------------

class LabelBase(SQLModel):
    domain: str = Field(max_length=64, index=True)
    kind: str = Field(max_length=16)
    attribute: str = Field(max_length=32)
    payload: dict[str, Any] = Field(sa_column=Column(JSON, nullable=False))


class LabelRecord(LabelBase, table=True):
    """One label made on the admin page (saved as it is made): an ordering, a comparison or a local change."""

    __tablename__ = "rba_label"

    id: int | None = Field(default=None, primary_key=True)
    created_at: dt.datetime = _time_column()


class LabelCreate(BaseModel):
    """Body of POST /api/admin/labels: exactly one of the three kinds, about library rollouts."""

    model_config = STRICT_BODY

    domain: DomainName
    ordering: Ordering | None = None
    comparison: Comparison | None = None
    local_change: LocalChange | None = None

    def label(self) -> tuple[str, Ordering | Comparison | LocalChange]:
        given = [(k, v) for k, v in (("ordering", self.ordering), ("comparison", self.comparison),
                                     ("local_change", self.local_change)) if v is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of ordering, comparison, local_change")
        return given[0]


class LabelPublic(LabelBase):
    id: int
    created_at: dt.datetime

    _utc = field_validator("created_at")(as_utc)


class ClipToLabel(SQLModel):
    rollout_id: str
    url: str
    data_url: str | None = None  # the clip's per-frame data (null where the domain has MP4s only)


class ClipsToLabelPublic(SQLModel):
    """Response of GET /api/admin/pairs: serve clips to label next."""

    domain: str
    clips: list[ClipToLabel]


# -- training jobs --------------------------------------------------------------------------------

class JobState(enum.StrEnum):
    queued = "queued"
    running = "running"
    succeeded = "succeeded"
    failed = "failed"
    cancelled = "cancelled"


FINISHED = (JobState.succeeded, JobState.failed, JobState.cancelled)


def new_job_id() -> str:
    return uuid.uuid4().hex


class TrainJobBase(SQLModel):
    """What a job trains and how far it got: the fields its table and its API view share."""

    domain: str = Field(max_length=64, index=True)
    method: str = Field(max_length=32)
    rep: str = Field(max_length=32)
    preset: str = Field(max_length=16)
    datasets: list[str] = Field(sa_column=Column(JSON, nullable=False))
    stage: str = Field(default="", max_length=64)
    step: int = 0
    total: int = 0
    loss: float | None = None
    stages: list[dict[str, Any]] | None = Field(default=None, sa_column=Column(JSON), description=(
        "each stage reported so far, in order: total steps, and the step and seconds (since the training process "
        "started) of its first report (first_step, first_at) and its latest (step, at); the time estimate's rates"))
    held_out: dict[str, Any] | None = Field(default=None, sa_column=Column(JSON))
    log_tail: str = Field(default="", sa_column=Column(Text, nullable=False))
    error: str | None = Field(default=None, sa_column=Column(Text))
    version: str | None = Field(default=None, max_length=64)


class TrainJob(TrainJobBase, table=True):
    """A retraining run in its own process; ``busy_domain`` (unique) makes one job per domain at a time.

    The database enforces that rule, so it holds across API replicas. ``owner`` names the server
    process that runs the job (``<replica>#<instance>``) and ``heartbeat_at`` is when it last said
    the job was alive: a job whose heartbeat went stale lost its server, and any replica fails it.
    """

    __tablename__ = "rba_train_job"

    id: str = Field(default_factory=new_job_id, primary_key=True, max_length=32)
    busy_domain: str | None = Field(default=None, max_length=64, unique=True)
    include_page_labels: bool = True
    state: str = Field(default=JobState.queued.value, max_length=16)
    created_at: dt.datetime = _time_column()
    updated_at: dt.datetime = _time_column()
    owner: str | None = Field(default=None, max_length=160)
    heartbeat_at: dt.datetime | None = Field(default=None, sa_column=Column(DateTime(timezone=True)))


# -- model versions -------------------------------------------------------------------------------

class ModelVersionBase(SQLModel):
    version: str = Field(primary_key=True, max_length=64)
    domain: str = Field(max_length=64, index=True)
    method: str = Field(max_length=32)
    rep: str = Field(max_length=32)
    attributes: list[str] = Field(sa_column=Column(JSON, nullable=False))
    held_out: dict[str, Any] = Field(sa_column=Column(JSON, nullable=False))


class ModelVersion(ModelVersionBase, table=True):
    """Models a job wrote under models/versions/<version>/<domain>/."""

    __tablename__ = "rba_model_version"

    job_id: str = Field(max_length=32)
    created_at: dt.datetime = _time_column()


class VersionPublic(ModelVersionBase):
    active: bool
    created_at: dt.datetime | None = Field(description="none for the built-in models")
    scores: dict[str, float | None] = Field(default_factory=dict, description=(
        "headline held-out numbers from the model cards, higher is better; null: untested (no held-out pairs)"))
    baseline: str | None = Field(default=None, description=(
        "the version new sessions of this method/rep get now (null when it is this one)"))
    baseline_scores: dict[str, float | None] = Field(default_factory=dict, description="the baseline's scores")
    concerns: list[str] = Field(default_factory=list, description=(
        "why activating this needs confirming: numbers below the baseline's, untested attributes"))

    _utc = field_validator("created_at")(lambda v: None if v is None else as_utc(v))


class ActiveModel(SQLModel, table=True):
    """Which version new sessions of a domain get (no row: the built-in models)."""

    __tablename__ = "rba_active_model"

    domain: str = Field(primary_key=True, max_length=64)
    version: str = Field(max_length=64)
    updated_at: dt.datetime = _time_column()


def _trainable_names() -> tuple[str, ...]:
    return tuple(m.name for m in trainable())


class TrainCreate(BaseModel):
    """Body of POST /api/admin/train; ``method`` and ``preset`` are checked against the method registry."""

    model_config = STRICT_BODY

    domain: DomainName
    datasets: list[str] = BodyField(default=[], max_length=100, description="ids from GET /api/admin/datasets")
    method: Annotated[str, OneOf("method", _trainable_names)] = "global"
    rep: RepName = "onehot"
    preset: Annotated[str, OneOf("preset", train_presets)] = "default"
    include_page_labels: bool = True

    @model_validator(mode="after")
    def _methods_preset(self) -> TrainCreate:
        """The preset must be the method's own (any method's passed before and failed the job minutes later)."""
        own = tuple(get_method(self.method).presets)
        if self.preset not in own:
            raise PydanticCustomError("enum", "unknown preset {given} for method {method}; valid: {valid}",
                                      {"given": repr(self.preset), "method": self.method, "valid": ", ".join(own)})
        return self


class JobPublic(TrainJobBase):
    id: str
    state: JobState
    progress: float = Field(description="share of the whole job done, 0-1 (its phases weighted by how long they "
                                        "typically take at its preset); stage, step and total are the current "
                                        "stage's")
    eta_seconds: float | None = Field(default=None, description=(
        "estimated seconds left: the current stage's remaining steps at the rate its steps went so far, plus the "
        "typical durations (GET /api/admin/presets) of the phases not started, their steps scaled by how much "
        "faster or slower this job's steps went than typical; null when finished or its method's stages are "
        "unknown"))
    created_at: dt.datetime
    updated_at: dt.datetime

    _utc = field_validator("created_at", "updated_at")(as_utc)


class PresetPublic(BaseModel):
    """A training preset of a method: GET /api/admin/presets."""

    method: str
    preset: str
    description: str = Field(description="what it trains and how big")
    steps: dict[str, int] = Field(description="gradient steps per model kind, for the domain asked about")
    typical_seconds: float = Field(description="how long a job typically takes on 2 CPU cores (measured on walker "
                                               "by benchmarks/training_presets.py)")


class SeriesPublic(BaseModel):
    """One measure of a model's training curve against the gradient step."""

    tag: str = Field(description="'loss', or 'held_out/<measure>' (on val, as the model card's, measured on a fixed "
                                 "part of val while training runs)")
    steps: list[int]
    values: list[float | None] = Field(description="one per step; null where the value was not a number")


class ModelCurvePublic(BaseModel):
    model: str = Field(description="the model file the curve belongs to: <kind>-<rep>")
    series: list[SeriesPublic]


class CurvesPublic(BaseModel):
    """A job's training curves: GET /api/admin/jobs/{id}/curves (partial while the job runs)."""

    job_id: str
    state: JobState
    models: list[ModelCurvePublic] = Field(description=(
        "each model the job fitted so far, in name order; empty before its first step, and for a failed or "
        "cancelled job (nothing it made is kept)"))


class DatasetUpload(BaseModel):
    """The form of POST /api/admin/datasets, for the OpenAPI document (the route parses the stream itself)."""

    domain: DomainName
    labels: bytes = BodyField(description=(
        "a JSON file holding a LabelSet (see Schemas): an object with any of the lists new_attributes, orderings, "
        "comparisons and local_changes, and no other key; a clip is a train or serve rollout id of the domain or a "
        "trajectory name in the .npz. GET /api/admin/datasets/example gives one for a domain"))
    trajectories: Annotated[bytes | None, WithJsonSchema({"type": "string", "format": "binary"})] = BodyField(
        default=None, description="an .npz of float32 [T, state_dim] arrays, one per trajectory name",
        json_schema_extra=lambda schema: schema.pop("default"))  # optional, not null: a form has no null
