"""Minari datasets of the app's clips (``rba export --format minari --session ID`` / ``--labels``).

A session's dataset holds every clip it showed, in the order first shown (made clips simulated again from
their params and seed, as ``server.runtime.clip_sources`` remakes them), with its rounds in the metadata.
The labels' dataset holds every clip the admin page's labels of a domain refer to (train and serve
rollouts), in the order first referred to, and the labels in the metadata (``rba.labels``: the labels as
a ``LabelSet`` with clip ids; ``rba.pairs``: each (more, less) pair of episodes that orderings and
comparisons state, per attribute; ``rba.local_changes``: anchor and changed episodes). Uploaded datasets are
not among them: their trajectories are states alone, with no params and seed to re-simulate.
``rba.data.minari_export`` writes both.

Import direction: beside ``server.ops.session_export`` (whose ``app_database`` it opens); ``rba export`` imports it
by name.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from sqlmodel import Session

from rba.data.labels import LabelSet
from rba.data.library import SkillLibrary
from rba.data.minari_export import (
    DatasetSource,
    MinariExportError,
    Written,
    check_domain,
    rollout_clip,
    write_dataset,
)
from server.common.app_settings import Settings
from server.db.tables import TuningSession
from server.ops.session_export import app_database, feedback_rounds, rebuilt_since
from server.runtime.catalog import Catalog
from server.runtime.clip_sources import ClipSources, UnknownRollout
from server.runtime.stored_labels import page_labels


def _first_seen(ids: list[str]) -> list[str]:
    return list(dict.fromkeys(ids))


def session_source(catalog: Catalog, sources: ClipSources, db: Session, session_id: str) -> DatasetSource:
    """Every clip session ``session_id`` showed; ``LookupError`` for an unknown session, ``MinariExportError`` if
    its serve library was rebuilt since (its ids name other clips now)."""
    s = db.get(TuningSession, session_id)
    if s is None:
        raise LookupError(f"no session {session_id!r}")
    check_domain(s.domain)
    events, rounds = feedback_rounds(db, s)
    library = catalog.library(s.domain)
    if (stale := rebuilt_since(s, library.version)) is not None:
        raise MinariExportError(stale)
    ids = _first_seen([rid for e in events for rid in (e.rollout_before, e.rollout_after)] + [s.current_rollout_id])
    try:
        clips = [rollout_clip(rid, sources.resolve(db, s.domain, rid).rollout()) for rid in ids]
    except UnknownRollout as exc:
        raise MinariExportError(f"session {s.id}: {exc}") from None
    about = {"source": "session", "session": {
        "id": s.id, "method": s.method, "rep": s.rep, "status": s.status, "model_version": s.model_version,
        "library_version": library.version, "rounds": rounds}}
    return DatasetSource(s.domain, f"session-{s.id}", f"the clips session {s.id} showed ({s.domain}, {s.method}), "
                         "in the order first shown", clips, about)


def labels_source(catalog: Catalog, db: Session, domain: str) -> DatasetSource:
    """Every clip the admin page's labels of ``domain`` refer to, the labels in the metadata (module docstring)."""
    check_domain(domain)
    labels = page_labels(db, domain)
    if not labels.size():
        raise MinariExportError(f"{domain} has no labels made on the admin page; label clips at /admin first")
    ids = _first_seen([rid for _, _, clips in labels.located() for rid in clips])
    libraries = [catalog.library(domain), SkillLibrary.load(domain, "train", catalog.store.data_dir)]
    clips = []
    for rid in ids:
        library = next((lib for lib in libraries if rid in lib), None)
        if library is None:
            raise MinariExportError(f"label clip {rid!r} is no train or serve rollout id of {domain} now (was the "
                                    "library rebuilt?)")
        clips.append(rollout_clip(rid, library.rollout(library.index_of(rid))))
    return DatasetSource(domain, f"{domain}-labels", f"the clips the admin page's labels of {domain} refer to",
                         clips, {"source": "labels", **_label_metadata(labels, {rid: i for i, rid in enumerate(ids)})})


def _label_metadata(labels: LabelSet, episode: dict[str, int]) -> dict[str, Any]:
    attributes = sorted(labels.attributes_used())
    pairs = [{"attribute": a, "more": episode[hi], "less": episode[lo]} for a in attributes
             for hi, lo in labels.pairs(a)]
    changes = [{"attribute": c.attribute, "anchor": episode[c.anchor], "changed": episode[c.changed],
                "direction": c.direction} for c in labels.local_changes]
    return {"labels": labels.model_dump(exclude={"new_attributes"}), "pairs": pairs, "local_changes": changes}


def _write(out: Path, profile: Path | None, settings: Settings | None,
           make: Callable[[Settings, Catalog, Session], DatasetSource], on_episode: Callable[[int], None] | None
           ) -> Written:
    settings = settings or Settings()
    catalog = Catalog(settings)
    with app_database(settings) as (db, where):
        try:
            source = make(settings, catalog, db)
        except LookupError as exc:
            raise LookupError(f"{exc.args[0]} (database {where})") from None
    return write_dataset(out, source, profile, on_episode)


def session_to_dataset(session_id: str, out: Path, profile: Path | None = None, settings: Settings | None = None,
                       on_episode: Callable[[int], None] | None = None) -> Written:
    """``rba export --format minari --session ID``: the app's database and files (the server's settings)."""
    def make(settings: Settings, catalog: Catalog, db: Session) -> DatasetSource:
        sources = ClipSources(catalog, settings.clip_width, settings.clip_height)  # made clips: simulated here
        return session_source(catalog, sources, db, session_id)

    return _write(out, profile, settings, make, on_episode)


def labels_to_dataset(domain: str, out: Path, profile: Path | None = None, settings: Settings | None = None,
                      on_episode: Callable[[int], None] | None = None) -> Written:
    """``rba export --format minari --labels --domain D``."""
    return _write(out, profile, settings, lambda _settings, catalog, db: labels_source(catalog, db, domain),
                  on_episode)
