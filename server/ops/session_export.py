"""Export a satisfied session (``GET /api/sessions/{id}/export`` and ``rba export``): ``rba.data.export_zip``'s zip.

The operation reads the session and its feedback rows, the serve library and the session's model set,
and the chosen clip's MP4: the app asks its clip cache (rendered on the compute layer if missing); the
command line, which starts no app, renders in its own process into the same clip store.

Import direction: beside ``server.ops.session_steps`` (above ``server.runtime.services``); the route and ``rba export``
(by name, as ``rba serve`` imports the app) use it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from sqlalchemy.engine import make_url
from sqlmodel import Session, select

from rba.data.export_zip import ExportError, ExportSource, Profile, build_export, export_bytes, write_export
from rba.media.clip_cache import render_job
from server.common.app_settings import Settings
from server.common.errors import conflict, not_found
from server.db.tables import FeedbackEvent, SessionStatus, TuningSession
from server.runtime.catalog import Catalog
from server.runtime.clip_sources import ClipSources, ResolvedClip, UnknownRollout
from server.runtime.services import Services

log = logging.getLogger(__name__)

CLIP_WAIT_SECONDS = 120.0  # an export waits this long at most for its clip to render

ClipBytes = Callable[[ResolvedClip], bytes]  # the chosen clip -> its MP4


def feedback_rounds(db: Session, s: TuningSession) -> tuple[list[FeedbackEvent], list[dict]]:
    """The session's feedback events in step order, and each as the JSON an export keeps."""
    events = list(db.exec(select(FeedbackEvent).where(FeedbackEvent.session_id == s.id)
                          .order_by(FeedbackEvent.step)).all())
    return events, [{"step": e.step, "feedback": e.feedback, "rollout_before": e.rollout_before,
                     "rollout_after": e.rollout_after} for e in events]


def rebuilt_since(s: TuningSession, library_version: str) -> str | None:
    """Why the session's clip ids no longer name the clips it showed (its serve library was rebuilt), or None."""
    if s.library_version is None or s.library_version == library_version:
        return None
    return (f"session {s.id} showed clips of {s.domain}'s serve library {s.library_version}; it is "
            f"{library_version} now (rebuilt), so its clip ids name other behaviours")


def export_source(catalog: Catalog, sources: ClipSources, db: Session, session_id: str,
                  clip: ClipBytes) -> ExportSource:
    """What the export of ``session_id`` is made of; 404 for an unknown session, 409 unless it ended satisfied.

    The chosen rollout comes from ``sources`` (a made one remade from its params and seed): the export holds its
    own params, seed and states."""
    s = db.get(TuningSession, session_id)
    if s is None:
        raise not_found(f"no session {session_id!r}; create one with POST /api/sessions")
    if s.status != SessionStatus.satisfied:
        raise conflict(f"session {s.id} is {s.status}: only a session that ended satisfied (\"This is it\") can "
                       "be exported")
    _, rounds = feedback_rounds(db, s)
    library, rid = catalog.library(s.domain), s.current_rollout_id
    if (stale := rebuilt_since(s, library.version)) is not None:
        raise conflict(f"{stale}: it cannot be exported")
    try:
        chosen = sources.resolve(db, s.domain, rid)
    except UnknownRollout as exc:
        raise not_found(str(exc)) from exc
    return ExportSource(domain=s.domain, method=s.method, rep=s.rep, model_version=s.model_version,
                        model_set=s.model_set, models_root=catalog.models(s.model_set).root, library=library,
                        rollout_id=rid, feedback=rounds, clip=clip(chosen), rollout=chosen.rollout())


def export_session(svc: Services, db: Session, session_id: str) -> tuple[Profile, bytes]:
    """The profile and zip bytes of a satisfied session; its clip comes from the app's clip cache."""
    def clip(chosen: ResolvedClip) -> bytes:
        path = svc.clips.request(chosen.key, chosen.source(), urgent=True).result(CLIP_WAIT_SECONDS)
        return Path(path).read_bytes()

    src = export_source(svc.catalog, svc.sources, db, session_id, clip)
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

    settings = settings or Settings()
    catalog = Catalog(settings)
    store = catalog.store.clips()
    sources = ClipSources(catalog, settings.clip_width, settings.clip_height)  # simulates in this process

    def clip(chosen: ResolvedClip) -> bytes:
        if not store.exists(chosen.key):  # the bytes the app would cache under this key
            data = render_here(render_job(chosen.key, chosen.source()))
            store.write(chosen.key, lambda tmp: tmp.write_bytes(data))
        with store.open(chosen.key) as f:
            return f.read()

    with app_database(settings) as (db, where):
        try:
            return write_export(out, export_source(catalog, sources, db, session_id, clip))
        except HTTPException as exc:
            if exc.status_code == 404:
                raise LookupError(f"{exc.detail} (database {where})") from None
            raise ValueError(exc.detail) from None


@contextmanager
def app_database(settings: Settings) -> Iterator[tuple[Session, str]]:
    """The app's database for a command (``rba export``): a session on it and where it is (password hidden).

    A SQLite database not made yet is a ``LookupError``: it is not created empty."""
    from server.db.engine import make_engine

    url = make_url(settings.db_url)
    if url.get_backend_name() == "sqlite" and not Path(url.database or "").is_file():  # not make an empty one
        raise LookupError(f"no database at {url.database}: the app has not run with these settings "
                          "(RBA_DATABASE_URL, RBA_DATA_DIR), so it has nothing to export")
    engine = make_engine(settings.db_url)
    try:
        with Session(engine) as db:
            yield db, url.render_as_string(hide_password=True)
    finally:
        engine.dispose()
