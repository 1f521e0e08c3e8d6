"""Sessions live in the database: a new app on the same database continues them exactly."""

from __future__ import annotations

from fastapi.testclient import TestClient
from sqlmodel import Session, select

from rba.interact import AttributeFeedback, load_context, new_agent
from server.db.tables import FeedbackEvent, TuningSession
from server.main import create_app
from tests.server.conftest import more

PLAN = [("amplitude", "more"), ("pace", "less"), ("amplitude", "less"), ("pace", "more")]


def reference_ids(toy_roots) -> list[str]:
    """What one agent, never serialised, shows for PLAN."""
    data, models, _ = toy_roots
    agent = new_agent("global", load_context("toy", "global", "onehot", data, models))
    ids = [agent.first_query()]
    for attribute, direction in PLAN:
        ids.append(agent.update([AttributeFeedback(attribute, 1 if direction == "more" else -1)]))
    return ids


def test_session_continues_exactly_after_a_restart(make_settings, database_url, toy_roots):
    settings = make_settings(database_url=database_url)
    with TestClient(create_app(settings)) as first:
        s = first.post("/api/sessions", json={"domain": "toy"}).json()
        for step, (attribute, direction) in enumerate(PLAN[:2]):
            s = first.post(f"/api/sessions/{s['id']}/feedback", json=more(attribute, step, direction)).json()
    with TestClient(create_app(settings)) as second:  # a new process would see only the database
        again = second.get(f"/api/sessions/{s['id']}").json()
        assert again == s
        for step, (attribute, direction) in enumerate(PLAN[2:], start=2):
            r = second.post(f"/api/sessions/{s['id']}/feedback", json=more(attribute, step, direction))
            assert r.status_code == 200, r.text
        final = r.json()
    shown = [h["rollout_before"]["rollout_id"] for h in final["history"]] + [final["clip"]["rollout_id"]]
    assert shown == reference_ids(toy_roots)
    assert final["step"] == len(PLAN) and len(final["history"]) == len(PLAN)


def test_each_feedback_is_one_event_and_one_session_update(make_settings, database_url):
    settings = make_settings(database_url=database_url)
    with TestClient(create_app(settings)) as client:
        s = client.post("/api/sessions", json={"domain": "toy"}).json()
        client.post(f"/api/sessions/{s['id']}/feedback", json=more("pace", 0))
        client.post(f"/api/sessions/{s['id']}/feedback", json={"step": 0, "feedback": [{"attribute": "x",
                                                                                          "direction": "more"}]})
        engine = client.app.state.services.engine
        with Session(engine) as db:
            events = db.exec(select(FeedbackEvent).where(FeedbackEvent.session_id == s["id"])).all()
            row = db.get(TuningSession, s["id"])
        assert [(e.step, e.feedback) for e in events] == [(0, [{"attribute": "pace", "direction": "more"}])]
        assert events[0].rollout_before == s["clip"]["rollout_id"] and events[0].rollout_after == row.current_rollout_id
        assert row.step == 1 and row.agent_state["method"] == "global" and row.agent_state["rejected"]
