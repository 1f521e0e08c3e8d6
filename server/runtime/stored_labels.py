"""Label data as the database and the upload folder hold it, and what a training job learns from it.

A dataset is whole once its row is committed; its files are written (and renamed into place)
before that, under the dataset's lock (``server.runtime.uploads.claimed``). ``sweep_uploads`` removes at
start-up what uploads cut short left: files without a row, and half-written temporaries.

Import direction: this module sits low, beside ``server.runtime.job_runner`` (whose training process reads
it) and under ``server.ops.label_admin`` (the admin operations that write it). It imports only
tables, ``server.runtime.uploads`` and the library, never ``server.runtime.services``, ``server.ops.label_admin`` or
``server.runtime.job_runner``.
"""

from __future__ import annotations

import logging
import zipfile

from sqlalchemy.engine import Engine
from sqlmodel import Session, select

from rba.core.fileio import load_npz
from rba.core.store import Store, UploadFiles
from rba.data.labels import LabelSet, NewAttribute
from rba.learn.training import LabelSource
from server.db.admin_tables import AttributeDef, Dataset, LabelRecord
from server.runtime.uploads import LEFTOVER_GRACE_SECONDS, abandoned, older_than

log = logging.getLogger(__name__)

LABEL_GROUPS = {"ordering": "orderings", "comparison": "comparisons", "local_change": "local_changes"}
"""A stored label's kind -> the LabelSet field that lists labels of that kind."""


def declared_attributes(db: Session, domain: str) -> dict[str, str]:
    """Attributes admins added to ``domain``: name -> description."""
    rows = db.exec(select(AttributeDef).where(AttributeDef.domain == domain)).all()
    return {r.name: r.description for r in rows}


def page_labels(db: Session, domain: str) -> LabelSet:
    """Every label made on the admin page for ``domain``, oldest first."""
    rows = db.exec(select(LabelRecord).where(LabelRecord.domain == domain).order_by(LabelRecord.id)).all()
    groups: dict[str, list] = {group: [] for group in LABEL_GROUPS.values()}
    for r in rows:
        groups[LABEL_GROUPS[r.kind]].append(r.payload)
    return LabelSet.model_validate(groups)


def _load_dataset(db: Session, uploads: UploadFiles, dataset_id: str) -> LabelSource:
    """One uploaded dataset as a label source; ValueError naming the dataset if its files are not what
    its row says (the training checks every reference again, by the source's name)."""
    name = f"dataset {dataset_id}"
    row = db.get(Dataset, dataset_id)
    labels_file, npz = uploads.labels(dataset_id), uploads.trajectories(dataset_id)
    if row is None:
        raise ValueError(f"{name}: no such dataset is recorded")
    for path, needed in ((labels_file, True), (npz, row.trajectories > 0)):
        if needed and not path.exists():
            raise ValueError(f"{name}: its file {path.name} is missing from {uploads.folder}")
    try:
        labels = LabelSet.model_validate_json(labels_file.read_bytes())
        trajectories = load_npz(npz) if row.trajectories else {}
    except (ValueError, OSError, zipfile.BadZipFile) as e:
        raise ValueError(f"{name}: its stored files cannot be read ({e})") from e
    if len(trajectories) != row.trajectories:
        raise ValueError(f"{name}: {len(trajectories)} trajectories stored where its upload had {row.trajectories}")
    return LabelSource(labels, trajectories, name=name)


def job_sources(db: Session, uploads: UploadFiles, domain: str, dataset_ids: list[str],
                include_page_labels: bool) -> list[LabelSource]:
    """The label sources of a training job: each dataset in ``uploads`` (with its trajectories), then the page's."""
    sources = [_load_dataset(db, uploads, i) for i in dataset_ids]
    if include_page_labels:
        page = page_labels(db, domain)
        if page.size():
            sources.append(LabelSource(page, name=f"the page labels of {domain}"))
    # attributes added on the page (or by another upload) that these labels use
    used = set().union(*(s.labels.attributes_used() for s in sources))
    added = [NewAttribute(name=n, description=d) for n, d in declared_attributes(db, domain).items() if n in used]
    return [LabelSource(LabelSet(new_attributes=added)), *sources] if added else sources


# -- what crashed uploads left ---------------------------------------------------------------------

def _sweep_dataset(engine: Engine, uploads: UploadFiles, dataset_id: str, grace: float) -> list[str]:
    """Remove one dataset's leftovers; returns their names.

    A free lock means its upload died: its temporaries go, and its files too unless its row was
    committed. Without a lock only old leftovers go: temporaries, and files no row refers to.
    A lock a live upload holds keeps everything.
    """
    with abandoned(uploads.lock(dataset_id)) as dead:
        if dead is False:
            return []
        with Session(engine) as db:
            recorded = db.get(Dataset, dataset_id) is not None
        leftovers = uploads.temporaries(dataset_id) + ([] if recorded else uploads.stored(dataset_id))
        if not dead:
            leftovers = [p for p in leftovers if older_than(p, grace)]
        for path in leftovers:
            path.unlink(missing_ok=True)
        return [p.name for p in leftovers] + ([uploads.lock(dataset_id).name] if dead else [])


def sweep_uploads(engine: Engine, store: Store, grace: float = LEFTOVER_GRACE_SECONDS) -> int:
    """At start-up: remove what uploads cut short left in every domain's folder; returns how many files.

    Other replicas may be storing an upload right now: their locks are held, so theirs stay.
    """
    removed = 0
    for uploads in store.upload_folders():
        for dataset_id in sorted(uploads.dataset_ids()):
            try:
                gone = _sweep_dataset(engine, uploads, dataset_id, grace)
            except OSError as e:
                log.warning("uploads: could not sweep %s in %s: %s", dataset_id, uploads.folder, e)
                continue
            if gone:
                log.warning("uploads: removed what an interrupted upload left in %s: %s", uploads.folder,
                            ", ".join(gone))
            removed += len(gone)
    return removed
