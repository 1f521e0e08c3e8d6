"""The SQL engine: SQLite (default, WAL, usable from many threads) or PostgreSQL via psycopg 3.

Sits low: it imports only the tables and ``server.errors``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from sqlalchemy import event, inspect, text
from sqlalchemy.engine import Connection, Engine, make_url
from sqlalchemy.exc import IntegrityError
from sqlmodel import Session, SQLModel, create_engine

from server import admin_models, models  # noqa: F401  (registers the tables on SQLModel.metadata)
from server.errors import conflict

log = logging.getLogger(__name__)


def make_engine(url: str) -> Engine:
    """Create the engine and the schema (idempotent), so a fresh database works at once."""
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite":
        if parsed.database and parsed.database != ":memory:":
            Path(parsed.database).parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30})

        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_conn, _record) -> None:  # WAL: readers never wait for the writer
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.close()
    else:
        engine = create_engine(url, pool_pre_ping=True, pool_size=10, max_overflow=20)
    _create_schema(engine)
    log.info("database ready: %s", parsed.render_as_string(hide_password=True))
    return engine


# Columns added after a table first shipped: (table, column, DDL type + default). create_all makes
# missing tables only, so databases from older versions get these added in place at start-up.
ADDED_COLUMNS = [("rba_session", "model_set", "VARCHAR(64) NOT NULL DEFAULT 'builtin'"),
                 ("rba_train_job", "owner", "VARCHAR(160)"),
                 ("rba_train_job", "heartbeat_at", "TIMESTAMP WITH TIME ZONE")]


SCHEMA_LOCK = 0x5_2BA_5C4E  # PostgreSQL advisory lock key: one replica at a time creates or alters tables


def _create_schema(engine: Engine) -> None:
    """Missing tables and columns, in one transaction that holds a database-wide lock.

    API replicas start together on one fresh database: without the lock, two ``create_all`` race and
    one fails (PostgreSQL: a duplicate key in pg_type). PostgreSQL takes an advisory lock; SQLite a
    write lock (``BEGIN IMMEDIATE``), which its DDL otherwise runs without.
    """
    with engine.begin() as conn:
        if engine.dialect.name == "postgresql":
            conn.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": SCHEMA_LOCK})
        elif engine.dialect.name == "sqlite":
            conn.exec_driver_sql("BEGIN IMMEDIATE")
        SQLModel.metadata.create_all(conn)
        _add_columns(conn)


def _add_columns(conn: Connection) -> None:
    for table, column, ddl in ADDED_COLUMNS:
        if column not in {c["name"] for c in inspect(conn).get_columns(table)}:
            conn.execute(text(f"ALTER TABLE {table} ADD COLUMN {column} {ddl}"))
            log.info("database: added %s.%s", table, column)


def commit_or_conflict(db: Session, detail: str | Callable[[], str]) -> None:
    """Commit; if a unique constraint says another request got there first, roll back and answer 409 ``detail``.

    ``detail`` may be a function, called after the rollback, to name what won (it may query ``db``).
    """
    try:
        db.commit()
    except IntegrityError as exc:
        db.rollback()
        raise conflict(detail() if callable(detail) else detail) from exc
