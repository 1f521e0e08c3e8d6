"""Two API replicas (two apps, each with its own Services) on one database, racing on one session.

``session_locks`` only serialise the requests of one process; across replicas the database decides:
the (session, step) feedback row is unique and the session row moves by compare-and-set. A barrier
holds each request just before it writes, so the two really do race.
"""

from __future__ import annotations

import shutil
import threading
from concurrent.futures import ThreadPoolExecutor

import pytest
from fastapi.testclient import TestClient
from sqlmodel import Session, select

from server.db.admin_tables import ModelVersion
from server.db.tables import FeedbackEvent, TuningSession
from server.main import create_app
from server.ops import session_steps
from tests.server.conftest import make_engines_together, more

REPLICA_TOKEN = "replica-test-t0ken"


@pytest.fixture
def two_replicas(make_settings, database_url):
    with (TestClient(create_app(make_settings(database_url=database_url, replica="a"))) as a,
          TestClient(create_app(make_settings(database_url=database_url, replica="b"))) as b):
        yield a, b


def hold_before_writing(monkeypatch, parties: int = 2) -> threading.Barrier:
    """Make every session write wait until ``parties`` requests are about to write."""
    barrier = threading.Barrier(parties, timeout=30)
    move = session_steps._move

    def held(*args, **kwargs):
        barrier.wait()
        return move(*args, **kwargs)

    monkeypatch.setattr(session_steps, "_move", held)
    return barrier


def race(*calls):
    with ThreadPoolExecutor(len(calls)) as pool:
        return [f.result() for f in [pool.submit(c) for c in calls]]


def stored(client: TestClient, session_id: str) -> tuple[TuningSession, list[FeedbackEvent]]:
    with Session(client.app.state.services.engine) as db:
        events = db.exec(select(FeedbackEvent).where(FeedbackEvent.session_id == session_id)).all()
        return db.get(TuningSession, session_id), list(events)


def test_two_replicas_answering_one_step_one_wins_the_other_gets_409(two_replicas, monkeypatch):
    a, b = two_replicas
    s = a.post("/api/sessions", json={"domain": "toy", "method": "global", "rep": "onehot"}).json()
    hold_before_writing(monkeypatch)
    url = f"/api/sessions/{s['id']}/feedback"
    results = race(lambda: a.post(url, json=more("amplitude", 0)), lambda: b.post(url, json=more("pace", 0, "less")))

    assert sorted(r.status_code for r in results) == [200, 409], [r.text for r in results]
    won = next(r for r in results if r.status_code == 200).json()
    lost = next(r for r in results if r.status_code == 409).json()
    assert lost["detail"] == f"step 0 is stale: session {s['id']} already moved on"
    row, events = stored(a, s["id"])
    assert row.step == 1 and row.status == "active" and row.current_rollout_id == won["clip"]["rollout_id"]
    assert [(e.step, e.feedback) for e in events] == [(0, won["history"][0]["feedback"])]
    for client in (a, b):  # both replicas read the winner's state
        assert client.get(f"/api/sessions/{s['id']}").json()["clip"] == won["clip"]


def test_abandon_and_feedback_on_two_replicas_never_leave_an_answered_abandoned_session(two_replicas, monkeypatch):
    a, b = two_replicas
    s = a.post("/api/sessions", json={"domain": "toy", "method": "global", "rep": "onehot"}).json()
    hold_before_writing(monkeypatch)
    answer, abandon = race(lambda: a.post(f"/api/sessions/{s['id']}/feedback", json=more("amplitude", 0)),
                           lambda: b.post(f"/api/sessions/{s['id']}/abandon"))

    assert abandon.status_code == 200, abandon.text
    row, events = stored(a, s["id"])
    assert row.status == "abandoned"
    if answer.status_code == 200:  # the answer came first, then the abandon: both hold
        assert row.step == 1 and [e.step for e in events] == [0]
    else:  # the abandon came first: the answer changed nothing
        assert answer.status_code == 409, answer.text
        assert answer.json()["detail"] == (f"session {s['id']} is abandoned; it takes no more feedback "
                                           "(start a new session)")
        assert row.step == 0 and events == []


def test_a_version_activated_on_one_replica_serves_new_sessions_on_the_other(make_settings, database_url, tmp_path,
                                                                           toy_roots):
    """The active version lives in SQL (``rba_active_model``) and the models on the shared models folder."""
    models = toy_roots[1]
    shutil.copytree(models, tmp_path / "models")
    shutil.copytree(models / "toy", tmp_path / "models" / "versions" / "toy-v2" / "toy")  # what a job publishes
    auth = {"Authorization": f"Bearer {REPLICA_TOKEN}"}

    def app(name: str) -> TestClient:
        return TestClient(create_app(make_settings(database_url=database_url, replica=name, admin_token=REPLICA_TOKEN,
                                                   models_dir=tmp_path / "models")))

    with app("a") as a, app("b") as b:
        with Session(a.app.state.services.engine) as db:  # the row the job recorded with its success
            db.add(ModelVersion(version="toy-v2", domain="toy", method="global", rep="onehot", job_id="j",
                                attributes=["amplitude", "pace"], held_out={}))
            db.commit()
        new = {"domain": "toy", "method": "global", "rep": "onehot"}
        assert b.post("/api/sessions", json=new).json()["model_set"] == "builtin"
        assert a.post("/api/admin/models/toy-v2/activate", headers=auth).status_code == 200
        assert b.post("/api/sessions", json=new).json()["model_set"] == "toy-v2"
        assert a.post("/api/admin/models/builtin/activate", params={"domain": "toy"}, headers=auth).status_code == 200
        assert b.post("/api/sessions", json=new).json()["model_set"] == "builtin"


def test_replicas_starting_together_on_a_fresh_database_all_get_the_schema(database_url):
    """Without the schema lock, concurrent create_all on PostgreSQL fails with a duplicate key in pg_type."""
    engines, errors = make_engines_together(database_url, 4)
    assert errors == [] and len(engines) == 4
    for engine in engines:
        with Session(engine) as db:
            assert db.exec(select(TuningSession)).all() == []
        engine.dispose()
