"""Schema migrations (Alembic): ``versions/`` holds one script per schema change, oldest first.

``server.db.engine`` runs :func:`upgrade` at start-up under its schema lock. Alembic is configured here in code,
from this package's folder (never the working directory; no alembic.ini). A database made before
migrations existed has the tables but no ``alembic_version``: it is recognised by its columns and
stamped with the revision it matches, then upgraded. How to add a migration: docs/architecture.md §6.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path

from alembic import command, op
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Column, create_engine, inspect
from sqlalchemy.engine import Connection

log = logging.getLogger(__name__)

HERE = Path(__file__).resolve().parent
TABLE_PREFIX = "rba_"  # the app's tables; anything else in the database is not ours to migrate
LAST_PRE_ALEMBIC = "0004"  # the newest schema a release without migrations made (start-up create_all + ALTERs)

Shape = dict[str, frozenset[str]]  # table -> column names

# Alembic's ``context`` is one module-level proxy: two runs at once in one process would share it.
_RUN = threading.Lock()


def config(connection: Connection | None = None) -> Config:
    """Alembic's configuration for this package; ``connection`` is what ``env.py`` migrates."""
    cfg = Config()
    cfg.set_main_option("script_location", str(HERE))
    cfg.set_main_option("file_template", "%%(rev)s_%%(slug)s")
    cfg.attributes["connection"] = connection
    return cfg


def upgrade(conn: Connection) -> None:
    """Bring the database on ``conn`` to the newest revision, inside the caller's transaction (and lock)."""
    with _RUN:
        cfg = config(conn)
        if MigrationContext.configure(conn).get_current_revision() is None:
            found = shape(conn)
            if found:
                revision = adopt(found)
                command.stamp(cfg, revision)
                log.info("database: tables from before migrations recognised as revision %s", revision)
        command.upgrade(cfg, "head")


def shape(conn: Connection) -> Shape:
    """The app's tables on ``conn`` and their column names."""
    inspector = inspect(conn)
    return {table: frozenset(c["name"] for c in inspector.get_columns(table))
            for table in inspector.get_table_names() if table.startswith(TABLE_PREFIX)}


def pre_alembic_shapes() -> dict[str, Shape]:
    """Each revision up to ``LAST_PRE_ALEMBIC`` and the tables it makes, oldest first.

    Worked out by running the migrations on a scratch in-memory SQLite database, so the scripts are the
    one description of every old schema.
    """
    cfg = config()
    order = [s.revision for s in ScriptDirectory.from_config(cfg).walk_revisions("base", LAST_PRE_ALEMBIC)]
    engine = create_engine("sqlite://")
    shapes: dict[str, Shape] = {}
    with engine.begin() as scratch:
        cfg.attributes["connection"] = scratch
        for revision in reversed(order):
            command.upgrade(cfg, revision)
            shapes[revision] = shape(scratch)
    engine.dispose()
    return shapes


def adopt(found: Shape) -> str:
    """The newest pre-migration revision whose every table and column ``found`` has.

    Old start-ups added columns one by one and never to a table that existed, so a database may hold some
    columns of a later revision too: the pre-migration scripts add only what is missing. A database holding
    not even the first revision's columns is refused, naming what it lacks.
    """
    shapes = pre_alembic_shapes()
    have = _columns(found)
    held = [revision for revision, tables in shapes.items() if _columns(tables) <= have]
    if not held:
        first = next(iter(shapes))
        missing = ", ".join(sorted(_columns(shapes[first]) - have))
        raise RuntimeError(f"the database has RBA Studio tables ({', '.join(sorted(found))}) but no alembic_version, "
                           f"and lacks columns every release had: {missing}. Restore it from a backup or point "
                           "RBA_DATABASE_URL at an empty database.")
    unknown = have - _columns(shapes[LAST_PRE_ALEMBIC])
    if unknown:
        log.warning("database: columns no release made, left as they are: %s", ", ".join(sorted(unknown)))
    return held[-1]


def _columns(tables: Shape) -> set[str]:
    return {f"{table}.{column}" for table, columns in tables.items() for column in columns}


def add_missing_columns(table: str, *columns: Column) -> None:
    """Add each of ``columns`` to ``table`` unless it is there: for the pre-migration scripts only (see ``adopt``)."""
    present = {c["name"] for c in inspect(op.get_bind()).get_columns(table)}
    for column in columns:
        if column.name not in present:
            op.add_column(table, column)
