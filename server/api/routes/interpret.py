"""POST /api/domains/{domain}/interpret: a sentence ("land more gently") -> attribute feedback to confirm."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Path
from pydantic import BaseModel, Field, field_validator

from rba.interact.free_text import LOW_CONFIDENCE, MAX_TEXT, Understood
from server.api.deps import ServicesDep
from server.common.errors import responses
from server.db.tables import STRICT_BODY, DomainName
from server.ops import text_feedback

router = APIRouter(prefix="/api/domains", tags=["interpret"])

class InterpretCreate(BaseModel):
    """Body: the sentence a person typed."""

    model_config = STRICT_BODY

    text: str = Field(description=f"feedback in your own words, at most {MAX_TEXT} characters",
                      examples=["land more gently", "bigger but softer steps"])

    @field_validator("text")
    @classmethod
    def _a_sentence(cls, text: str) -> str:
        if not text.strip():
            raise ValueError("is empty: say what to change, e.g. 'land more gently'")
        if len(text) > MAX_TEXT:
            raise ValueError(f"is {len(text)} characters long; at most {MAX_TEXT}: one or two short sentences")
        return text


class InterpretedChoice(BaseModel):
    model_config = STRICT_BODY

    attribute: str = Field(description="an attribute name of the domain, e.g. softness")
    direction: Literal["more", "less"]


Reading = list[InterpretedChoice]


class InterpretPublic(BaseModel):
    """What the sentence was understood as: send ``feedback`` (or the chosen one of ``alternatives``) as the
    session's feedback once confirmed."""

    model_config = STRICT_BODY

    feedback: Reading = Field(description="the likeliest reading, in the sentence's order; never empty")
    confidence: float = Field(ge=0.0, le=1.0, description="the least certain clause's score: cosine similarity "
                              "to the closest anchor phrase, plus a bonus for a cue word, at most 1")
    low_confidence: bool = Field(description=f"confidence below {LOW_CONFIDENCE}: ask which reading was meant "
                                 "rather than for a yes / no (docs/decisions/0021-free-text-low-confidence.md)")
    alternatives: list[Reading] = Field(description="when low_confidence: the two likeliest readings to choose "
                                        "from, likeliest first (the first is `feedback`); otherwise empty")

    @classmethod
    def of(cls, understood: Understood) -> InterpretPublic:
        def reading(pairs: tuple[tuple[str, str], ...]) -> Reading:
            return [InterpretedChoice(attribute=a, direction=d) for a, d in pairs]

        return cls(feedback=reading(understood.feedback), confidence=round(understood.confidence, 3),
                   low_confidence=understood.low_confidence, alternatives=list(map(reading, understood.alternatives)))


ERRORS = responses(413, 422, said={
    422: "unknown domain, empty or too long text, or not understood: the message lists the valid names"})


@router.post("/{domain}/interpret", response_model=InterpretPublic, responses=ERRORS,
             summary="Map a sentence of feedback to more/less of the domain's attributes")
def interpret(domain: Annotated[DomainName, Path()], body: InterpretCreate, svc: ServicesDep) -> InterpretPublic:
    return InterpretPublic.of(text_feedback.interpret(svc, domain, body.text))
