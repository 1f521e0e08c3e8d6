"""Studies, the experimenter's side: create one (its targets drawn once), list, make participant links.

The design is fixed when a participant is made: their trials' order comes from a balanced Latin square over the
conditions (Williams 1949) and a rotation of each condition's targets, both from the study's seed and the
participant's number, so the same study gives the same plan on any replica.
"""

from __future__ import annotations

import hashlib
import secrets

import numpy as np
from sqlalchemy import func
from sqlalchemy.exc import IntegrityError
from sqlmodel import Session, select

from rba.core.methods import get_method
from rba.data.library import LibraryNotFoundError, SkillLibrary
from server.common.errors import conflict, invalid, not_found
from server.db.study_tables import (
    Participant,
    ParticipantLink,
    ParticipantsPublic,
    Study,
    StudyConfig,
    StudyCreate,
    StudyPublic,
    StudyTrial,
)
from server.runtime.clip_sources import TARGETS
from server.runtime.services import Services


def token_hash(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def target_library(svc: Services, domain: str) -> SkillLibrary:
    """The domain's test split, through the catalog (the clip route serves its clips too)."""
    return svc.catalog.split(domain, TARGETS)


def balanced_latin_square(n: int) -> list[list[int]]:
    """Rows of condition orders in which each condition precedes every other equally often (Williams 1949):
    n rows for even n, 2n (each row and its reverse) for odd n."""
    first, low, high = [0], 1, n - 1
    for j in range(1, n):
        if j % 2:
            first.append(low)
            low += 1
        else:
            first.append(high)
            high -= 1
    rows = [[(c + r) % n for c in first] for r in range(n)]
    return rows + [row[::-1] for row in rows] if n % 2 else rows


def plan(config: StudyConfig, number: int) -> list[tuple[int, str | None]]:
    """Participant ``number``'s trials in order: (condition, target rollout id or None for the free task)."""
    rows = balanced_latin_square(len(config.conditions))
    out: list[tuple[int, str | None]] = []
    k = config.targets_per_condition
    for c in rows[(number + config.seed) % len(rows)]:
        targets = config.targets[c]
        out += [(c, targets[(j + number + c) % k] if targets else None) for j in range(k)]
    return out


def _check_conditions(svc: Services, body: StudyCreate) -> None:
    """422 unless every condition can serve the domain now (its models and the serve library exist)."""
    if not svc.catalog.has_library(body.domain):
        raise invalid(f"domain {body.domain!r} has no serve library ({svc.catalog.missing_reason(body.domain)})")
    for c in body.conditions:
        if get_method(c.method).model_kinds:
            svc.catalog.check_available(body.domain, c.method, c.rep)


def _draw_targets(svc: Services, body: StudyCreate, seed: int) -> list[list[str]]:
    """``targets_per_condition`` distinct test rollouts, seeded, the same for every condition: a paired comparison
    then compares the conditions on equal targets, not on targets that happened to be easier for one of them."""
    if body.task == "free":
        return [[] for _ in body.conditions]
    try:
        test = target_library(svc, body.domain)
    except LibraryNotFoundError as exc:
        raise invalid(f"domain {body.domain!r} has no {TARGETS} split to draw targets from; run "
                      f"`rba build {body.domain}`") from exc
    k = body.targets_per_condition
    if k > len(test):
        raise invalid(f"{k} targets_per_condition, but the {TARGETS} split of {body.domain} has {len(test)} "
                      f"rollouts; ask for at most {len(test)}")
    pick = [test.ids[int(i)] for i in np.random.default_rng(seed).choice(len(test), size=k, replace=False)]
    return [list(pick) for _ in body.conditions]


def create_study(svc: Services, db: Session, body: StudyCreate) -> StudyPublic:
    _check_conditions(svc, body)
    seed = body.seed if body.seed is not None else secrets.randbelow(2**31)
    config = StudyConfig(**{**body.model_dump(), "seed": seed, "targets": _draw_targets(svc, body, seed)})
    study = Study(name=body.name, domain=body.domain, config=config.model_dump(mode="json"))
    db.add(study)
    db.commit()
    db.refresh(study)
    return study_public(db, study)


def load_study(db: Session, study_id: str) -> Study:
    study = db.get(Study, study_id)
    if study is None:
        raise not_found(f"no study {study_id!r}; GET /api/admin/studies lists them")
    return study


def study_config(study: Study) -> StudyConfig:
    return StudyConfig.model_validate(study.config)


def study_public(db: Session, study: Study) -> StudyPublic:
    count = db.exec(select(func.count()).select_from(Participant).where(Participant.study_id == study.id)).one()
    return StudyPublic(id=study.id, config=study_config(study), participants=count, created=study.created_at)


def list_studies(db: Session) -> list[StudyPublic]:
    return [study_public(db, s) for s in db.exec(select(Study).order_by(Study.created_at.desc())).all()]


def add_participants(db: Session, study_id: str, count: int) -> ParticipantsPublic:
    """``count`` new links, each with its trials planned, in one transaction; the tokens are shown only here."""
    study = load_study(db, study_id)
    config = study_config(study)
    start = db.exec(select(func.max(Participant.number)).where(Participant.study_id == study.id)).one()
    start = 0 if start is None else start + 1
    links = []
    for number in range(start, start + count):
        token = secrets.token_urlsafe(24)
        p = Participant(study_id=study.id, number=number, token_hash=token_hash(token))
        db.add(p)
        for position, (condition, target) in enumerate(plan(config, number)):
            db.add(StudyTrial(participant_id=p.id, position=position, condition=condition, target_rollout_id=target))
        links.append(ParticipantLink(id=p.id, number=number, token=token, link=f"/study/{token}"))
    try:
        db.commit()
    except IntegrityError as exc:  # another request numbered the same participants first
        db.rollback()
        raise conflict("another request made links for this study at the same time; ask again") from exc
    return ParticipantsPublic(participants=links)
