"""SQL tables (sessions, feedback events) and the API's request/response models.

SQLModel's Base / table / Create / Public split: the table classes hold what must survive a
restart (the agent's JSON state included); the Public classes are what the API returns.
Request bodies are strict (``"step": "0"`` or ``"satisfied": "yes"`` are refused, not coerced) and refuse
unknown fields. Names that come from a registry (domains, methods, reps) are ``OneOf`` strings: checked
against the registry as it is now, and listed as an enum in the OpenAPI document.
Imports only ``server.common.feedback`` (the body's feedback rule), so every other module may import it.
"""

from __future__ import annotations

import datetime as dt
import enum
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, GetCoreSchemaHandler, GetJsonSchemaHandler, field_validator, model_validator
from pydantic_core import PydanticCustomError, core_schema
from sqlalchemy import JSON, Boolean, Column, DateTime, UniqueConstraint, false
from sqlmodel import Field, SQLModel

from rba.core.methods import methods
from rba.domains import domain_names
from rba.learn.embed import REPRESENTATIONS
from server.common.feedback import check_kind

STRICT_BODY = ConfigDict(strict=True, extra="forbid")
"""Request bodies: no type coercion, no unknown fields."""


def utcnow() -> dt.datetime:
    return dt.datetime.now(dt.UTC)


def as_utc(value: dt.datetime) -> dt.datetime:
    """SQLite hands back naive datetimes; everything stored is UTC, so say so in the API."""
    return value.replace(tzinfo=dt.UTC) if value.tzinfo is None else value.astimezone(dt.UTC)


def new_session_id() -> str:
    return uuid.uuid4().hex


def attribute_methods() -> tuple[str, ...]:
    """Methods whose agents take more/less feedback (PbRL asks A/B questions: not served here)."""
    return tuple(m.name for m in methods() if m.feedback_kind == "attribute")


@dataclass(frozen=True)
class OneOf:
    """``Annotated[str, OneOf("domain", domain_names)]``: one of the names ``valid()`` lists when the request comes
    (registries grow at run time), an enum of those it lists when the OpenAPI document is made (app start)."""

    kind: str
    valid: Callable[[], tuple[str, ...]]

    def __get_pydantic_core_schema__(self, source: Any, handler: GetCoreSchemaHandler) -> core_schema.CoreSchema:
        return core_schema.no_info_after_validator_function(self.check, handler(source))

    def __get_pydantic_json_schema__(self, schema: core_schema.CoreSchema, handler: GetJsonSchemaHandler) -> dict:
        return {**handler(schema), "enum": list(self.valid())}

    def check(self, value: str) -> str:
        valid = self.valid()
        if value not in valid:
            raise PydanticCustomError("enum", "unknown {kind} {given}; valid: {valid}",
                                      {"kind": self.kind, "given": repr(value), "valid": ", ".join(valid)})
        return value


DomainName = Annotated[str, OneOf("domain", domain_names)]
MethodName = Annotated[str, OneOf("method", attribute_methods)]
RepName = Annotated[str, OneOf("rep", lambda: REPRESENTATIONS)]


class SessionStatus(enum.StrEnum):
    active = "active"
    satisfied = "satisfied"
    abandoned = "abandoned"


# -- sessions -------------------------------------------------------------------------------

class SessionBase(SQLModel):
    domain: str = Field(max_length=64, description="a domain from GET /api/domains, e.g. walker")
    method: str = Field(default="global", max_length=32, description="agent: one of the domain's methods")
    rep: str = Field(default="onehot", max_length=32, description="attribute representation: onehot or language")


class SessionCreate(SessionBase):
    """Body of POST /api/sessions."""

    model_config = STRICT_BODY

    domain: DomainName = Field(description="a domain from GET /api/domains, e.g. walker")
    method: MethodName = Field(default="global", description="agent: one of the domain's methods")
    rep: RepName = Field(default="onehot", description="attribute representation")
    generate: bool | None = Field(default=None, description="make new behaviours when no serve clip is near the "
                                  "agent's target (RBA-Global only); null: the server's RBA_GENERATE")


class TuningSession(SessionBase, table=True):
    """One person tuning one agent; ``agent_state`` is the agent's ``state_dict()``."""

    __tablename__ = "rba_session"

    id: str = Field(default_factory=new_session_id, primary_key=True, max_length=32)
    model_version: str = Field(max_length=128)
    model_set: str = Field(default="builtin", max_length=64, description="models/versions/<model_set>, or builtin")
    library_version: str | None = Field(default=None, max_length=64, description="content hash of the serve library "
                                        "its clip ids name (null: a session from before migration 0006)")
    status: str = Field(default=SessionStatus.active.value, max_length=16, index=True)
    step: int = Field(default=0, ge=0)
    current_rollout_id: str = Field(max_length=128)
    agent_state: dict[str, Any] = Field(sa_column=Column(JSON, nullable=False))
    generate: bool = Field(default=False, sa_column=Column(Boolean, nullable=False, server_default=false()),
                           description="its agent is rba.interact.generating_agent's: agent_state holds generated "
                                       "clips")
    created_at: dt.datetime = Field(default_factory=utcnow, sa_column=Column(DateTime(timezone=True), nullable=False))
    updated_at: dt.datetime = Field(default_factory=utcnow, sa_column=Column(DateTime(timezone=True), nullable=False))


class FeedbackEvent(SQLModel, table=True):
    """One round of feedback: what was shown, what the person said, what came next."""

    __tablename__ = "rba_feedback"
    __table_args__ = (UniqueConstraint("session_id", "step", name="uq_feedback_session_step"),)

    id: int | None = Field(default=None, primary_key=True)
    session_id: str = Field(foreign_key="rba_session.id", index=True, max_length=32)
    step: int = Field(ge=0)
    feedback: Any = Field(sa_column=Column(JSON, nullable=False))  # [{"attribute", "direction"}] or "satisfied"
    rollout_before: str = Field(max_length=128)
    rollout_after: str = Field(max_length=128)
    created_at: dt.datetime = Field(default_factory=utcnow, sa_column=Column(DateTime(timezone=True), nullable=False))


class GeneratedClip(SQLModel, table=True):
    """A rollout a session's agent made (``gen-<hash of domain, params, seed>``): what remakes it, bit for bit.

    Written in the transaction of the step that first showed it; the clip route renders from it.
    """

    __tablename__ = "rba_generated_clip"

    id: str = Field(primary_key=True, max_length=128)
    domain: str = Field(max_length=64)
    params: dict[str, float] = Field(sa_column=Column(JSON, nullable=False))
    seed: int
    proxies: dict[str, float] = Field(sa_column=Column(JSON, nullable=False))
    created_at: dt.datetime = Field(default_factory=utcnow, sa_column=Column(DateTime(timezone=True), nullable=False))


# -- API bodies and responses -------------------------------------------------------------------

Direction = Literal["more", "less"]


class AttributeChoice(BaseModel):
    model_config = STRICT_BODY

    attribute: str = Field(description="an attribute name of the session's domain, e.g. step_size")
    direction: Direction = Field(description="'more' or 'less'")


class FeedbackCreate(BaseModel):
    """Body of POST /api/sessions/{id}/feedback: attribute feedback, or ``satisfied: true``."""

    model_config = STRICT_BODY

    step: int = Field(ge=0, description="the session's current step (409 if it moved on)")
    clip: str | None = Field(default=None, max_length=128,
                             description="the rollout id of the clip this answers about (the session's "
                                         "clip.rollout_id); 409 if the session shows another one")
    feedback: list[AttributeChoice] | None = Field(default=None, max_length=32)
    satisfied: bool = False

    @model_validator(mode="after")
    def _one_kind(self) -> FeedbackCreate:
        check_kind(self.satisfied, bool(self.feedback))
        return self

    def choices(self) -> list[tuple[str, str]]:
        return [(c.attribute, c.direction) for c in self.feedback or ()]


class ReadingPublic(BaseModel):
    """Show ``sign * value`` under ``label``: how a person reads this attribute's measured value."""

    label: str = Field(description="e.g. landing speed")
    sign: int = Field(description="-1: the shown value is minus the measured one")
    note: str = Field(description="which way is more of the attribute, e.g. lower is softer")


class AttributePublic(BaseModel):
    name: str
    description: str
    unit: str
    low: float | None = Field(default=None, description="smallest measured value in the serve library")
    high: float | None = Field(default=None, description="largest measured value in the serve library")
    decimals: int = Field(default=2, description="decimals that show a change a person can tell apart")
    reading: ReadingPublic | None = Field(default=None, description="how to show the value, if not as it is")


class MethodPublic(BaseModel):
    method: str
    rep: str
    label: str = Field(default="", description="display name, e.g. RBA-Global")
    description: str = Field(default="", description="one line on how it chooses the next clip (and, for a "
                             "research representation, what its models read)")
    advanced: bool = Field(default=False, description="a research variant (the language representation): the page "
                           "offers it behind its Advanced choice; the API and the CLI take it as any other")


class TrainablePublic(BaseModel):
    method: str
    label: str = Field(description="display name, e.g. RBA-Global")
    presets: list[str] = Field(description="valid `preset` values of POST /api/admin/train for this method")


class DomainPublic(BaseModel):
    name: str
    attributes: list[AttributePublic]
    frame_rate: float
    available: list[MethodPublic] = Field(description="method/rep pairs whose models and serve library exist")
    missing: str | None = Field(default=None, description="why nothing is available, if so")
    examples: list[str] = Field(default_factory=list, description="feedback in one's own words that POST "
                                "/api/domains/{domain}/interpret reads right: hints for the text box")
    states: Literal["features", "raw", "image"] = Field(
        default="features", description="what the agent's models see: the domain's own features, or a research "
        "view of the same scene: the simulator's raw positions and velocities, or a model of its rendered frames")
    description: str = Field(default="", description="one line on the scene and its skill (and, for a research view, "
                             "what its models see)")
    advanced: bool = Field(default=False, description="a research view (`states` raw or image): the page offers it "
                           "behind its Advanced choice; the API and the CLI take it as any other domain")


class DomainsPublic(BaseModel):
    domains: list[DomainPublic]
    methods: list[str] = Field(description="every agent method the server offers (more/less feedback)")
    reps: list[str] = Field(description="every attribute representation")
    trainable: list[TrainablePublic] = Field(description="methods whose models POST /api/admin/train can retrain")
    generate: bool = Field(default=False, description="whether new sessions make new behaviours unless they say "
                           "otherwise (RBA_GENERATE)")
    generating: list[str] = Field(default_factory=list, description="methods whose sessions can make new behaviours")


class ClipPublic(BaseModel):
    rollout_id: str
    url: str
    data_url: str | None = Field(default=None, description="the clip's per-frame data the page draws itself "
                                 "(GET /api/clips/{domain}/{rollout_id}.json); null where the domain has MP4s only")
    measured: dict[str, float] = Field(description="the clip's measured attribute values (proxies)")
    ready: bool = Field(description="already rendered: the URL answers at once")
    generated: bool = Field(default=False, description="made for this session by a search, not from the serve "
                            "library (its id is gen-<hash>)")


class ClipStatusPublic(BaseModel):
    """GET /api/clips/{domain}/{rollout_id}/status: how far a clip's render is."""

    rollout_id: str
    state: Literal["ready", "queued", "rendering", "absent"] = Field(
        description="ready: stored; queued: waiting for a worker; rendering; absent: not asked for yet")
    elapsed_seconds: float | None = Field(description="since the render was submitted")
    typical_seconds: float | None = Field(description="mean render time of this domain's clips on this server so far")


class TargetRange(BaseModel):
    attribute: str
    low: float = Field(description="measured value (the attribute's unit) at the interval's lower end")
    high: float = Field(description="measured value at the upper end")


class FeedbackPublic(BaseModel):
    step: int
    feedback: list[AttributeChoice] | None
    satisfied: bool
    rollout_before: ClipPublic
    rollout_after: str
    created_at: dt.datetime

    _utc = field_validator("created_at")(as_utc)


class GenerationPublic(BaseModel):
    """GET /api/sessions/{id}/generation: the search for a new behaviour a feedback started (202), if any."""

    step: int = Field(description="the step whose answer started it; the session moves on when it ends")
    state: Literal["searching", "done", "failed"] = Field(
        description="searching: candidates are being simulated; done: the session shows its result (GET it); "
                    "failed: the answer was not taken (detail says why), answer again")
    generation: int = Field(description="CMA-ES generations simulated so far")
    generations: int = Field(description="generations at most (the search may stop early)")
    elapsed_seconds: float = Field(description="since the answer, until the search ended")
    seconds_at_most: float | None = Field(default=None, description="the search's time bound "
                                          "(RBA_GENERATE_SECONDS): no generation starts that would end after it")
    detail: str | None = Field(default=None, description="why it failed")


class SessionPublic(SessionBase):
    id: str
    generate: bool = Field(description="the agent makes new behaviours when no serve clip fits")
    model_version: str
    model_set: str
    status: SessionStatus
    step: int
    clip: ClipPublic
    attributes: list[AttributePublic]
    history: list[FeedbackPublic]
    target: list[TargetRange] | None = Field(
        default=None, description="where the agent believes the target is (the middle half of its belief), "
                                  "for agents that keep such a belief (RBA-Global)")
    generation: GenerationPublic | None = Field(
        default=None, description="a running (or just ended) search for the next clip; poll "
                                  "GET /api/sessions/{id}/generation while it is searching")
    created_at: dt.datetime
    updated_at: dt.datetime

    _utc = field_validator("created_at", "updated_at")(as_utc)
