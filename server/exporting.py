"""Export a satisfied session (``GET /api/sessions/{id}/export`` and ``rba export``): ``rba.export``'s zip.

The operation reads the session and its feedback rows, the serve library and the session's model set,
and the chosen clip's MP4: the app asks its clip cache (rendered on the compute layer if missing); the
command line, which starts no app, renders in its own process into the same clip store.

Import direction: beside ``server.sessions`` (above ``server.services``); the route and ``rba export``
(by name, as ``rba serve`` imports the app) use it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from sqlmodel import Session, select

from rba.clips import ClipKey
from rba.domains import domain_target
from rba.export import ExportError, ExportSource, Profile, build_export, export_bytes, write_export
from rba.library import SkillLibrary
from server.catalog import Catalog
from server.errors import conflict, not_found
from server.models import FeedbackEvent, SessionStatus, TuningSession
from server.services import Services
from server.settings import Settings

log = logging.getLogger(__name__)

CLIP_WAIT_SECONDS = 120.0  # an export waits this long at most for its clip to render

ClipBytes = Callable[[SkillLibrary, str], bytes]  # (serve library, rollout id) -> the clip's MP4


def export_source(catalog: Catalog, db: Session, session_id: str, clip: ClipBytes) -> ExportSource:
    """What the export of ``session_id`` is made of; 404 for an unknown session, 409 unless it ended satisfied."""
    s = db.get(TuningSession, session_id)
    if s is None:
        raise not_found(f"no session {session_id!r}; create one with POST /api/sessions")
    if s.status != SessionStatus.satisfied:
        raise conflict(f"session {s.id} is {s.status}: only a session that ended satisfied (\"This is it\") can "
                       "be exported")
    events = db.exec(select(FeedbackEvent).where(FeedbackEvent.session_id == s.id)
                     .order_by(FeedbackEvent.step)).all()
    rounds = [{"step": e.step, "feedback": e.feedback, "rollout_before": e.rollout_before,
               "rollout_after": e.rollout_after} for e in events]
    library = catalog.library(s.domain)
    return ExportSource(domain=s.domain, method=s.method, rep=s.rep, model_version=s.model_version,
                        model_set=s.model_set, models_root=catalog.models(s.model_set).root, library=library,
                        rollout_id=s.current_rollout_id, feedback=rounds, clip=clip(library, s.current_rollout_id))


def export_session(svc: Services, db: Session, session_id: str) -> tuple[Profile, bytes]:
    """The profile and zip bytes of a satisfied session; its clip comes from the app's clip cache."""
    def clip(library: SkillLibrary, rollout_id: str) -> bytes:
        path = svc.clips.request(svc.clips.key(library, rollout_id), library, urgent=True).result(CLIP_WAIT_SECONDS)
        return Path(path).read_bytes()

    src = export_source(svc.catalog, db, session_id, clip)
    try:
        profile, reward = build_export(src)
    except ExportError as exc:
        raise conflict(str(exc)) from exc
    log.info("session %s exported: %s %s seed %d", session_id, src.domain, src.rollout_id, profile.seed)
    return profile, export_bytes(profile, reward, src.clip)


def export_to_file(session_id: str, out: Path, settings: Settings | None = None) -> Profile:
    """``rba export``: the app's database and files (the server's settings), the zip written atomically to ``out``.

    Raises ``LookupError`` for an unknown session and ``ValueError`` for one that cannot be exported.
    """
    from fastapi import HTTPException

    from rba.compute.tasks import render_clip
    from server.db import make_engine

    settings = settings or Settings()
    catalog = Catalog(settings)
    store = catalog.store.clips()

    def clip(library: SkillLibrary, rollout_id: str) -> bytes:
        key = ClipKey(library.domain, library.version, rollout_id, settings.clip_width, settings.clip_height)
        if not store.exists(key):
            rollout = library.rollout(library.index_of(rollout_id))
            data = render_clip(domain_target(library.domain), rollout, key.width, key.height)
            store.write(key, lambda tmp: tmp.write_bytes(data))
        with store.open(key) as f:
            return f.read()

    engine = make_engine(settings.db_url)
    try:
        with Session(engine) as db:
            try:
                return write_export(out, export_source(catalog, db, session_id, clip))
            except HTTPException as exc:
                raise (LookupError if exc.status_code == 404 else ValueError)(exc.detail) from None
    finally:
        engine.dispose()
