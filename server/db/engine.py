"""The SQL engine: SQLite (default, WAL, usable from many threads) or PostgreSQL via psycopg 3.

Sits low: it imports only ``server.db.migrations`` (the schema's history) and ``server.common.errors``.
"""

from __future__ import annotations

import logging
import sqlite3
import time
from collections.abc import Callable
from pathlib import Path

from sqlalchemy import event, text
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.engine import Engine, make_url
from sqlalchemy.exc import IntegrityError
from sqlalchemy.sql.dml import Insert
from sqlmodel import Session, SQLModel, create_engine

from server.common.errors import conflict
from server.db import migrations

log = logging.getLogger(__name__)


def make_engine(url: str) -> Engine:
    """Create the engine and migrate the schema to the newest revision, so any database works at once."""
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite":
        if parsed.database and parsed.database != ":memory:":
            Path(parsed.database).parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": SQLITE_WAIT_SECONDS})

        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_conn, _record) -> None:  # WAL: readers never wait for the writer
            cur = dbapi_conn.cursor()
            _journal_wal(cur)
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.close()
    else:
        engine = create_engine(url, pool_pre_ping=True, pool_size=10, max_overflow=20)
    try:
        _migrate(engine)
    except Exception:
        engine.dispose()  # a refused database keeps no pooled connections open
        raise
    log.info("database ready: %s", parsed.render_as_string(hide_password=True))
    return engine


SQLITE_WAIT_SECONDS = 30.0  # how long a SQLite connection waits for another's lock before "database is locked"


def _journal_wal(cur, wait: float = SQLITE_WAIT_SECONDS) -> None:
    """Switch the database to WAL, waiting out other connections' locks.

    Leaving rollback-journal mode needs the database to itself, and SQLite answers "database is locked" at
    once, without its busy handler, while another connection holds a lock: replicas that start together on
    an old (rollback-journal) database would fail at random. So retry until ``wait`` runs out.
    """
    deadline = time.monotonic() + wait
    while True:
        try:
            cur.execute("PRAGMA journal_mode=WAL")
            return
        except sqlite3.OperationalError as exc:
            if "locked" not in str(exc) or time.monotonic() > deadline:
                raise
            time.sleep(0.05)


SCHEMA_LOCK = 0x5_2BA_5C4E  # PostgreSQL advisory lock key: one replica at a time migrates the schema


def _migrate(engine: Engine) -> None:
    """Upgrade the schema to the newest migration, in one transaction that holds a database-wide lock.

    API replicas start together on one database: without the lock, two upgrades race and one fails
    (PostgreSQL: a duplicate key in pg_type); with it, the later ones find the schema at head. PostgreSQL
    takes an advisory lock; SQLite a write lock (``BEGIN IMMEDIATE``), which its DDL otherwise runs without.
    """
    with engine.begin() as conn:
        if engine.dialect.name == "postgresql":
            conn.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": SCHEMA_LOCK})
        elif engine.dialect.name == "sqlite":
            conn.exec_driver_sql("BEGIN IMMEDIATE")
        migrations.upgrade(conn)


def commit_or_conflict(db: Session, detail: str | Callable[[], str]) -> None:
    """Commit; if a unique constraint says another request got there first, roll back and answer 409 ``detail``.

    ``detail`` may be a function, called after the rollback, to name what won (it may query ``db``).
    """
    try:
        db.commit()
    except IntegrityError as exc:
        db.rollback()
        raise conflict(detail() if callable(detail) else detail) from exc


def dialect_insert(db: Session, table: type[SQLModel]) -> Insert:
    """An INSERT in ``db``'s own dialect, whose ``on_conflict_do_*`` makes an insert-or-update one statement: no
    read-then-write that two requests can interleave (SQLite and PostgreSQL spell it alike)."""
    dialect = postgresql if db.get_bind().dialect.name == "postgresql" else sqlite
    return dialect.insert(table)
