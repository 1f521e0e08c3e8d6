"""Admin operations on labels: attributes, page labels, uploaded datasets, and clips to label.

Uploads are checked completely (in a workspace folder) before anything is written; then, under
the dataset's lock, the two files are stored atomically under
``data/uploads/<domain>/<content hash>.{npz,json}`` and recorded in one transaction, last: a
crash at any point leaves the whole dataset or leftovers that start-up removes
(``server.runtime.stored_labels.sweep_uploads``, ``server.runtime.uploads.sweep_workspaces``). The uploader's file
name is kept for display only: paths come from the hash.

Import direction: above ``server.runtime.services``, ``server.runtime.stored_labels`` (the stored label data it shares
with training jobs), ``server.ops.views`` and ``server.runtime.uploads`` (the checks); only routes and
``server.ops.training_jobs`` import it.
"""

from __future__ import annotations

import hashlib
import logging
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np
from fastapi import HTTPException, Request
from sqlalchemy.exc import IntegrityError
from sqlmodel import Session, select
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile
from starlette.formparsers import MultiPartException, MultiPartParser

from rba.core.fileio import save_npz, save_text
from rba.core.store import UploadFiles
from rba.data.labels import Comparison, LabelSet, LocalChange, NewAttribute, Ordering, capped
from rba.data.library import SkillLibrary
from rba.domains import Domain
from server.common.app_settings import Settings
from server.common.errors import conflict, invalid
from server.db.admin_tables import (
    AttributeAddedPublic,
    AttributeDef,
    AttributeDefPublic,
    AttributesPublic,
    ClipsToLabelPublic,
    ClipToLabel,
    Dataset,
    DatasetPublic,
    LabelCreate,
    LabelRecord,
)
from server.db.engine import commit_or_conflict
from server.ops.views import clip_data_url, clip_url
from server.runtime.services import Services
from server.runtime.stored_labels import LABEL_GROUPS, declared_attributes
from server.runtime.uploads import UploadLimits, check_labels, check_npz, claimed, workspace

log = logging.getLogger(__name__)


class UploadProblems(HTTPException):
    """422 listing every problem found in an upload (up to ``MAX_PROBLEMS``, then how many more)."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = capped(problems)
        super().__init__(422, detail="; ".join(self.problems))


# -- attributes -----------------------------------------------------------------------------------

def library_ids(svc: Services, domain: str) -> frozenset[str]:
    """Rollouts labels may refer to: ``train`` and ``serve`` (``test`` stays held out)."""
    return frozenset(rid for split in ("train", "serve")
                     for rid in SkillLibrary.load(domain, split, svc.store.data_dir).ids)


def list_attributes(svc: Services, db: Session, domain: str) -> AttributesPublic:
    """The domain's own attributes, then those admins added."""
    d = svc.catalog.domain(domain)
    own = [AttributeDefPublic(name=a.name, description=a.description, added=False) for a in d.attributes]
    added = [AttributeDefPublic(name=n, description=desc, added=True)
             for n, desc in declared_attributes(db, d.name).items()]
    return AttributesPublic(domain=d.name, attributes=own + added)


def add_attribute(svc: Services, db: Session, domain: str, name: str, description: str) -> AttributeAddedPublic:
    d = svc.catalog.domain(domain)
    if name in d.attribute_names:
        raise conflict(f"{name!r} is already an attribute of {domain}")
    row = AttributeDef(domain=domain, name=name, description=description)
    db.add(row)
    commit_or_conflict(db, f"attribute {name!r} of {domain} exists already")
    db.refresh(row)
    return AttributeAddedPublic(domain=row.domain, name=row.name, description=row.description, added=True)


# -- labels made on the page --------------------------------------------------------------------

def add_label(svc: Services, db: Session, body: LabelCreate) -> LabelRecord:
    d = svc.catalog.domain(body.domain)
    try:
        kind, item = body.label()
    except ValueError as e:
        raise invalid(str(e)) from e
    labels = LabelSet.model_validate({LABEL_GROUPS[kind]: [item.model_dump()]})
    problems = labels.problems(declared_attributes(db, d.name), library_ids(svc, d.name), d.attribute_names)
    if problems:
        raise invalid("; ".join(problems))
    row = LabelRecord(domain=d.name, kind=kind, attribute=item.attribute, payload=item.model_dump())
    db.add(row)
    db.commit()
    db.refresh(row)
    return row


def list_labels(db: Session, domain: str, attribute: str | None, limit: int) -> list[LabelRecord]:
    """The newest ``limit`` page labels of ``domain`` (of one ``attribute``, if given)."""
    q = select(LabelRecord).where(LabelRecord.domain == domain)
    if attribute:
        q = q.where(LabelRecord.attribute == attribute)
    return list(db.exec(q.order_by(LabelRecord.id.desc()).limit(limit)).all())  # type: ignore[union-attr]


def nearest(proxies: np.ndarray, anchor: int, k: int) -> list[int]:
    """The ``k`` rollouts closest to ``anchor`` in measured attributes (each scaled to its range), not itself."""
    span = proxies.max(0) - proxies.min(0) + 1e-9
    dist = (((proxies - proxies[anchor]) / span) ** 2).sum(1)
    return [int(i) for i in dist.argsort()[1:k + 1]]


def clips_to_label(svc: Services, db: Session, domain: str, size: int, anchor: bool,
                   seed: int | None) -> ClipsToLabelPublic:
    """``size`` random serve clips (seeded by ``seed``, else by how many labels exist: a reload shows the same).

    With ``anchor``, the first clip is an anchor and the others its nearest neighbours in the
    library's measured attributes: candidates for "the same, but a little more α".
    """
    d = svc.catalog.domain(domain)
    lib = svc.catalog.library(d.name)
    if seed is None:
        seed = len(db.exec(select(LabelRecord.id).where(LabelRecord.domain == d.name)).all())
    rng = random.Random(seed)
    if anchor:
        a = rng.randrange(len(lib))
        picks = [a, *nearest(lib.proxies, a, size - 1)]
    else:
        picks = rng.sample(range(len(lib)), size)
    ids = [lib.ids[i] for i in picks]
    return ClipsToLabelPublic(domain=d.name, clips=[ClipToLabel(rollout_id=r, url=clip_url(d.name, r),
                                                                data_url=clip_data_url(d, r)) for r in ids])


# -- uploads --------------------------------------------------------------------------------------

EXAMPLE_ATTRIBUTE = NewAttribute(name="my_attribute", description="Say in one sentence what more of it looks like.")


def example_labels(svc: Services, domain: str) -> LabelSet:
    """A label file ``domain`` accepts, with one label of each kind about its serve clips, true by their measured
    attributes, and a new attribute declared and used: what the upload form offers to download."""
    d = svc.catalog.domain(domain)
    lib = svc.catalog.library(d.name)
    first, second = d.attribute_names[0], d.attribute_names[-1]
    picks = random.Random(0).sample(range(len(lib)), 3)
    by_first = sorted(picks, key=lambda i: lib.proxies[i, 0])
    a, b = sorted(picks[:2], key=lambda i: -lib.proxies[i, -1])
    anchor = picks[2]
    near = nearest(lib.proxies, anchor, 1)[0]
    name = EXAMPLE_ATTRIBUTE.name if EXAMPLE_ATTRIBUTE.name not in d.attribute_names else f"{EXAMPLE_ATTRIBUTE.name}_2"
    return LabelSet(
        new_attributes=[EXAMPLE_ATTRIBUTE.model_copy(update={"name": name})],
        orderings=[Ordering(attribute=first, clips=[lib.ids[i] for i in by_first]),
                   Ordering(attribute=name, clips=[lib.ids[picks[0]], lib.ids[picks[1]]])],
        comparisons=[Comparison(attribute=second, more=lib.ids[a], less=lib.ids[b])],
        local_changes=[LocalChange(attribute=first, anchor=lib.ids[anchor], changed=lib.ids[near],
                                   direction="more" if lib.proxies[near, 0] > lib.proxies[anchor, 0] else "less")])


async def read_upload_form(request: Request) -> dict[str, UploadFile | str]:
    """The multipart form; its size is capped as it streams by ``server.api.limits.BodyLimit``
    (RBA_UPLOAD_MAX_BYTES)."""
    if not request.headers.get("content-type", "").startswith("multipart/form-data"):
        raise invalid("send multipart/form-data with fields: domain, labels (a JSON file), "
                      "trajectories (an .npz file, optional)")
    try:
        form = await MultiPartParser(request.headers, request.stream(), max_files=2, max_fields=4).parse()
    except MultiPartException as e:
        raise invalid(f"malformed multipart body: {e.message}") from e
    return dict(form.multi_items())


def _limits(settings: Settings) -> UploadLimits:
    return UploadLimits(max_bytes=settings.upload_max_bytes, max_uncompressed=settings.upload_max_uncompressed)


@dataclass
class CheckedUpload:
    """What an upload's two files hold once read, and every problem found in them."""

    filename: str  # the uploader's, for display only
    trajectories: dict[str, np.ndarray] = field(default_factory=dict)
    npz_digest: bytes = hashlib.sha256(b"").digest()  # of the .npz as uploaded
    labels: LabelSet | None = None
    labels_json: bytes = b""  # canonical: what is stored and hashed
    problems: list[str] = field(default_factory=list)

    def dataset_id(self, domain: str) -> str:
        """The content hash the dataset is stored and recorded under."""
        digest = hashlib.sha256(domain.encode() + b"\0" + self.npz_digest + self.labels_json)
        return digest.hexdigest()[:32]


def _form_files(svc: Services, form: dict) -> tuple[Domain, UploadFile, UploadFile | None]:
    domain_name = form.get("domain")
    if not isinstance(domain_name, str) or not domain_name:
        raise invalid("field 'domain' is required (e.g. walker)")
    domain = svc.catalog.domain(domain_name)
    labels_file, npz_file = form.get("labels"), form.get("trajectories")
    if not isinstance(labels_file, UploadFile):
        raise invalid("field 'labels' must be a JSON file")
    if npz_file is not None and not isinstance(npz_file, UploadFile):
        raise invalid("field 'trajectories' must be an .npz file")
    return domain, labels_file, npz_file


def _copy(src: BinaryIO, path: Path) -> tuple[int, bytes]:
    """Copy ``src`` to ``path``; returns its size and SHA-256."""
    h, size = hashlib.sha256(), 0
    with path.open("wb") as out:
        while chunk := src.read(1 << 20):
            h.update(chunk)
            out.write(chunk)
            size += len(chunk)
    return size, h.digest()


def _read_files(labels_file: UploadFile, npz_file: UploadFile | None, state_dim: int,
                limits: UploadLimits) -> CheckedUpload:
    """Both files read and checked on their own (the .npz through a file of our naming in a workspace)."""
    filename = (getattr(labels_file, "filename", None) or "labels.json")[:200]
    if npz_file is not None:
        filename = (npz_file.filename or "trajectories.npz")[:200]
    upload = CheckedUpload(filename)
    if npz_file is not None:
        with workspace() as folder:
            npz_path = folder / "upload.npz"  # our name, never the uploader's
            size, upload.npz_digest = _copy(npz_file.file, npz_path)
            if not size:
                upload.problems.append("trajectories: the file is empty")
            else:
                upload.trajectories, found = check_npz(npz_path, state_dim, limits)
                upload.problems += found
    upload.labels, upload.labels_json, found = check_labels(labels_file.file.read(limits.max_bytes + 1),
                                                            limits.max_bytes)
    upload.problems += found
    return upload


def _label_problems(svc: Services, db: Session, domain: Domain, upload: CheckedUpload) -> list[str]:
    """What is wrong with the labels given the library, the uploaded trajectories and declared attributes."""
    library = library_ids(svc, domain.name)
    clash = sorted(set(upload.trajectories) & library)
    problems = [f"trajectory name {c!r} is also a library rollout id; rename it" for c in clash[:5]]
    problems += upload.labels.problems(declared_attributes(db, domain.name), library | set(upload.trajectories),
                                       domain.attribute_names)
    whole = bool(upload.labels_json)  # not only the part of a set that parsed
    if whole and not upload.labels.size() and upload.labels.new_attributes:  # problems() reports an empty set
        problems.append("labels: no orderings, comparisons or local_changes to learn from")
    return problems


def _record_upload(db: Session, domain: str, dataset_id: str, upload: CheckedUpload) -> tuple[DatasetPublic, bool]:
    """The dataset's row and its new attributes in one transaction; a twin upload that won the race wins."""
    labels = upload.labels
    row = Dataset(id=dataset_id, domain=domain, filename=upload.filename, trajectories=len(upload.trajectories),
                  labels=labels.size(), new_attributes=[a.name for a in labels.new_attributes])
    db.add(row)
    known = declared_attributes(db, domain)
    for a in labels.new_attributes:
        if a.name not in known:
            db.add(AttributeDef(domain=domain, name=a.name, description=a.description))
    try:
        db.commit()
    except IntegrityError:  # the same upload raced us: it is stored once
        db.rollback()
        existing = db.get(Dataset, dataset_id)
        if existing is None:
            raise
        return DatasetPublic.model_validate(existing, update={"duplicate": True}), False
    db.refresh(row)
    log.info("dataset %s for %s: %d trajectories, %d labels", dataset_id, domain, row.trajectories, row.labels)
    return DatasetPublic.model_validate(row), True


def _save_files(uploads: UploadFiles, dataset_id: str, upload: CheckedUpload) -> None:
    """Both files, each written under a temporary name and renamed; none of them if either fails."""
    try:
        if upload.trajectories:
            save_npz(uploads.trajectories(dataset_id), upload.trajectories)
        save_text(uploads.labels(dataset_id), upload.labels_json.decode())
    except BaseException:
        for path in uploads.stored(dataset_id):  # no row refers to them yet
            path.unlink(missing_ok=True)
        raise


def _store(svc: Services, db: Session, domain: str, dataset_id: str,
           upload: CheckedUpload) -> tuple[DatasetPublic, bool]:
    """Files first, the row last, under the dataset's lock: until the row is committed nothing refers to
    the files, and what a crash leaves the start-up sweep removes (``server.runtime.stored_labels.sweep_uploads``)."""
    uploads = svc.store.uploads(domain)
    with claimed(uploads.lock(dataset_id)):  # waits while another request stores the same dataset
        db.rollback()  # a fresh snapshot: see the twin that may have been stored while we waited
        existing = db.get(Dataset, dataset_id)
        if existing is not None:
            return DatasetPublic.model_validate(existing, update={"duplicate": True}), False
        _save_files(uploads, dataset_id, upload)
        return _record_upload(db, domain, dataset_id, upload)


def _check_and_store(svc: Services, db: Session, domain: Domain, labels_file: UploadFile,
                     npz_file: UploadFile | None) -> tuple[DatasetPublic, bool]:
    upload = _read_files(labels_file, npz_file, domain.state_dim, _limits(svc.settings))
    if upload.labels is not None:
        upload.problems += _label_problems(svc, db, domain, upload)
    if upload.problems:
        raise UploadProblems(upload.problems)
    return _store(svc, db, domain.name, upload.dataset_id(domain.name), upload)


async def store_upload(svc: Services, db: Session, form: dict) -> tuple[DatasetPublic, bool]:
    """Check everything, then store; returns the dataset and whether it was new.

    In a worker thread: reading, checking and compressing a large upload takes seconds, which the
    event loop must not wait for, and storing may wait for a twin upload's lock.
    """
    domain, labels_file, npz_file = _form_files(svc, form)
    try:
        return await run_in_threadpool(_check_and_store, svc, db, domain, labels_file, npz_file)
    finally:
        for f in (labels_file, npz_file):
            if f is not None:
                await f.close()


def list_datasets(db: Session, domain: str) -> list[DatasetPublic]:
    rows = db.exec(select(Dataset).where(Dataset.domain == domain).order_by(Dataset.created_at)).all()
    return [DatasetPublic.model_validate(r) for r in rows]


def check_datasets(db: Session, domain: str, ids: list[str]) -> None:
    """422 unless every id is an uploaded dataset of ``domain``."""
    for i in ids:
        row = db.get(Dataset, i)
        if row is None or row.domain != domain:
            have = db.exec(select(Dataset.id).where(Dataset.domain == domain)).all()
            raise invalid(f"no dataset {i!r} for {domain}; uploaded: {', '.join(have) or 'none'}")
