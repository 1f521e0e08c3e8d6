"""SQL tables and API models of studies with people: the study, its participants, their trials, answers and
questionnaires (docs/studies.md).

A participant's token is shown once and stored only as its sha256, so the database cannot hand out links. A trial
owns one ``rba_session`` row (the agent), so clips, prerendering and the agents work as for any session; what the
participant must never see (the target's true distance, success) lives on the trial row. Same Base / table / Public
split as ``server.db.admin_tables``.
"""

from __future__ import annotations

import datetime as dt
import uuid
from typing import Annotated, Any, Literal

from pydantic import BaseModel, field_validator, model_validator
from pydantic import Field as BodyField  # sqlmodel's Field is for tables
from pydantic_core import PydanticCustomError
from sqlalchemy import JSON, Column, DateTime, UniqueConstraint
from sqlmodel import Field, SQLModel

from rba.core.methods import get_method, method_names
from server.db.tables import STRICT_BODY, AttributeChoice, AttributePublic, DomainName, OneOf, as_utc, utcnow

SATISFACTION_MAX = 7  # the satisfaction items' scale: 1..7
USABILITY_MAX = 5  # the System Usability Scale's: 1..5


def _new_id() -> str:
    return uuid.uuid4().hex


def _time_column(nullable: bool = False) -> Any:
    if nullable:
        return Field(default=None, sa_column=Column(DateTime(timezone=True), nullable=True))
    return Field(default_factory=utcnow, sa_column=Column(DateTime(timezone=True), nullable=False))


def study_methods() -> tuple[str, ...]:
    """Methods a study may compare: every attribute-feedback method, the floor (random) included, not the ceiling."""
    out = []
    for name in method_names():
        m = get_method(name)
        if m.feedback_kind == "attribute" and m.reference != "ceiling":
            out.append(name)
    return tuple(out)


# -- the configuration ----------------------------------------------------------------------------

class ConditionConfig(BaseModel):
    """One condition: a registered method (``random``: the floor) and its representation (null: the method's own)."""

    model_config = STRICT_BODY

    method: Annotated[str, OneOf("method", study_methods)]
    rep: str | None = BodyField(default=None, max_length=32, description="null: the method's first representation")

    @model_validator(mode="after")
    def _rep(self) -> ConditionConfig:
        reps = get_method(self.method).run_reps
        if self.rep is None:
            self.rep = reps[0]
        elif self.rep not in reps:
            raise PydanticCustomError("enum", "unknown rep {given} for method {method}; valid: {valid}",
                                      {"given": repr(self.rep), "method": self.method, "valid": ", ".join(reps)})
        return self


class StudyCreate(BaseModel):
    """Body of POST /api/admin/studies: what the study compares and how each trial runs."""

    model_config = STRICT_BODY

    name: str = BodyField(min_length=1, max_length=120)
    domain: DomainName
    conditions: list[ConditionConfig] = BodyField(min_length=2, max_length=6, description="2 to 6 conditions, each "
                                                  "a method (incl. the floor 'random'; the ceiling 'oracle' is not a "
                                                  "method people use) and rep")
    task: Literal["target", "free"] = BodyField(default="target", description="target: reach a shown target clip "
                                                "from the test split; free: tune until satisfied")
    targets_per_condition: int = BodyField(default=3, ge=1, le=50, description="trials per condition per "
                                           "participant")
    answer_budget: int = BodyField(default=20, ge=1, le=500, description="more/less answers per trial at most")
    precision: Literal["normal", "high"] = BodyField(default="normal", description="what success means: within "
                                                     "the domain's ε at this precision (Domain.epsilons)")
    consent_text: str = BodyField(min_length=1, max_length=20000)
    seed: int | None = BodyField(default=None, ge=0, le=2**31 - 1, description="draws the targets and the Latin "
                                 "square's rows; null: a random one (stored)")

    @model_validator(mode="after")
    def _distinct(self) -> StudyCreate:
        pairs = [(c.method, c.rep) for c in self.conditions]
        if len(set(pairs)) != len(pairs):
            raise PydanticCustomError("value_error", "conditions repeat a method/rep pair: {pairs}",
                                      {"pairs": ", ".join(f"{m}/{r}" for m, r in pairs)})
        return self


class StudyConfig(StudyCreate):
    """The stored configuration: the body with its seed fixed and the targets drawn (per condition)."""

    seed: int
    targets: list[list[str]] = BodyField(description="per condition, the test rollouts its trials chase (empty for "
                                         "the free task)")


# -- tables ---------------------------------------------------------------------------------------

class Study(SQLModel, table=True):
    __tablename__ = "rba_study"

    id: str = Field(default_factory=_new_id, primary_key=True, max_length=32)
    name: str = Field(max_length=120)
    domain: str = Field(max_length=64)
    config: dict[str, Any] = Field(sa_column=Column(JSON, nullable=False))  # a StudyConfig
    created_at: dt.datetime = _time_column()


class Participant(SQLModel, table=True):
    """One person's link: ``token_hash`` is the sha256 of the token; ``number`` picks the Latin square's row."""

    __tablename__ = "rba_study_participant"
    __table_args__ = (UniqueConstraint("study_id", "number", name="uq_participant_study_number"),)

    id: str = Field(default_factory=_new_id, primary_key=True, max_length=32)
    study_id: str = Field(foreign_key="rba_study.id", index=True, max_length=32)
    number: int = Field(ge=0)
    token_hash: str = Field(max_length=64, unique=True)
    consented_at: dt.datetime | None = _time_column(nullable=True)
    questionnaire_at: dt.datetime | None = _time_column(nullable=True)
    withdrawn_at: dt.datetime | None = _time_column(nullable=True)
    created_at: dt.datetime = _time_column()


class StudyTrial(SQLModel, table=True):
    """One (participant, condition, target) and its tuning session; ``ended`` is null while it runs."""

    __tablename__ = "rba_study_trial"
    __table_args__ = (UniqueConstraint("participant_id", "position", name="uq_trial_participant_position"),)

    id: str = Field(default_factory=_new_id, primary_key=True, max_length=32)
    participant_id: str = Field(foreign_key="rba_study_participant.id", index=True, max_length=32)
    position: int = Field(ge=0)
    condition: int = Field(ge=0)
    target_rollout_id: str | None = Field(default=None, max_length=128)
    session_id: str | None = Field(default=None, foreign_key="rba_session.id", max_length=32)
    answers: int = 0
    feedbacks: int = 0
    ended: str | None = Field(default=None, max_length=16)  # "satisfied" | "budget"
    final_rollout_id: str | None = Field(default=None, max_length=128)
    distance: float | None = None
    success: bool | None = None
    started_at: dt.datetime | None = _time_column(nullable=True)
    ended_at: dt.datetime | None = _time_column(nullable=True)


class StudyAnswer(SQLModel, table=True):
    """One answer: the clip it was about, what was said, time from clip start, replays."""

    __tablename__ = "rba_study_answer"
    __table_args__ = (UniqueConstraint("trial_id", "step", name="uq_answer_trial_step"),)

    id: int | None = Field(default=None, primary_key=True)
    trial_id: str = Field(foreign_key="rba_study_trial.id", index=True, max_length=32)
    step: int = Field(ge=0)
    rollout_id: str = Field(max_length=128)
    feedback: Any = Field(sa_column=Column(JSON, nullable=False))  # [{"attribute", "direction"}] or "satisfied"
    ms: int = Field(ge=0)
    replays: int = Field(ge=0)
    created_at: dt.datetime = _time_column()


class Questionnaire(SQLModel, table=True):
    __tablename__ = "rba_study_questionnaire"

    participant_id: str = Field(foreign_key="rba_study_participant.id", primary_key=True, max_length=32)
    satisfaction: list[int] = Field(sa_column=Column(JSON, nullable=False))
    usability: list[int] = Field(sa_column=Column(JSON, nullable=False))
    created_at: dt.datetime = _time_column()


# -- API bodies and responses ---------------------------------------------------------------------

class StudyPublic(BaseModel):
    id: str
    config: StudyConfig
    participants: int = BodyField(description="links made (withdrawn ones included)")
    created: dt.datetime

    _utc = field_validator("created")(as_utc)


class ParticipantsCreate(BaseModel):
    model_config = STRICT_BODY

    count: int = BodyField(ge=1, le=500)


class ParticipantLink(BaseModel):
    id: str
    number: int
    token: str = BodyField(description="shown only here; the database keeps its sha256")
    link: str = BodyField(description="the participant's page, /study/<token>")


class ParticipantsPublic(BaseModel):
    participants: list[ParticipantLink]


class AttributeFeedbackAnswer(BaseModel):
    model_config = STRICT_BODY

    kind: Literal["attribute"]
    feedback: list[AttributeChoice] = BodyField(min_length=1, max_length=32)


class SatisfiedAnswer(BaseModel):
    model_config = STRICT_BODY

    kind: Literal["satisfied"]


class AnswerCreate(BaseModel):
    """Body of POST /api/participate/{token}/answer."""

    model_config = STRICT_BODY

    trial_id: str = BodyField(max_length=32, description="the current trial's id (409 otherwise)")
    feedback: Annotated[AttributeFeedbackAnswer | SatisfiedAnswer, BodyField(discriminator="kind")]
    ms: int = BodyField(ge=0, le=86_400_000, description="milliseconds from the clip's start to the answer")
    replays: int = BodyField(ge=0, le=10_000, description="times the participant replayed the clip")


class QuestionnaireCreate(BaseModel):
    model_config = STRICT_BODY

    satisfaction: list[Annotated[int, BodyField(ge=1, le=SATISFACTION_MAX)]]
    usability: list[Annotated[int, BodyField(ge=1, le=USABILITY_MAX)]] = BodyField(
        description="the System Usability Scale's 10 items, 1 (strongly disagree) to 5 (strongly agree)")


class ClipRef(BaseModel):
    rollout_id: str
    url: str
    data_url: str | None = BodyField(description="its per-frame data for the page to draw; null: MP4 only")


class TrialView(BaseModel):
    index: int = BodyField(description="0-based position among the participant's trials")
    of: int
    id: str
    label: str = BodyField(description="'Agent A', 'Agent B', ...: conditions are blinded, lettered in the order "
                           "this participant meets them")
    target: ClipRef | None
    clip: ClipRef
    answers_used: int
    answer_budget: int


class ItemView(BaseModel):
    id: str
    text: str
    min: int
    max: int
    low: str = BodyField(description="what the lowest value means")
    high: str = BodyField(description="what the highest value means")


class QuestionnaireView(BaseModel):
    satisfaction: list[ItemView]
    usability: list[ItemView]


class StudyView(BaseModel):
    name: str
    domain: str
    task: str
    consent_text: str
    answer_budget: int
    attributes: list[AttributePublic] = BodyField(description="the attributes the participant answers about")


class ParticipationPublic(BaseModel):
    """GET /api/participate/{token}: where this participant is."""

    study: StudyView
    consented: bool
    finished: bool = BodyField(description="every trial done and the questionnaire answered")
    trial: TrialView | None
    questionnaire: QuestionnaireView | None = BodyField(description="set when every trial is done and the "
                                                        "questionnaire is not answered yet")
