"""A new walker attribute end to end, through the REST API only.

An admin adds ``foot_lift`` ("How high the walker lifts its feet while stepping."), labels
100 library clips by ordering them (the simulated labeller looks at a proxy: the peak foot
clearance of the clip's states; nothing else ever sees it), retrains, activates the new
version; then a simulated user tunes foot_lift in sessions over 10 held-out targets.

    python -m pytest tests/test_new_attribute.py -q -s     # prints the SR / AF it measured
"""

from __future__ import annotations

import io
import json
import shutil
import time
import zipfile

import numpy as np
import pytest
from fastapi.testclient import TestClient

from rba.core.settings import REPO_ROOT
from rba.data.library import SkillLibrary
from rba.interact.users import SimulatedUser
from server.common.app_settings import Settings
from server.main import create_app

TOKEN = "new-attribute-test"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
CLEARANCE = slice(26, 28)  # walker state features: right/left foot clearance above the floor (m)
EPSILON = 0.015  # m; foot_lift spans ~0.06-0.17 m over the library: ~7 buckets, like the built-in attributes
LABELLED = 100  # clips the admin orders (10 orderings of 10)
TARGETS = 10
MAX_STEPS = 40  # feedback rounds per session before it counts as a failure


def foot_lift(lib: SkillLibrary) -> np.ndarray:
    """The labeller's proxy: the highest either foot gets above the floor during the clip (m)."""
    return np.array([lib.trajectory(i)[:, CLEARANCE].max() for i in range(len(lib))])


@pytest.fixture(scope="module")
def app_client(tmp_path_factory):
    if not (REPO_ROOT / "models" / "walker" / "ranker-onehot.pt").exists():
        pytest.fail("the shipped walker models are missing (models/walker); they are part of the repository")
    root = tmp_path_factory.mktemp("new-attribute")
    shutil.copytree(REPO_ROOT / "data" / "walker", root / "data" / "walker")
    shutil.copytree(REPO_ROOT / "models" / "walker", root / "models" / "walker")
    settings = Settings(data_dir=root / "data", models_dir=root / "models", admin_token=TOKEN, warm_start=False,
                        prerender=False, database_url=f"sqlite:///{root / 'rba.db'}")
    with TestClient(create_app(settings)) as client:
        yield client


def test_new_attribute_end_to_end(app_client):
    client = app_client
    train = SkillLibrary.load("walker", "train")
    serve = SkillLibrary.load("walker", "serve")
    test = SkillLibrary.load("walker", "test")

    r = client.post("/api/admin/attributes", headers=AUTH, json={
        "domain": "walker", "name": "foot_lift", "description": "How high the walker lifts its feet while stepping."})
    assert r.status_code == 201, r.text

    # the admin orders 100 train clips, 10 at a time, by what they see (here: the proxy)
    rng = np.random.default_rng(0)
    picked = rng.choice(len(train), LABELLED, replace=False)
    lift = foot_lift(train)
    for group in picked.reshape(-1, 10):
        clips = [train.ids[i] for i in sorted(group, key=lambda i: lift[i])]
        r = client.post("/api/admin/labels", headers=AUTH,
                        json={"domain": "walker", "ordering": {"attribute": "foot_lift", "clips": clips}})
        assert r.status_code == 201, r.text

    start = time.perf_counter()
    r = client.post("/api/admin/train", headers=AUTH, json={"domain": "walker", "preset": "quick"})
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    while (job := client.get(f"/api/admin/jobs/{job_id}", headers=AUTH).json())["state"] in ("queued", "running"):
        time.sleep(1)
    assert job["state"] == "succeeded", job
    held = job["held_out"]["ranker"]["foot_lift"]
    print(f"\ntraining {time.perf_counter() - start:.0f} s; foot_lift held-out pair accuracy "
          f"{held['held_out_pair_accuracy']:.3f} on {held['held_out_pairs']} pairs")
    assert held["held_out_pair_accuracy"] >= 0.85, job["held_out"]

    r = client.post(f"/api/admin/models/{job['version']}/activate", headers=AUTH)
    assert r.status_code == 200, r.text

    # a simulated user who only cares about foot_lift, targets from held-out test clips
    serve_lift = foot_lift(serve)
    targets = foot_lift(test)[np.random.default_rng(1).choice(len(test), TARGETS, replace=False)]
    outcomes, exported = [], {}
    for t, target in enumerate(targets):
        user = SimulatedUser(np.array([target]), np.array([EPSILON]), ("foot_lift",), serve_lift[:, None], seed=t)
        s = client.post("/api/sessions", json={"domain": "walker", "method": "global", "rep": "onehot"}).json()
        assert s["model_set"] == job["version"] and "foot_lift" in [a["name"] for a in s["attributes"]]
        feedbacks = 0
        while s["status"] == "active" and s["step"] < MAX_STEPS:
            answer = user.respond(serve.index_of(s["clip"]["rollout_id"]))
            if answer == "satisfied":
                body = {"step": s["step"], "satisfied": True}
            else:
                body = {"step": s["step"], "feedback": [{"attribute": fb.attribute,
                                                         "direction": "more" if fb.direction > 0 else "less"}
                                                        for fb in answer]}
                feedbacks += 1
            r = client.post(f"/api/sessions/{s['id']}/feedback", json=body)
            assert r.status_code == 200, r.text
            s = r.json()
        outcomes.append((s["status"] == "satisfied", feedbacks))
        if s["status"] == "satisfied" and not exported:  # the export names ζσ by the model's attributes, new ones too
            r = client.get(f"/api/sessions/{s['id']}/export")
            assert r.status_code == 200, r.text
            with zipfile.ZipFile(io.BytesIO(r.content)) as zf:
                exported = json.loads(zf.read("profile.json"))["zeta"]
    assert set(exported) == {"step_size", "softness", "foot_lift"}, exported
    sr = np.mean([ok for ok, _ in outcomes])
    af = np.mean([n for ok, n in outcomes if ok]) if sr else float("nan")
    print(f"foot_lift over {TARGETS} targets: SR {sr:.2f}, AF {af:.2f}")
    assert sr >= 0.9, outcomes
