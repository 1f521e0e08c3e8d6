"""Alembic's environment: migrates the connection ``server.db.migrations.config`` hands over.

The target is the SQLModel tables, so autogenerate compares them with the database. Only the app's
tables (``rba_*``) are considered, so a shared PostgreSQL database's other tables are left alone.
"""

from __future__ import annotations

from typing import Any

from alembic import context
from sqlalchemy.engine import Connection
from sqlmodel import SQLModel
from sqlmodel.sql.sqltypes import AutoString

from server.db import admin_tables, study_tables, tables  # noqa: F401  (registers the tables on SQLModel.metadata)
from server.db.migrations import TABLE_PREFIX


def include_name(name: str | None, type_: str, _parents: dict[str, Any]) -> bool:
    return type_ != "table" or bool(name and name.startswith(TABLE_PREFIX))


def render_item(type_: str, obj: Any, _context: Any) -> str | bool:
    """SQLModel's AutoString is written as sa.String, so a script imports nothing but sqlalchemy."""
    if type_ == "type" and isinstance(obj, AutoString):
        return f"sa.String(length={obj.length})" if obj.length else "sa.String()"
    return False


def run(connection: Connection) -> None:
    """Run in the caller's transaction (Alembic opens none of its own when one is in progress)."""
    context.configure(connection=connection, target_metadata=SQLModel.metadata, include_name=include_name,
                      render_item=render_item, render_as_batch=True)  # batch: SQLite can only rebuild tables
    with context.begin_transaction():
        context.run_migrations()


if context.is_offline_mode():
    raise RuntimeError("offline (SQL script) mode is not supported: migrations run on a live connection")
run(context.config.attributes["connection"])
