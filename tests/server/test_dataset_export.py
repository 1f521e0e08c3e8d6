"""``rba export --format minari`` of a session's clips and of the admin page's labels, from the app's database."""

from __future__ import annotations

import minari
import numpy as np
import pytest
from sqlmodel import Session

from rba.cli import main
from rba.data.export_zip import read_export
from rba.data.library import SkillLibrary
from rba.data.minari_export import STATES_ATOL, STATES_RTOL, MinariExportError
from rba.domains import get_domain
from rba.generate.cma import generated_id
from server.db.admin_tables import LabelRecord
from server.db.tables import FeedbackEvent, GeneratedClip, TuningSession
from server.ops.dataset_export import labels_to_dataset, session_to_dataset
from tests.server.conftest import more


def _load(monkeypatch, root, dataset_id: str) -> minari.MinariDataset:
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    return minari.load_dataset(dataset_id)


def _rollout_ids(ds: minari.MinariDataset) -> list[str]:
    return [m["rollout_id"] for m in ds.storage.get_episode_metadata(range(ds.total_episodes))]


def _recorded(episode) -> np.ndarray:
    return episode.observations[episode.infos["recorded"]].astype(np.float32)


def test_a_sessions_clips_with_its_exported_reward(client, session, tmp_path, monkeypatch):
    sid, first = session["id"], session["clip"]["rollout_id"]
    r = client.post(f"/api/sessions/{sid}/feedback", json=more("amplitude", 0, clip=first))
    assert r.status_code == 200, r.text
    second = r.json()["clip"]["rollout_id"]
    r = client.post(f"/api/sessions/{sid}/feedback", json={"step": 1, "satisfied": True})
    assert r.status_code == 200, r.text
    profile = tmp_path / "profile.zip"
    profile.write_bytes(client.get(f"/api/sessions/{sid}/export").content)
    svc = client.app.state.services
    written = session_to_dataset(sid, tmp_path / "ds", profile, settings=svc.settings)
    assert written.dataset_id == f"rba/session-{sid}-v0"
    ds = _load(monkeypatch, tmp_path / "ds", written.dataset_id)
    shown = list(dict.fromkeys([first, second]))
    assert _rollout_ids(ds) == shown
    about = ds.storage.metadata["rba"]
    assert about["source"] == "session" and about["session"]["id"] == sid and about["session"]["status"] == "satisfied"
    assert [r["feedback"] for r in about["session"]["rounds"]] == [[{"attribute": "amplitude", "direction": "more"}],
                                                                    "satisfied"]
    library, reward = svc.catalog.library("toy"), read_export(profile).reward
    for rid, episode in zip(shown, ds.iterate_episodes(), strict=True):
        states = library.trajectory(library.index_of(rid))
        np.testing.assert_allclose(_recorded(episode), states, rtol=STATES_RTOL, atol=STATES_ATOL)
        assert episode.rewards.sum() == pytest.approx(reward.total(states), rel=1e-5)


def test_a_sessions_made_clip_is_simulated_again(client, tmp_path, monkeypatch):
    """A clip a search made is remade from its row's params and seed, and comes out as the rollout it was."""
    svc = client.app.state.services
    serve = svc.catalog.library("toy")
    toy = get_domain("toy")
    params, seed = toy.sample_params(np.random.default_rng(3)), 7
    made = toy.rollout(params, seed)
    gid = generated_id("toy", params, seed)
    with Session(svc.engine) as db:
        db.add(GeneratedClip(id=gid, domain="toy", params=params, seed=seed, proxies=made.proxies))
        db.add(TuningSession(id="made", domain="toy", method="global", rep="onehot", model_version="v", step=1,
                             current_rollout_id=gid, agent_state={}, library_version=serve.version))
        db.commit()
        db.add(FeedbackEvent(session_id="made", step=0, feedback=[{"attribute": "pace", "direction": "less"}],
                             rollout_before=serve.ids[3], rollout_after=gid))
        db.commit()
    written = session_to_dataset("made", tmp_path, settings=svc.settings)
    ds = _load(monkeypatch, tmp_path, written.dataset_id)
    assert _rollout_ids(ds) == [serve.ids[3], gid]
    episode = list(ds.iterate_episodes())[1]
    np.testing.assert_allclose(_recorded(episode), made.states, rtol=STATES_RTOL, atol=STATES_ATOL)
    meta = next(iter(ds.storage.get_episode_metadata([1])))
    assert meta["seed"] == seed and meta["options"]["params"] == pytest.approx(params)


def test_an_unknown_session_names_the_database(client, tmp_path):
    with pytest.raises(LookupError, match=r"no session 'nosuch' \(database "):
        session_to_dataset("nosuch", tmp_path, settings=client.app.state.services.settings)


def test_the_admin_labels_as_episodes_and_pairs(client, tmp_path, monkeypatch, capsys):
    svc = client.app.state.services
    serve = svc.catalog.library("toy")
    train = SkillLibrary.load("toy", "train", svc.store.data_dir)
    s1, t2, s4, t5, s6 = serve.ids[1], train.ids[2], serve.ids[4], train.ids[5], serve.ids[6]
    with pytest.raises(MinariExportError, match="toy has no labels made on the admin page; label clips at /admin"):
        labels_to_dataset("toy", tmp_path, settings=svc.settings)
    with Session(svc.engine) as db:
        db.add(LabelRecord(domain="toy", kind="ordering", attribute="amplitude",
                           payload={"attribute": "amplitude", "clips": [s1, t2, s4]}))
        db.add(LabelRecord(domain="toy", kind="comparison", attribute="pace",
                           payload={"attribute": "pace", "more": t5, "less": s1}))
        db.add(LabelRecord(domain="toy", kind="local_change", attribute="amplitude",
                           payload={"attribute": "amplitude", "anchor": s4, "changed": s6, "direction": "less"}))
        db.commit()
    out = tmp_path / "ds"
    settings = svc.settings
    for name, value in {"RBA_DATA_DIR": settings.data_dir, "RBA_MODELS_DIR": settings.models_dir,
                        "RBA_CACHE_DIR": settings.cache_dir, "RBA_DATABASE_URL": settings.db_url}.items():
        monkeypatch.setenv(name, str(value))  # `rba export` reads the app's settings from the environment
    assert main(["export", "--format", "minari", "--labels", "--domain", "toy", "--out", str(out)]) == 0
    assert "wrote rba/toy-labels-v0 (5 episodes" in capsys.readouterr().out
    ds = _load(monkeypatch, out, "rba/toy-labels-v0")
    assert _rollout_ids(ds) == [s1, t2, s4, t5, s6]
    for (lib, rid), episode in zip([(serve, s1), (train, t2), (serve, s4), (train, t5), (serve, s6)],
                                   ds.iterate_episodes(), strict=True):
        np.testing.assert_allclose(_recorded(episode), lib.trajectory(lib.index_of(rid)), rtol=STATES_RTOL,
                                   atol=STATES_ATOL)
    about = ds.storage.metadata["rba"]
    assert about["source"] == "labels"
    pairs = {(p["attribute"], p["more"], p["less"]) for p in about["pairs"]}
    assert pairs == {("amplitude", 1, 0), ("amplitude", 2, 0), ("amplitude", 2, 1), ("pace", 3, 0)}
    assert about["local_changes"] == [{"attribute": "amplitude", "anchor": 2, "changed": 4, "direction": "less"}]
    assert about["labels"]["orderings"] == [{"attribute": "amplitude", "clips": [s1, t2, s4]}]
