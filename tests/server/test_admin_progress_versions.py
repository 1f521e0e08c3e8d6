"""What the admin page shows about training and versions: one progress bar for the whole job with a time estimate,
held-out numbers beside those of what a version would replace, and the intro's attributes after activating."""

from __future__ import annotations

import datetime as dt
import json
import shutil

import pytest
from fastapi.testclient import TestClient
from sqlmodel import Session

from server.db.admin_tables import ModelVersion, TrainJob
from server.main import create_app
from tests.conftest import own_copy

TOKEN = "progress-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
CARD_SECONDS = {"ranker": 100.0, "global_reward": 300.0}  # ζσ a quarter of the job, rθ three quarters


def _edit_card(path, change) -> None:
    card = json.loads(path.read_text())
    change(card)
    path.write_text(json.dumps(card))


@pytest.fixture
def settings(make_settings, toy_roots, tmp_path, database_url):
    """Own copies of the toy models (cards with known training seconds) and data."""
    own_copy(toy_roots, tmp_path)
    for kind, seconds in CARD_SECONDS.items():
        _edit_card(tmp_path / "models" / "toy" / f"{kind}-onehot.json",
                   lambda c, s=seconds: c["training"].update(seconds=s))
    return make_settings(admin_token=TOKEN, data_dir=tmp_path / "data", models_dir=tmp_path / "models",
                         database_url=database_url)


@pytest.fixture
def admin(settings):
    with TestClient(create_app(settings)) as c:
        yield c


def _job(admin, method: str = "global", **fields) -> str:
    """A running job's row as its process would leave it (no process: the test plays the trainer)."""
    now = dt.datetime.now(dt.UTC)
    job = TrainJob(domain="toy", method=method, rep="onehot", preset="tiny", datasets=[], state="running",
                   created_at=now - dt.timedelta(seconds=100), updated_at=now, heartbeat_at=now, **fields)
    with Session(admin.app.state.services.engine) as db:
        db.add(job)
        db.commit()
        return job.id


def _set(admin, job_id: str, **fields) -> dict:
    with Session(admin.app.state.services.engine) as db:
        job = db.get(TrainJob, job_id)
        for k, v in fields.items():
            setattr(job, k, v)
        db.add(job)
        db.commit()
    r = admin.get(f"/api/admin/jobs/{job_id}", headers=AUTH)
    assert r.status_code == 200, r.text
    return r.json()


def test_progress_is_one_bar_for_the_whole_job_with_an_estimate(admin):
    job_id = _job(admin, stage="loading")
    seen = []
    for stage, step, total in [("loading", 0, 0), ("ranker[onehot]", 1, 200), ("ranker[onehot]", 100, 200),
                               ("ranker[onehot]", 200, 200), ("global_reward[onehot]", 1, 120),
                               ("global_reward[onehot]", 60, 120), ("global_reward[onehot]", 120, 120)]:
        seen.append(_set(admin, job_id, stage=stage, step=step, total=total))
    progress = [j["progress"] for j in seen]
    assert progress == sorted(progress), progress  # never drops between stages (it fell from 1.0 to 0.01 before)
    assert progress[2] == pytest.approx(0.125) and progress[3] == pytest.approx(0.25)  # ζσ weighs 100 s of 400
    assert progress[5] == pytest.approx(0.25 + 0.75 / 2) and progress[6] == pytest.approx(1.0)
    assert seen[0]["eta_seconds"] is None  # nothing done yet: no estimate
    # 100 s elapsed for 62.5 %: the rest at the same pace takes 60 s more
    assert seen[5]["eta_seconds"] == pytest.approx(60, abs=2)
    assert seen[5]["stage"] == "global_reward[onehot]" and seen[5]["step"] == 60  # the stage's own numbers stay
    done = _set(admin, job_id, state="succeeded", stage="done", step=120, total=120)
    assert done["progress"] == 1.0 and done["eta_seconds"] is None
    listed = admin.get("/api/admin/jobs", params={"domain": "toy"}, headers=AUTH).json()
    assert [(j["id"], j["progress"]) for j in listed] == [(job_id, 1.0)]


def test_a_method_without_shipped_cards_weighs_its_stages_equally(admin):
    job_id = _job(admin, method="local", stage="local_reward[onehot]", step=30, total=150)  # toy ships no local
    assert _set(admin, job_id)["progress"] == pytest.approx(0.2)


def _publish(settings, admin, version: str, argmax: float, amplitude: float, wobble_pairs: int) -> None:
    """A version folder (the toy models with other held-out numbers, plus an uploaded attribute) and its row."""
    folder = settings.models_dir / "versions" / version / "toy"
    shutil.copytree(settings.models_dir / "toy", folder)
    wobble = {"held_out_pair_accuracy": 0.9 if wobble_pairs else None, "held_out_pairs": wobble_pairs}

    def ranker(card):
        card["attributes"].append({"name": "wobble", "description": "How much the dot wobbles.", "unit": ""})
        card["held_out"]["amplitude"]["pairwise_accuracy"] = amplitude
        card["held_out"]["wobble"] = wobble

    _edit_card(folder / "ranker-onehot.json", ranker)
    _edit_card(folder / "global_reward-onehot.json", lambda c: c["held_out"].update(argmax_within_epsilon=argmax))
    with Session(admin.app.state.services.engine) as db:
        db.add(ModelVersion(version=version, domain="toy", method="global", rep="onehot", job_id="0" * 32,
                            attributes=["amplitude", "pace", "wobble"], held_out={}))
        db.commit()


def _versions(admin) -> dict[str, dict]:
    r = admin.get("/api/admin/models", params={"domain": "toy"}, headers=AUTH)
    assert r.status_code == 200, r.text
    return {v["version"]: v for v in r.json()}


def test_versions_show_what_they_replace_and_why_to_confirm(admin, settings, toy_roots):
    builtin_card = json.loads((settings.models_dir / "toy" / "global_reward-onehot.json").read_text())
    shipped_argmax = builtin_card["held_out"]["argmax_within_epsilon"]
    ranker_card = json.loads((settings.models_dir / "toy" / "ranker-onehot.json").read_text())
    shipped_amplitude = ranker_card["held_out"]["amplitude"]["pairwise_accuracy"]
    _publish(settings, admin, "toy-worse", argmax=shipped_argmax - 0.1, amplitude=shipped_amplitude, wobble_pairs=0)
    _publish(settings, admin, "toy-better", argmax=min(1.0, shipped_argmax + 0.05), amplitude=1.0, wobble_pairs=12)

    versions = _versions(admin)
    builtin, worse, better = versions["builtin"], versions["toy-worse"], versions["toy-better"]
    assert builtin["active"] and builtin["baseline"] is None and builtin["concerns"] == []
    assert builtin["scores"]["argmax within ε"] == pytest.approx(shipped_argmax)
    assert builtin["scores"]["pair accuracy · amplitude"] == pytest.approx(shipped_amplitude)
    assert worse["baseline"] == "builtin" and worse["baseline_scores"] == builtin["scores"]
    assert worse["scores"]["pair accuracy · wobble"] is None
    assert worse["concerns"] == ["pair accuracy · wobble: untested (no held-out pairs)",
                                 f"argmax within ε: {shipped_argmax - 0.1:.3f}, below {shipped_argmax:.3f} of builtin"]
    assert better["scores"]["pair accuracy · wobble"] == 0.9 and better["concerns"] == []

    r = admin.post("/api/admin/models/toy-worse/activate", headers=AUTH)  # the page asked; the API serves it
    assert r.status_code == 200 and r.json()["active"] is True
    versions = _versions(admin)
    assert versions["toy-worse"]["baseline"] is None and versions["toy-worse"]["concerns"] == []
    assert versions["builtin"]["baseline"] == "toy-worse" and versions["builtin"]["concerns"] == []  # better
    assert versions["toy-better"]["baseline"] == "toy-worse"

    toy = next(d for d in admin.get("/api/domains").json()["domains"] if d["name"] == "toy")
    assert [a["name"] for a in toy["attributes"]] == ["amplitude", "pace", "wobble"]  # the intro's list
    admin.post("/api/admin/models/builtin/activate", params={"domain": "toy"}, headers=AUTH)
    toy = next(d for d in admin.get("/api/domains").json()["domains"] if d["name"] == "toy")
    assert [a["name"] for a in toy["attributes"]] == ["amplitude", "pace"]


def test_docs_pages_load_nothing_from_elsewhere(admin):
    for path, assets in [("/docs", ["swagger-ui-bundle.js", "swagger-ui.css"]), ("/redoc", ["redoc.standalone.js"])]:
        r = admin.get(path)
        assert r.status_code == 200, r.text
        assert "http://" not in r.text and "https://" not in r.text, r.text  # no CDN, no web fonts
        for name in [*assets, "favicon.png"]:
            assert f'"/docs-assets/{name}"' in r.text
            got = admin.get(f"/docs-assets/{name}")
            assert got.status_code == 200 and len(got.content) > 1000, name
    assert admin.get("/docs-assets/missing.js").status_code == 404
