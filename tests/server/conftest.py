"""Apps on the toy pipeline: one per test, on SQLite and (when RBA_TEST_POSTGRES_URL is set) PostgreSQL."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text
from sqlmodel import SQLModel

from server.common.app_settings import Settings
from server.main import create_app

POSTGRES_URL = os.environ.get("RBA_TEST_POSTGRES_URL")


def _reset_postgres(url: str) -> None:
    """Drop the app's tables and the migrations' record, so every test starts from an empty database."""
    from server.db import admin_tables, study_tables, tables  # noqa: F401  (registers every table)

    engine = create_engine(url)
    SQLModel.metadata.drop_all(engine)
    with engine.begin() as conn:
        conn.execute(text("DROP TABLE IF EXISTS alembic_version"))
    engine.dispose()


@pytest.fixture(params=["sqlite", "postgres"])
def database_url(request, tmp_path) -> Iterator[str]:
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'rba.db'}"
        return
    if not POSTGRES_URL:
        pytest.skip("RBA_TEST_POSTGRES_URL is unset (CI sets it; locally: a postgresql+psycopg:// URL)")
    _reset_postgres(POSTGRES_URL)
    yield POSTGRES_URL
    _reset_postgres(POSTGRES_URL)


@pytest.fixture
def make_settings(toy_roots, tmp_path) -> Callable[..., Settings]:
    data, models, _ = toy_roots

    def make(**overrides) -> Settings:
        values = {"data_dir": data, "models_dir": models, "cache_dir": tmp_path / "clips", "warm_start": False,
                  "prerender_library": False,
                  "prerender": False, "database_url": f"sqlite:///{tmp_path / 'rba.db'}"}
        return Settings(**{**values, **overrides})

    return make


@pytest.fixture
def client(make_settings, database_url) -> Iterator[TestClient]:
    with TestClient(create_app(make_settings(database_url=database_url))) as c:
        yield c


@pytest.fixture
def session(client) -> dict:
    r = client.post("/api/sessions", json={"domain": "toy", "method": "global", "rep": "onehot"})
    assert r.status_code == 201, r.text
    return r.json()


def more(attribute: str, step: int, direction: str = "more", clip: str | None = None) -> dict:
    """A feedback body; with ``clip``, it names the clip it answers about (the page always does)."""
    body = {"step": step, "feedback": [{"attribute": attribute, "direction": direction}]}
    return body if clip is None else {**body, "clip": clip}


def make_engines_together(database_url: str, n: int) -> tuple[list, list[Exception]]:
    """``n`` replicas' ``make_engine`` started at once (each in a thread): their engines and errors."""
    from server.db.engine import make_engine

    engines, errors = [], []

    def start() -> None:
        try:
            engines.append(make_engine(database_url))
        except Exception as exc:
            errors.append(exc)

    threads = [threading.Thread(target=start) for _ in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    return engines, errors
