"""GET /api/sessions/{id}/export: status codes with their text, and what the zip holds."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np

from rba.data.export_zip import read_export
from tests.server.conftest import more


def _finish(client, session: dict, asks: int = 1) -> dict:
    """Answer ``asks`` rounds with "more amplitude", then "this is it"."""
    sid, now = session["id"], session
    for _ in range(asks):
        body = more("amplitude", now["step"], clip=now["clip"]["rollout_id"])
        r = client.post(f"/api/sessions/{sid}/feedback", json=body)
        assert r.status_code == 200, r.text
        now = r.json()
    r = client.post(f"/api/sessions/{sid}/feedback", json={"step": now["step"], "satisfied": True})
    assert r.status_code == 200 and r.json()["status"] == "satisfied", r.text
    return r.json()


def test_export_of_a_satisfied_session_holds_profile_clip_and_reward(client, session, tmp_path):
    done = _finish(client, session)
    r = client.get(f"/api/sessions/{session['id']}/export")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/zip"
    assert r.headers["content-disposition"] == f'attachment; filename="rba-toy-{session["id"]}.zip"'
    with zipfile.ZipFile(io.BytesIO(r.content)) as zf:
        assert sorted(zf.namelist()) == ["README.md", "clip.mp4", "profile.json", "reward.json", "reward.pt"]
        profile = json.loads(zf.read("profile.json"))
        assert zf.read("clip.mp4")[4:8] == b"ftyp"  # an MP4
    assert profile["domain"] == "toy" and profile["method"] == "global" and profile["rep"] == "onehot"
    assert profile["rollout_id"] == done["clip"]["rollout_id"]
    assert profile["proxies"] == done["clip"]["measured"]
    assert set(profile["params"]) == {"amplitude", "pace"} and isinstance(profile["seed"], int)
    assert set(profile["zeta"]) == {"amplitude", "pace"}
    assert [h["feedback"] for h in profile["feedback"]] == [[{"attribute": "amplitude", "direction": "more"}],
                                                              "satisfied"]
    assert profile["model"]["version"] == session["model_version"]
    assert set(profile["model"]["weights_sha"]) == {"ranker", "global_reward"}
    assert profile["reward"]["kind"] == "global_reward" and len(profile["reward"]["condition"]["v_star"]) == 2
    assert set(profile["simulators"]) == {"mujoco", "dm-control", "highway-env", "gymnasium"}
    path = tmp_path / "out.zip"
    path.write_bytes(r.content)
    export = read_export(path)
    chosen = export.reward.rewards(np.zeros((3, 4)))
    assert chosen.shape == (3,) and np.isfinite(chosen).all()


def test_export_of_an_unknown_session_is_404(client):
    r = client.get("/api/sessions/nosuchsession/export")
    assert r.status_code == 404
    assert r.json()["detail"] == "no session 'nosuchsession'; create one with POST /api/sessions"


def test_export_of_an_active_or_abandoned_session_is_409(client, session):
    sid = session["id"]
    r = client.get(f"/api/sessions/{sid}/export")
    assert r.status_code == 409
    assert r.json()["detail"] == (f'session {sid} is active: only a session that ended satisfied ("This is it") '
                                  "can be exported")
    assert client.post(f"/api/sessions/{sid}/abandon").status_code == 200
    r = client.get(f"/api/sessions/{sid}/export")
    assert r.status_code == 409 and f"session {sid} is abandoned: only" in r.json()["detail"]


def test_a_session_whose_serve_library_was_rebuilt_is_not_exported(client, session):
    """A session names the serve library its clip ids come from; one rebuilt since (another content hash) is
    refused, a session from before migration 0006 (no library named) is exported as before."""
    from sqlmodel import Session

    from server.db.tables import TuningSession

    _finish(client, session)
    svc = client.app.state.services
    sid = session["id"]
    with Session(svc.engine) as db:
        row = db.get(TuningSession, sid)
        current = svc.catalog.library("toy").version
        assert row.library_version == current
        row.library_version = "0123456789ab"  # as if the library had been rebuilt since
        db.add(row)
        db.commit()
    r = client.get(f"/api/sessions/{sid}/export")
    assert r.status_code == 409
    assert r.json()["detail"] == (f"session {sid} showed clips of toy's serve library 0123456789ab; it is {current} "
                                  "now (rebuilt), so its clip ids name other behaviours: it cannot be exported")
    with Session(svc.engine) as db:
        row = db.get(TuningSession, sid)
        row.library_version = None
        db.add(row)
        db.commit()
    assert client.get(f"/api/sessions/{sid}/export").status_code == 200
