"""Studies, the experimenter's routes (admin token): set one up, make participant links, results, the export."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Path
from fastapi.responses import Response

from server.api.auth import ADMIN_ERRORS, require_admin
from server.api.deps import DbDep, ServicesDep
from server.common.errors import responses
from server.db.study_tables import ParticipantsCreate, ParticipantsPublic, StudyCreate, StudyPublic
from server.ops import studies, study_export

router = APIRouter(prefix="/api/admin/studies", tags=["studies"], dependencies=[Depends(require_admin)],
                   responses=responses(*ADMIN_ERRORS))

StudyId = Annotated[str, Path(max_length=64, description="the id POST /api/admin/studies returned")]
NO_STUDY = responses(404, said={404: "no such study"})


@router.post("", response_model=StudyPublic, status_code=201, summary="Set up a study: conditions, task, budget, "
             "precision, consent; its targets are drawn from the test split once")
def create_study(body: StudyCreate, svc: ServicesDep, db: DbDep) -> StudyPublic:
    return studies.create_study(svc, db, body)


@router.get("", response_model=list[StudyPublic], summary="Studies, newest first")
def list_studies(db: DbDep) -> list[StudyPublic]:
    return studies.list_studies(db)


@router.get("/{study_id}", response_model=StudyPublic, responses=NO_STUDY, summary="One study")
def read_study(study_id: StudyId, db: DbDep) -> StudyPublic:
    return studies.study_public(db, studies.load_study(db, study_id))


@router.post("/{study_id}/participants", response_model=ParticipantsPublic, status_code=201,
             responses=responses(404, 409, said={404: "no such study", 409: "another request made links at once"}),
             summary="Make participant links (the only time their tokens are shown)")
def add_participants(study_id: StudyId, body: ParticipantsCreate, db: DbDep) -> ParticipantsPublic:
    return studies.add_participants(db, study_id, body.count)


@router.get("/{study_id}/results", responses=NO_STUDY, summary="Live results: per condition SR, AF, SR@k, time "
            "per answer with 95 % intervals; paired comparisons (the test is named); questionnaires; progress")
def read_results(study_id: StudyId, db: DbDep) -> dict[str, Any]:
    return study_export.results(db, studies.load_study(db, study_id))


@router.get("/{study_id}/export", response_class=Response, responses={
    200: {"content": {"application/zip": {}}, "description": "participants.csv, trials.csv, answers.csv, "
          "questionnaires.csv, codebook.json, study.json, software.json"}, **NO_STUDY},
    summary="Download the study's data (a zip) to rerun the analysis from")
def export_study(study_id: StudyId, db: DbDep) -> Response:
    study = studies.load_study(db, study_id)
    return Response(study_export.export_zip(db, study), media_type="application/zip",
                    headers={"Content-Disposition": f'attachment; filename="rba-study-{study.id}.zip"'})
