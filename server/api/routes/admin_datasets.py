"""Admin uploads: an .npz of trajectories + a JSON of labels, checked completely before anything is stored."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request, Response
from fastapi.responses import JSONResponse

from rba.data.labels import LabelSet
from server.api.auth import ADMIN_ERRORS, require_admin
from server.api.deps import DbDep, ServicesDep
from server.common.errors import error_response, responses
from server.db.admin_tables import DatasetPublic
from server.db.tables import DomainName
from server.ops import label_admin

router = APIRouter(prefix="/api/admin/datasets", tags=["admin"], dependencies=[Depends(require_admin)],
                   responses=responses(*ADMIN_ERRORS))

UPLOAD_FORM = {  # the route streams and parses the form itself (under RBA_UPLOAD_MAX_BYTES): FastAPI cannot see it
    "required": True,
    "content": {"multipart/form-data": {"schema": {"$ref": "#/components/schemas/DatasetUpload"},
                                        "encoding": {"labels": {"contentType": "application/json"}}}},
}


@router.post("", status_code=201, response_model=DatasetPublic, openapi_extra={"requestBody": UPLOAD_FORM},
             responses={200: {"model": DatasetPublic,
                              "description": "the same files were uploaded before: nothing new stored"},
                        **responses(404, 413, 422, said={404: "unknown domain", 413: "over RBA_UPLOAD_MAX_BYTES",
                                                         422: "every problem found, in 'problems'"})},
             summary="Upload labelled behaviour (multipart: domain, labels = JSON file, trajectories = .npz)",
             description="The labels file is a LabelSet (see Schemas; GET /api/admin/datasets/example gives one "
                         "for a domain). Every problem of both files is listed in one 422.")
async def upload_dataset(request: Request, svc: ServicesDep, db: DbDep):
    form = await label_admin.read_upload_form(request)
    try:
        dataset, new = await label_admin.store_upload(svc, db, form)
    except label_admin.UploadProblems as e:
        return error_response(422, e.detail, problems=e.problems)
    if not new:
        return JSONResponse(status_code=200, content=dataset.model_dump(mode="json"))
    return dataset


@router.get("/example", response_model=LabelSet, response_description="a label file (JSON) the domain accepts",
            responses=responses(404, said={404: "the domain has no serve library"}),
            summary="An example label file for a domain: every kind of label, about its serve clips")
def example_labels(domain: DomainName, svc: ServicesDep, response: Response) -> LabelSet:
    response.headers["Content-Disposition"] = f'attachment; filename="labels-example-{domain}.json"'
    return label_admin.example_labels(svc, domain)


@router.get("", response_model=list[DatasetPublic], summary="Uploaded datasets of a domain")
def list_datasets(domain: DomainName, db: DbDep) -> list[DatasetPublic]:
    return label_admin.list_datasets(db, domain)
