"""Label data as the database and the upload folder hold it, and what a training job learns from it.

Import direction: this module sits low, beside ``server.jobs`` (whose training process reads
it) and under ``server.labelling`` (the admin operations that write it). It imports only
tables and the library, never ``server.services``, ``server.labelling`` or ``server.jobs``.
"""

from __future__ import annotations

from sqlmodel import Session, select

from rba.labels import LabelSet, NewAttribute
from rba.storage import load_npz
from rba.store import UploadFiles
from rba.training import LabelSource
from server.admin_models import AttributeDef, LabelRecord

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


def job_sources(db: Session, uploads: UploadFiles, domain: str, dataset_ids: list[str],
                include_page_labels: bool) -> list[LabelSource]:
    """The label sources of a training job: each dataset in ``uploads`` (with its trajectories), then the page's."""
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
