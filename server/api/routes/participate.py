"""Studies, the participant's routes: the token in the path is the only credential, and each route looks up only
its own participant (``study_participation.by_token``)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path
from fastapi.responses import Response

from server.api.deps import DbDep, ServicesDep
from server.common.errors import ErrorPublic, responses
from server.db.study_tables import AnswerCreate, ParticipationPublic, QuestionnaireCreate
from server.ops import study_participation as part

GONE = {410: {"model": ErrorPublic, "description": "the participant withdrew; their data was deleted"}}
router = APIRouter(prefix="/api/participate", tags=["participate"],
                   responses={**responses(404, 413, 422, said={404: "no participant has this link"}), **GONE})

Token = Annotated[str, Path(max_length=64, description="the participant's token, from their link /study/<token>")]
CONFLICT = responses(409, said={409: "consent first, not the current trial, or answered already"})


@router.get("/{token}", response_model=ParticipationPublic, summary="Where the participant is: consent, the current "
            "trial (target and clip), or the questionnaire")
def read(token: Token, svc: ServicesDep, db: DbDep) -> ParticipationPublic:
    return part.view(svc, db, part.by_token(db, token))


@router.post("/{token}/consent", response_model=ParticipationPublic, summary="Give consent (idempotent)")
def consent(token: Token, svc: ServicesDep, db: DbDep) -> ParticipationPublic:
    p = part.by_token(db, token)
    part.consent(db, p)
    return part.view(svc, db, p)


@router.post("/{token}/answer", response_model=ParticipationPublic, responses=CONFLICT,
             summary="Answer the current clip: more/less of attributes, or satisfied; the next clip or trial")
def answer(token: Token, body: AnswerCreate, svc: ServicesDep, db: DbDep) -> ParticipationPublic:
    return part.answer(svc, db, part.by_token(db, token), body)


@router.post("/{token}/questionnaire", response_model=ParticipationPublic, responses=CONFLICT,
             summary="The end questionnaire: satisfaction (3 items, 1-7) and the System Usability Scale (10, 1-5)")
def questionnaire(token: Token, body: QuestionnaireCreate, svc: ServicesDep, db: DbDep) -> ParticipationPublic:
    p = part.by_token(db, token)
    part.answer_questionnaire(db, p, body)
    return part.view(svc, db, p)


@router.delete("/{token}", status_code=204, response_class=Response,
               summary="Withdraw: every answer, trial and questionnaire of the participant is deleted")
def withdraw(token: Token, svc: ServicesDep, db: DbDep) -> Response:
    part.withdraw(svc, db, part.by_token(db, token))
    return Response(status_code=204)
