"""Schema migrations: an empty database and every database made before migrations reach the models' schema, rows kept.

Each test runs on SQLite and on PostgreSQL (``database_url``). "The old way" is what start-up did before
migrations: ``create_all`` of the tables of the time, then hand-written ALTERs.
"""

from __future__ import annotations

import datetime as dt
import sqlite3
import threading
import time
from typing import Any

import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from alembic.script import ScriptDirectory
from fastapi.testclient import TestClient
from sqlalchemy import (
    JSON,
    Column,
    DateTime,
    Engine,
    ForeignKey,
    Integer,
    MetaData,
    String,
    Table,
    UniqueConstraint,
    create_engine,
    inspect,
    text,
)
from sqlmodel import Session, SQLModel, select

from server.db import migrations
from server.db.admin_tables import TrainJob
from server.db.engine import make_engine
from server.db.migrations.__main__ import main as migrations_cli
from server.db.tables import FeedbackEvent, TuningSession, as_utc
from server.main import create_app
from tests.server.conftest import make_engines_together, more

HEAD = ScriptDirectory.from_config(migrations.config()).get_current_head()
TOKEN = "migrati0n-test-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
NOW = dt.datetime(2026, 11, 23, 4, 0, tzinfo=dt.UTC)
JOB = {"id": "j-old", "domain": "toy", "method": "global", "rep": "onehot", "preset": "quick", "datasets": [],
       "state": "succeeded", "stage": "done", "step": 10, "total": 10, "log_tail": "ok", "version": "toy-v1",
       "owner": "a#1", "created_at": NOW, "updated_at": NOW}

# The first release's tables (server/db/tables.py at the web app's first commit), before any start-up ALTER.
FIRST_RELEASE = MetaData()
Table("rba_session", FIRST_RELEASE, Column("domain", String(64), nullable=False),
      Column("method", String(32), nullable=False), Column("rep", String(32), nullable=False),
      Column("id", String(32), primary_key=True), Column("model_version", String(128), nullable=False),
      Column("status", String(16), nullable=False, index=True), Column("step", Integer, nullable=False),
      Column("current_rollout_id", String(128), nullable=False), Column("agent_state", JSON, nullable=False),
      Column("created_at", DateTime(timezone=True), nullable=False),
      Column("updated_at", DateTime(timezone=True), nullable=False))
Table("rba_feedback", FIRST_RELEASE, Column("id", Integer, primary_key=True),
      Column("session_id", String(32), ForeignKey("rba_session.id"), nullable=False, index=True),
      Column("step", Integer, nullable=False), Column("feedback", JSON, nullable=False),
      Column("rollout_before", String(128), nullable=False), Column("rollout_after", String(128), nullable=False),
      Column("created_at", DateTime(timezone=True), nullable=False),
      UniqueConstraint("session_id", "step", name="uq_feedback_session_step"))


def _pre_migrations() -> MetaData:
    """The tables of the last release without migrations (revision 0004): today's models, less what later
    revisions added (0005: ``rba_generated_clip`` and ``rba_session.generate``; 0006:
    ``rba_session.library_version``; 0007: ``rba_train_job.stages``; 0008: the ``rba_study*`` tables)."""
    later = {"rba_session": ("generate", "library_version"), "rba_train_job": ("stages",)}
    old = MetaData()
    for table in SQLModel.metadata.tables.values():
        if table.name in later:
            Table(table.name, old, *(c._copy() for c in table.columns if c.name not in later[table.name]))
        elif table.name != "rba_generated_clip" and not table.name.startswith("rba_study"):
            table.to_metadata(old)
    return old


PRE_MIGRATIONS = _pre_migrations()


def differences(engine: Engine) -> list[Any]:
    """What autogenerate would put in a new migration: empty when the database is the models' schema."""
    with engine.connect() as conn:
        return compare_metadata(MigrationContext.configure(conn), SQLModel.metadata)


def revision(engine: Engine) -> str | None:
    with engine.connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()


def _utc(row: dict[str, Any]) -> dict[str, Any]:
    """SQLite returns naive datetimes (they are UTC): make them aware before they go to another database."""
    return {k: as_utc(v) if isinstance(v, dt.datetime) else v for k, v in row.items()}


@pytest.fixture
def answered(make_settings, tmp_path) -> tuple[dict, dict, list[dict]]:
    """A session the app made and answered once (on its own SQLite file): its API view and its rows."""
    with TestClient(create_app(make_settings(database_url=f"sqlite:///{tmp_path / 'source.db'}"))) as app:
        s = app.post("/api/sessions", json={"domain": "toy"}).json()
        s = app.post(f"/api/sessions/{s['id']}/feedback", json=more("pace", 0)).json()
        with Session(app.app.state.services.engine) as db:
            row = _utc(db.get(TuningSession, s["id"]).model_dump())
            events = [_utc(e.model_dump(exclude={"id"})) for e in db.exec(select(FeedbackEvent))]
    assert s["step"] == 1 and len(events) == 1
    return s, row, events


def _continue(app: TestClient, s: dict) -> None:
    """The migrated rows still work: the session reads back as it was and takes the next answer."""
    again = app.get(f"/api/sessions/{s['id']}")
    assert again.status_code == 200, again.text
    assert again.json() == s
    r = app.post(f"/api/sessions/{s['id']}/feedback", json=more("amplitude", 1))
    assert r.status_code == 200, r.text
    assert r.json()["step"] == 2 and len(r.json()["history"]) == 2


def test_an_empty_database_gets_exactly_the_models_tables(database_url):
    """Fails when a table in server/db/tables.py or server/db/admin_tables.py changed without a migration."""
    engine = make_engine(database_url)
    assert revision(engine) == HEAD
    assert differences(engine) == [], "a table changed without a migration: python -m server.db.migrations revision -m"
    engine.dispose()
    assert migrations_cli(["check"]) == 0


def test_a_table_changed_without_a_migration_is_seen(database_url):
    """The check above is not vacuous: one column more in the models is a difference naming it."""
    engine = make_engine(database_url)
    changed = MetaData()
    for table in SQLModel.metadata.tables.values():
        table.to_metadata(changed)
    changed.tables["rba_session"].append_column(Column("note", String(20)))
    with engine.connect() as conn:
        found = compare_metadata(MigrationContext.configure(conn), changed)
    engine.dispose()
    assert [(d[0], d[2], d[3].name) for d in found] == [("add_column", "rba_session", "note")]


def test_a_database_from_the_current_code_is_adopted_with_its_rows(make_settings, database_url, answered):
    s, row, events = answered
    old = create_engine(database_url)
    PRE_MIGRATIONS.create_all(old)  # the schema the code before migrations made
    session = PRE_MIGRATIONS.tables["rba_session"]
    with old.begin() as conn:  # the session row first: the feedback's foreign key names it
        conn.execute(session.insert(), [{k: v for k, v in row.items() if k in session.c}])
        conn.execute(PRE_MIGRATIONS.tables["rba_feedback"].insert(), events)
        conn.execute(PRE_MIGRATIONS.tables["rba_train_job"].insert(), [JOB])
    old.dispose()
    with TestClient(create_app(make_settings(database_url=database_url, admin_token=TOKEN))) as app:
        jobs = app.get("/api/admin/jobs", headers=AUTH)
        assert jobs.status_code == 200, jobs.text
        assert [(j["id"], j["state"], j["version"]) for j in jobs.json()] == [("j-old", "succeeded", "toy-v1")]
        _continue(app, s)
        engine = app.app.state.services.engine
        assert revision(engine) == HEAD and differences(engine) == []
        with Session(engine) as db:
            assert db.get(TrainJob, "j-old").owner == "a#1"


def test_a_first_release_database_upgrades_with_its_rows(make_settings, database_url, answered):
    s, row, events = answered
    old = create_engine(database_url)
    FIRST_RELEASE.create_all(old)
    with old.begin() as conn:
        conn.execute(FIRST_RELEASE.tables["rba_session"].insert(), [{k: v for k, v in row.items() if k != "model_set"}])
        conn.execute(FIRST_RELEASE.tables["rba_feedback"].insert(), events)
    old.dispose()
    with TestClient(create_app(make_settings(database_url=database_url, admin_token=TOKEN))) as app:
        _continue(app, s)  # model_set is "builtin", as it was for every session of that release
        jobs = app.get("/api/admin/jobs", headers=AUTH)
        assert jobs.status_code == 200 and jobs.json() == []
        engine = app.app.state.services.engine
        assert revision(engine) == HEAD and differences(engine) == []


def test_an_oldest_database_run_by_later_code_gets_the_column_it_missed(database_url):
    """Made before jobs had ``include_page_labels`` (create_all never adds a column), then given the owner columns."""
    old = create_engine(database_url)
    PRE_MIGRATIONS.create_all(old)
    with old.begin() as conn:
        conn.execute(text("ALTER TABLE rba_train_job DROP COLUMN include_page_labels"))
    with old.begin() as conn:  # the table as it is, without the column
        conn.execute(Table("rba_train_job", MetaData(), autoload_with=conn).insert(), [JOB])
    old.dispose()
    engine = make_engine(database_url)
    with engine.connect() as conn:
        assert conn.execute(text("SELECT include_page_labels, owner FROM rba_train_job")).one() == (False, "a#1")
    assert revision(engine) == HEAD and differences(engine) == []
    engine.dispose()


def test_tables_no_release_made_are_refused_and_left_as_they_were(database_url):
    old = create_engine(database_url)
    with old.begin() as conn:
        conn.execute(text("CREATE TABLE rba_train_job (id VARCHAR(32) PRIMARY KEY, domain VARCHAR(64) NOT NULL)"))
    with pytest.raises(RuntimeError, match=r"the database has RBA Studio tables \(rba_train_job\) but no "
                                           r"alembic_version, and lacks columns every release had: "
                                           r"rba_feedback\.created_at, .*rba_session\.updated_at\. Restore it"):
        make_engine(database_url)
    assert inspect(old).get_table_names() == ["rba_train_job"]
    old.dispose()


def test_migrations_undo_and_redo(database_url):
    engine = make_engine(database_url)
    with engine.begin() as conn:
        command.downgrade(migrations.config(conn), "base")
        assert migrations.shape(conn) == {}
    with engine.begin() as conn:
        migrations.upgrade(conn)
    assert revision(engine) == HEAD and differences(engine) == []
    engine.dispose()


def test_replicas_adopting_one_old_database_together_all_start(database_url):
    old = create_engine(database_url)
    PRE_MIGRATIONS.create_all(old)
    old.dispose()
    engines, errors = make_engines_together(database_url, 3)
    assert errors == [] and len(engines) == 3
    with engines[0].connect() as conn:
        assert conn.execute(text("SELECT version_num FROM alembic_version")).all() == [(HEAD,)]
    for engine in engines:
        engine.dispose()


def test_a_replica_waits_for_another_holding_an_old_sqlite_database(tmp_path):
    """SQLite refuses the switch to WAL at once while another connection holds a lock: the start waits instead."""
    path = tmp_path / "rba.db"
    holder = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
    holder.execute("CREATE TABLE other (i INTEGER)")  # a rollback-journal database, as before any replica
    holder.execute("BEGIN IMMEDIATE")
    threading.Timer(0.5, holder.execute, ("COMMIT",)).start()
    started = time.monotonic()
    engine = make_engine(f"sqlite:///{path}")
    assert time.monotonic() - started >= 0.4  # it waited for the holder rather than failing
    assert revision(engine) == HEAD  # migrated beside the holder's own table
    with engine.connect() as conn:
        assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
    engine.dispose()
    holder.close()
