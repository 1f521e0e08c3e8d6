"""Admin uploads: an .npz of trajectories + a JSON of labels, checked completely before anything is stored."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse

from server import labelling
from server.admin_models import DatasetPublic
from server.auth import require_admin
from server.deps import DbDep, ServicesDep

router = APIRouter(prefix="/api/admin/datasets", tags=["admin"], dependencies=[Depends(require_admin)],
                   responses={401: {"description": "missing or wrong admin token"},
                              503: {"description": "admin disabled (RBA_ADMIN_TOKEN unset)"}})


@router.post("", status_code=201, response_model=DatasetPublic,
             responses={200: {"description": "the same files were uploaded before: nothing new stored"},
                        413: {"description": "over RBA_UPLOAD_MAX_BYTES"},
                        422: {"description": "every problem found, in 'problems'"}},
             summary="Upload labelled behaviour (multipart: domain, labels = JSON file, trajectories = .npz)")
async def upload_dataset(request: Request, svc: ServicesDep, db: DbDep):
    form = await labelling.read_upload_form(request, svc.settings.upload_max_bytes)
    try:
        dataset, new = await labelling.store_upload(svc, db, form)
    except labelling.UploadProblems as e:
        return JSONResponse(status_code=422, content={"detail": e.detail, "problems": e.problems})
    if not new:
        return JSONResponse(status_code=200, content=dataset.model_dump(mode="json"))
    return dataset


@router.get("", response_model=list[DatasetPublic], summary="Uploaded datasets of a domain")
def list_datasets(domain: str, db: DbDep) -> list[DatasetPublic]:
    return labelling.list_datasets(db, domain)
