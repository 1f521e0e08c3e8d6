"""Export a satisfied session (``GET /api/sessions/{id}/export`` and ``rba export``): ``rba.data.export_zip``'s zip.

The operation reads the session and its feedback rows, the serve library and the session's model set,
and the chosen clip's MP4: the app asks its clip cache (rendered on the compute layer if missing); the
command line, which starts no app, renders in its own process into the same clip store.

Import direction: beside ``server.ops.session_steps`` (above ``server.runtime.services``); the route and ``rba export``
(by name, as ``rba serve`` imports the app) use it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from sqlalchemy.engine import make_url
from sqlmodel import Session, select

from rba.data.export_zip import ExportError, ExportSource, Profile, build_export, export_bytes, write_export
from rba.domains import Rollout
from rba.generate.cma import is_generated
from rba.media.clip_cache import GENERATED, ClipKey, Source, render_job
from server.common.app_settings import Settings
from server.common.errors import conflict, not_found
from server.db.tables import FeedbackEvent, GeneratedClip, SessionStatus, TuningSession
from server.ops import session_searches
from server.runtime.catalog import Catalog
from server.runtime.services import Services

log = logging.getLogger(__name__)

CLIP_WAIT_SECONDS = 120.0  # an export waits this long at most for its clip to render

ClipBytes = Callable[[Source, str], bytes]  # (serve library or generated rollout, rollout id) -> the clip's MP4
Remake = Callable[[GeneratedClip], Rollout]  # a generated rollout from its row (params and seed)


def export_source(catalog: Catalog, db: Session, session_id: str, clip: ClipBytes, remake: Remake) -> ExportSource:
    """What the export of ``session_id`` is made of; 404 for an unknown session, 409 unless it ended satisfied.

    A generated chosen rollout is remade from its row: the export holds its own params, seed and states."""
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
    library, rid = catalog.library(s.domain), s.current_rollout_id
    if s.library_version is not None and s.library_version != library.version:
        raise conflict(f"session {s.id} showed clips of {s.domain}'s serve library {s.library_version}; it is "
                       f"{library.version} now (rebuilt), so its clip ids name other behaviours: it cannot be exported")
    chosen = remake(session_searches.lookup(db, s.domain, rid)) if is_generated(rid) else None
    return ExportSource(domain=s.domain, method=s.method, rep=s.rep, model_version=s.model_version,
                        model_set=s.model_set, models_root=catalog.models(s.model_set).root, library=library,
                        rollout_id=rid, feedback=rounds, clip=clip(chosen or library, rid), rollout=chosen)


def export_session(svc: Services, db: Session, session_id: str) -> tuple[Profile, bytes]:
    """The profile and zip bytes of a satisfied session; its clip comes from the app's clip cache."""
    def clip(source: Source, rollout_id: str) -> bytes:
        key = (svc.clips.generated_key(source.domain, rollout_id) if isinstance(source, Rollout)
               else svc.clips.key(source, rollout_id))
        path = svc.clips.request(key, source, urgent=True).result(CLIP_WAIT_SECONDS)
        return Path(path).read_bytes()

    src = export_source(svc.catalog, db, session_id, clip, lambda row: session_searches.rollout_of(svc, row))
    try:
        profile, reward = build_export(src)
    except ExportError as exc:
        raise conflict(str(exc)) from exc
    log.info("session %s exported: %s %s seed %d", session_id, src.domain, src.rollout_id, profile.seed)
    return profile, export_bytes(profile, reward, src.clip)


def export_to_file(session_id: str, out: Path, settings: Settings | None = None) -> Profile:
    """``rba export``: the app's database and files (the server's settings), the zip written atomically to ``out``.

    Raises ``LookupError`` for an unknown session (naming the database) or a SQLite database not made yet (it is
    not created empty), and ``ValueError`` for a session that cannot be exported.
    """
    from fastapi import HTTPException

    from rba.compute.tasks import render_here
    from server.db.engine import make_engine

    settings = settings or Settings()
    catalog = Catalog(settings)
    store = catalog.store.clips()

    def clip(source: Source, rollout_id: str) -> bytes:
        version = GENERATED if isinstance(source, Rollout) else source.version
        key = ClipKey(source.domain, version, rollout_id, settings.clip_width, settings.clip_height)
        if not store.exists(key):  # the bytes the app would cache under this key
            data = render_here(render_job(key, source))
            store.write(key, lambda tmp: tmp.write_bytes(data))
        with store.open(key) as f:
            return f.read()

    def remake(row: GeneratedClip) -> Rollout:  # simulated in this process, as the clip is rendered here
        return catalog.generated_store(row.domain).rollout(row.domain, row.id, row.params, row.seed)

    url = make_url(settings.db_url)
    where = url.render_as_string(hide_password=True)
    if url.get_backend_name() == "sqlite" and not Path(url.database or "").is_file():  # not make an empty one
        raise LookupError(f"no database at {url.database}: the app has not run with these settings "
                          "(RBA_DATABASE_URL, RBA_DATA_DIR), so it has no session to export")
    engine = make_engine(settings.db_url)
    try:
        with Session(engine) as db:
            try:
                return write_export(out, export_source(catalog, db, session_id, clip, remake))
            except HTTPException as exc:
                if exc.status_code == 404:
                    raise LookupError(f"{exc.detail} (database {where})") from None
                raise ValueError(exc.detail) from None
    finally:
        engine.dispose()
