"""Which model version serves what: new sessions get the domain's active version, running ones keep theirs."""

from __future__ import annotations

import re

from sqlmodel import Session

from server.admin_models import BUILTIN_VERSION, ActiveModel
from server.services import Services

VERSION_NAME = re.compile(r"^[a-z0-9_]{1,40}-\d{8}-\d{6}-[0-9a-f]{6}$")  # what jobs name versions


def active_version(db: Session, domain: str) -> str:
    row = db.get(ActiveModel, domain)
    return row.version if row is not None else BUILTIN_VERSION


def serving_version(svc: Services, db: Session, domain: str, method: str, rep: str) -> str:
    """The active version if it has models for (method, rep), else the built-in models."""
    version = active_version(db, domain)
    if version != BUILTIN_VERSION and (method, rep) not in svc.catalog.available(domain, version):
        return BUILTIN_VERSION
    return version
