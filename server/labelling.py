"""Admin operations on labels: attributes, page labels, uploaded datasets, and what a job trains on.

Uploads are checked completely before anything is written; then the two files are stored
atomically under ``data/uploads/<domain>/<content hash>.{npz,json}`` and recorded in one
transaction. The uploader's file name is kept for display only: paths come from the hash.
"""

from __future__ import annotations

import hashlib
import logging
import shutil
import tempfile
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
from fastapi import HTTPException, Request
from sqlalchemy.exc import IntegrityError
from sqlmodel import Session, select
from starlette.datastructures import UploadFile
from starlette.formparsers import MultiPartException, MultiPartParser

from rba.labels import LabelSet, NewAttribute
from rba.library import SkillLibrary
from rba.storage import load_npz, save_npz, save_text
from rba.store import Store
from rba.training import LabelSource
from server.admin_models import AttributeDef, Dataset, DatasetPublic, LabelCreate, LabelRecord
from server.errors import invalid
from server.services import Services
from server.settings import Settings
from server.uploads import UploadLimits, check_labels, check_npz

log = logging.getLogger(__name__)


class UploadProblems(HTTPException):
    """422 listing every problem found in an upload."""

    def __init__(self, problems: list[str]) -> None:
        super().__init__(422, detail="; ".join(problems))
        self.problems = problems


# -- what exists ----------------------------------------------------------------------------------

def declared_attributes(db: Session, domain: str) -> dict[str, str]:
    rows = db.exec(select(AttributeDef).where(AttributeDef.domain == domain)).all()
    return {r.name: r.description for r in rows}


def library_ids(svc: Services, domain: str) -> frozenset[str]:
    """Rollouts labels may refer to: ``train`` and ``serve`` (``test`` stays held out)."""
    return frozenset(rid for split in ("train", "serve")
                     for rid in SkillLibrary.load(domain, split, svc.store.data_dir).ids)


def add_attribute(svc: Services, db: Session, domain: str, name: str, description: str) -> AttributeDef:
    d = svc.catalog.domain(domain)
    if name in d.attribute_names:
        raise HTTPException(409, f"{name!r} is already an attribute of {domain}")
    row = AttributeDef(domain=domain, name=name, description=description)
    db.add(row)
    try:
        db.commit()
    except IntegrityError as e:
        db.rollback()
        raise HTTPException(409, f"attribute {name!r} of {domain} exists already") from e
    db.refresh(row)
    return row


# -- labels made on the page --------------------------------------------------------------------

def add_label(svc: Services, db: Session, body: LabelCreate) -> LabelRecord:
    d = svc.catalog.domain(body.domain)
    try:
        kind, item = body.label()
    except ValueError as e:
        raise invalid(str(e)) from e
    key = {"ordering": "orderings", "comparison": "comparisons", "local_change": "local_changes"}[kind]
    labels = LabelSet.model_validate({key: [item.model_dump()]})
    problems = labels.problems(declared_attributes(db, d.name), library_ids(svc, d.name), d.attribute_names)
    if problems:
        raise invalid("; ".join(problems))
    row = LabelRecord(domain=d.name, kind=kind, attribute=item.attribute, payload=item.model_dump())
    db.add(row)
    db.commit()
    db.refresh(row)
    return row


def page_labels(db: Session, domain: str) -> LabelSet:
    rows = db.exec(select(LabelRecord).where(LabelRecord.domain == domain).order_by(LabelRecord.id)).all()
    groups: dict[str, list] = {"orderings": [], "comparisons": [], "local_changes": []}
    for r in rows:
        groups[{"ordering": "orderings", "comparison": "comparisons", "local_change": "local_changes"}[r.kind]].append(
            r.payload)
    return LabelSet.model_validate(groups)


# -- uploads --------------------------------------------------------------------------------------

async def _limited(request: Request, limit: int) -> AsyncIterator[bytes]:
    """The request body, stopped with 413 as soon as it passes ``limit`` bytes."""
    received = 0
    async for chunk in request.stream():
        received += len(chunk)
        if received > limit:
            raise HTTPException(413, f"upload too large: over the limit of {limit} bytes (RBA_UPLOAD_MAX_BYTES)")
        yield chunk


async def read_upload_form(request: Request, limit: int) -> dict[str, UploadFile | str]:
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > limit:
        raise HTTPException(413, f"upload too large: {declared} bytes, over the limit of {limit} bytes "
                                 "(RBA_UPLOAD_MAX_BYTES)")
    if not request.headers.get("content-type", "").startswith("multipart/form-data"):
        raise invalid("send multipart/form-data with fields: domain, labels (a JSON file), "
                      "trajectories (an .npz file, optional)")
    try:
        form = await MultiPartParser(request.headers, _limited(request, limit), max_files=2, max_fields=4).parse()
    except MultiPartException as e:
        raise invalid(f"malformed multipart body: {e.message}") from e
    return dict(form.multi_items())


def _limits(settings: Settings) -> UploadLimits:
    return UploadLimits(max_bytes=settings.upload_max_bytes, max_uncompressed=settings.upload_max_uncompressed)


async def store_upload(svc: Services, db: Session, form: dict) -> tuple[DatasetPublic, bool]:
    """Check everything, then store; returns the dataset and whether it was new."""
    domain_name = form.get("domain")
    if not isinstance(domain_name, str) or not domain_name:
        raise invalid("field 'domain' is required (e.g. walker)")
    domain = svc.catalog.domain(domain_name)
    labels_file, npz_file = form.get("labels"), form.get("trajectories")
    if not isinstance(labels_file, UploadFile):
        raise invalid("field 'labels' must be a JSON file")
    if npz_file is not None and not isinstance(npz_file, UploadFile):
        raise invalid("field 'trajectories' must be an .npz file")
    limits = _limits(svc.settings)
    problems: list[str] = []
    with tempfile.TemporaryDirectory(prefix="rba-upload-") as tmp:
        npz_path = Path(tmp) / "upload.npz"  # our name, never the uploader's
        trajectories: dict[str, np.ndarray] = {}
        npz_bytes = b""
        if npz_file is not None:
            with npz_path.open("wb") as out:
                shutil.copyfileobj(npz_file.file, out)
            npz_bytes = npz_path.read_bytes()
            if not npz_bytes:
                problems.append("trajectories: the file is empty")
            else:
                trajectories, found = check_npz(npz_path, domain.state_dim, limits)
                problems += found
        labels, labels_json, found = check_labels(await labels_file.read(), limits.max_bytes)
        problems += found
    if labels is not None:
        library = library_ids(svc, domain.name)
        clash = sorted(set(trajectories) & library)
        problems += [f"trajectory name {c!r} is also a library rollout id; rename it" for c in clash[:5]]
        problems += labels.problems(declared_attributes(db, domain.name), library | set(trajectories),
                                    domain.attribute_names)
        if not labels.size() and labels.new_attributes:  # problems() reports a wholly empty set itself
            problems.append("labels: no orderings, comparisons or local_changes to learn from")
    if problems:
        raise UploadProblems(problems)
    digest = hashlib.sha256(domain.name.encode() + b"\0" + hashlib.sha256(npz_bytes).digest() + labels_json)
    dataset_id = digest.hexdigest()[:32]
    existing = db.get(Dataset, dataset_id)
    if existing is not None:
        return DatasetPublic(**existing.model_dump(), duplicate=True), False
    uploads = svc.store.uploads(domain.name)
    if trajectories:
        save_npz(uploads.trajectories(dataset_id), trajectories)
    save_text(uploads.labels(dataset_id), labels_json.decode())
    filename = (getattr(labels_file, "filename", None) or "labels.json")[:200]
    if npz_file is not None:
        filename = (npz_file.filename or "trajectories.npz")[:200]
    row = Dataset(id=dataset_id, domain=domain.name, filename=filename, trajectories=len(trajectories),
                  labels=labels.size(), new_attributes=[a.name for a in labels.new_attributes])
    db.add(row)
    known = declared_attributes(db, domain.name)
    for a in labels.new_attributes:
        if a.name not in known:
            db.add(AttributeDef(domain=domain.name, name=a.name, description=a.description))
    try:
        db.commit()
    except IntegrityError:  # the same upload raced us: it is stored once
        db.rollback()
        existing = db.get(Dataset, dataset_id)
        if existing is None:
            raise
        return DatasetPublic(**existing.model_dump(), duplicate=True), False
    db.refresh(row)
    log.info("dataset %s for %s: %d trajectories, %d labels", dataset_id, domain.name, row.trajectories, row.labels)
    return DatasetPublic(**row.model_dump()), True


# -- what a job trains on ----------------------------------------------------------------------------

def check_datasets(db: Session, domain: str, ids: list[str]) -> None:
    for i in ids:
        row = db.get(Dataset, i)
        if row is None or row.domain != domain:
            have = db.exec(select(Dataset.id).where(Dataset.domain == domain)).all()
            raise invalid(f"no dataset {i!r} for {domain}; uploaded: {', '.join(have) or 'none'}")


def job_sources(db: Session, store: Store, domain: str, dataset_ids: list[str],
                include_page_labels: bool) -> list[LabelSource]:
    """The label sources of a training job: each dataset (with its trajectories), then the page's labels."""
    uploads = store.uploads(domain)
    sources = []
    for i in dataset_ids:
        labels = LabelSet.model_validate_json(uploads.labels(i).read_text(encoding="utf-8"))
        npz = uploads.trajectories(i)
        sources.append(LabelSource(labels, load_npz(npz) if npz.exists() else {}))
    if include_page_labels:
        page = page_labels(db, domain)
        if page.size():
            sources.append(LabelSource(page))
    # attributes added on the page (or by another upload) that these labels use
    used = set().union(*(s.labels.attributes_used() for s in sources))
    added = [NewAttribute(name=n, description=d) for n, d in declared_attributes(db, domain).items() if n in used]
    return [LabelSource(LabelSet(new_attributes=added)), *sources] if added else sources
