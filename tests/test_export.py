"""The export zip: `rba export` from a toy session, `rba replay` of it, and every bad zip refused with one line."""

from __future__ import annotations

import io
import json
import pickle
import zipfile
from pathlib import Path

import pytest

import rba.data.export_zip as export_module
from rba.cli import main
from rba.core.fileio import load_json
from rba.data.export_zip import FORMAT_VERSION, ExportError, read_export
from rba.data.library import SkillLibrary


@pytest.fixture
def app_env(toy_roots, tmp_path, monkeypatch) -> dict:
    """The app's settings as `rba export` reads them (RBA_* variables) and a database holding toy sessions."""
    from sqlmodel import Session

    from server.db.engine import make_engine
    from server.db.tables import FeedbackEvent, TuningSession

    data, models, _ = toy_roots
    url = f"sqlite:///{tmp_path / 'rba.db'}"
    for name, value in {"RBA_DATA_DIR": data, "RBA_MODELS_DIR": models, "RBA_CACHE_DIR": tmp_path / "clips",
                        "RBA_DATABASE_URL": url}.items():
        monkeypatch.setenv(name, str(value))
    serve = SkillLibrary.load("toy", "serve", data)
    version = "-".join(load_json(models / "toy" / f"{kind}-onehot.json")["weights_sha"]
                       for kind in ("ranker", "global_reward"))
    first, chosen = serve.ids[3], serve.ids[7]
    engine = make_engine(url)
    with Session(engine) as db:
        for sid, status in (("done", "satisfied"), ("open", "active")):
            db.add(TuningSession(id=sid, domain="toy", method="global", rep="onehot", model_version=version,
                                 status=status, step=2, current_rollout_id=chosen, agent_state={}))
        db.commit()
        db.add(FeedbackEvent(session_id="done", step=0, feedback=[{"attribute": "pace", "direction": "less"}],
                             rollout_before=first, rollout_after=chosen))
        db.add(FeedbackEvent(session_id="done", step=1, feedback="satisfied", rollout_before=chosen,
                             rollout_after=chosen))
        db.commit()
    engine.dispose()
    return {"serve": serve, "chosen": chosen, "version": version}


@pytest.fixture
def exported(app_env, tmp_path) -> Path:
    out = tmp_path / "out.zip"
    assert main(["export", "done", str(out)]) == 0
    return out


def test_export_then_replay_matches(app_env, exported, capsys):
    profile = read_export(exported).profile
    serve, i = app_env["serve"], app_env["serve"].index_of(app_env["chosen"])
    assert profile.rollout_id == app_env["chosen"] and profile.seed == int(serve.seeds[i])
    assert profile.params == dict(zip(serve.param_names, serve.params[i].tolist(), strict=True))
    assert profile.proxies == serve.proxies_of(i)
    assert profile.model["version"] == app_env["version"]
    assert [r["feedback"] for r in profile.feedback] == [[{"attribute": "pace", "direction": "less"}], "satisfied"]
    assert not list(exported.parent.glob(".out.zip.*"))  # written atomically: no temporary left
    capsys.readouterr()
    assert main(["replay", str(exported)]) == 0
    out = capsys.readouterr().out
    assert out.strip().endswith("match") and "amplitude" in out and "pace" in out


def test_replay_of_a_profile_that_differs_from_its_simulation_exits_1(exported, tmp_path, capsys):
    bad = _rewrite(exported, tmp_path,
                   profile=lambda p: {**p, "proxies": {k: v + 1.0 for k, v in p["proxies"].items()}})
    assert main(["replay", str(bad)]) == 1
    assert "MISMATCH" in capsys.readouterr().out


def test_export_of_an_unknown_or_unfinished_session_exits_2(app_env, tmp_path, capsys):
    assert main(["export", "ghost", str(tmp_path / "x.zip")]) == 2
    assert "rba: error: no session 'ghost'" in capsys.readouterr().err
    assert main(["export", "open", str(tmp_path / "x.zip")]) == 2
    assert 'session open is active: only a session that ended satisfied ("This is it") can be exported' in \
        capsys.readouterr().err
    assert not (tmp_path / "x.zip").exists()


def test_export_names_the_database_and_makes_none(app_env, tmp_path, monkeypatch, capsys):
    assert main(["export", "ghost", str(tmp_path / "x.zip")]) == 2
    assert f"(database sqlite:///{tmp_path / 'rba.db'})" in capsys.readouterr().err
    monkeypatch.setenv("RBA_DATABASE_URL", f"sqlite:///{tmp_path / 'elsewhere' / 'rba.db'}")
    assert main(["export", "done", str(tmp_path / "x.zip")]) == 2
    assert f"no database at {tmp_path / 'elsewhere' / 'rba.db'}: the app has not run with these settings" in \
        capsys.readouterr().err
    assert not (tmp_path / "elsewhere").exists() and not (tmp_path / "x.zip").exists()


def test_export_to_a_folder_exits_2_and_writes_nothing(app_env, tmp_path, capsys):
    folder = tmp_path / "exports"
    folder.mkdir()
    assert main(["export", "done", str(folder)]) == 2
    err = capsys.readouterr().err
    assert f"rba: error: {folder} is a folder; give the zip's file path, e.g. {folder / 'behaviour.zip'}" in err
    assert list(folder.iterdir()) == [] and not list(tmp_path.glob(".exports*"))


def _rewrite(src: Path, tmp_path: Path, drop: str | None = None, replace: dict[str, bytes] | None = None,
             profile=None) -> Path:
    """A copy of the export ``src`` without ``drop``, with members replaced, or with its profile edited."""
    with zipfile.ZipFile(src) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    if profile is not None:
        members["profile.json"] = json.dumps(profile(json.loads(members["profile.json"]))).encode()
    members.update(replace or {})
    members.pop(drop, None)
    out = tmp_path / "bad.zip"
    with zipfile.ZipFile(out, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return out


def _bad_cases(exported: Path, tmp_path: Path) -> dict[str, tuple[Path, str]]:
    raw = exported.read_bytes()
    foreign = tmp_path / "foreign.zip"
    with zipfile.ZipFile(foreign, "w") as zf:
        zf.writestr("readme.txt", "hello")
    cases = {
        "truncated": (raw[: len(raw) // 2], "is not a zip archive (truncated or not an export)"),
        "not a zip": (b"hello", "is not a zip archive"),
    }
    out = {}
    for name, (data, message) in cases.items():
        path = tmp_path / f"{name.replace(' ', '_')}.zip"
        path.write_bytes(data)
        out[name] = (path, message)
    out["foreign"] = (foreign, "member 'readme.txt' is no export member (valid: profile.json, clip.mp4, README.md")
    twice = tmp_path / "twice.zip"  # a second clip.mp4 before the real one: unzip and the reader would differ
    with zipfile.ZipFile(exported) as src, zipfile.ZipFile(twice, "w") as zf:
        zf.writestr("clip.mp4", b"\0\0\0\x20ftypisom-other")
        with pytest.warns(UserWarning, match="Duplicate name: 'clip.mp4'"):
            for name in src.namelist():
                zf.writestr(name, src.read(name))
    out["duplicate member"] = (twice, "member clip.mp4 appears more than once; an export holds each member once")
    return out


@pytest.mark.parametrize("case", [
    "truncated", "not a zip", "foreign", "missing clip", "missing reward", "wrong version", "unknown domain",
    "wrong params", "nan param", "inf param", "param out of range", "negative seed", "huge seed",
    "pickled reward", "pickled profile", "tampered clip", "unknown field", "duplicate member", "unlisted member",
    "text proxy", "arrays not a mapping", "array not a member", "no v_star", "short v_star",
])
def test_bad_zips_exit_2_with_a_message(exported, tmp_path, case, capsys):
    edits = {
        "missing clip": ({"drop": "clip.mp4"}, "missing member clip.mp4"),
        "missing reward": ({"drop": "reward.pt"}, "missing member reward.pt"),
        "wrong version": ({"profile": lambda p: {**p, "format_version": FORMAT_VERSION + 1}},
                          f"unsupported format version {FORMAT_VERSION + 1}; this rba reads version {FORMAT_VERSION}"),
        "unknown domain": ({"profile": lambda p: {**p, "domain": "atlantis"}}, "unknown domain 'atlantis'; valid: "),
        "wrong params": ({"profile": lambda p: {**p, "params": {"amplitude": 1.0, "speed": 2.0}}},
                         "params ['amplitude', 'speed'] do not match domain 'toy''s param_names ['amplitude', 'pace']"),
        "nan param": ({"profile": lambda p: {**p, "params": {**p["params"], "amplitude": float("nan")}}},
                      "profile.json is not JSON ('NaN is not a JSON number')"),
        "inf param": ({"profile": lambda p: {**p, "params": {**p["params"], "amplitude": 1e308 * 10}}},
                      "profile.json is not JSON ('Infinity is not a JSON number')"),
        "param out of range": ({"profile": lambda p: {**p, "params": {**p["params"], "pace": 1e6}}},
                               "param pace = 1000000.0 is outside domain 'toy''s range ["),
        "negative seed": ({"profile": lambda p: {**p, "seed": -1}}, "seed must be an integer in [0, 2**32), got -1"),
        "huge seed": ({"profile": lambda p: {**p, "seed": 2**80}},
                      f"seed must be an integer in [0, 2**32), got {2**80}"),
        "pickled reward": ({"replace": {"reward.pt": pickle.dumps({"w": 1})}},
                           "member reward.pt is a pickle; exports hold no pickles"),
        "pickled profile": ({"replace": {"profile.json": pickle.dumps({"format": "rba-export"})}},
                            "member profile.json is a pickle; exports hold no pickles"),
        "tampered clip": ({"replace": {"clip.mp4": b"\0\0\0\x20ftypisom-other"}},
                          "member clip.mp4 does not match its sha256 in profile.json: the zip was changed"),
        "unknown field": ({"profile": lambda p: {**p, "extra": 1}}, "unknown ['extra']"),
        "unlisted member": ({"replace": {"notes.npy": b"hi"}},
                            "member notes.npy is not listed in profile.json's members, so nothing checks it"),
        "text proxy": ({"profile": lambda p: {**p, "proxies": {**p["proxies"], "pace": "fast"}}},
                       "profile.json proxies must map attribute names to finite numbers"),
        "arrays not a mapping": ({"profile": lambda p: {**p, "reward": {**p["reward"], "arrays": ["a.npy"]}}},
                                 "profile.json reward arrays must map names to .npy members listed in its members"),
        "array not a member": ({"profile": lambda p: {**p, "reward": {**p["reward"], "arrays": {"a": "a.npy"}}}},
                               "profile.json reward arrays must map names to .npy members listed in its members"),
        "no v_star": ({"profile": lambda p: {**p, "reward": {**p["reward"], "condition": {}}}},
                      "reward condition v_star must be 2 finite numbers, one per attribute (amplitude, pace)"),
        "short v_star": ({"profile": lambda p: {**p, "reward": {**p["reward"], "condition": {"v_star": [0.1]}}}},
                         "reward condition v_star must be 2 finite numbers, one per attribute (amplitude, pace)"),
    }
    if case in edits:
        kwargs, message = edits[case]
        path = _rewrite(exported, tmp_path, **kwargs)
    else:
        path, message = _bad_cases(exported, tmp_path)[case]
    assert main(["replay", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rba: error: ") and message in err and err.count("\n") == 1


def test_every_export_holds_a_readme_naming_each_member(exported, tmp_path):
    """README.md says what each member is and how to use the zip; an export without one (older) still reads."""
    with zipfile.ZipFile(exported) as zf:
        names, readme = zf.namelist(), zf.read("README.md").decode()
    assert "README.md" in names and read_export(exported).profile.members["README.md"]
    assert all(f"`{name}`" in readme for name in names)
    assert "rba replay" in readme and "rba.gym.ExportedReward" in readme and "rba.gym.skill_policy" in readme
    old = _rewrite(exported, tmp_path, drop="README.md", profile=lambda p: {
        **p, "members": {k: v for k, v in p["members"].items() if k != "README.md"}})
    assert read_export(old).reward is not None


@pytest.mark.parametrize("cap, message", [
    ("MAX_MEMBER_BYTES", "unpacks to more than 0 MiB; not an RBA export"),
    ("MAX_EXPORT_BYTES", "the members unpack to more than 0 MiB; not an RBA export"),
])
def test_an_export_unpacking_beyond_its_caps_is_refused_before_unpacking(exported, monkeypatch, cap, message):
    monkeypatch.setattr(export_module, cap, 1000)
    monkeypatch.setattr(zipfile.ZipFile, "read", lambda *args: pytest.fail("a member was unpacked"))
    with pytest.raises(ExportError, match=message):
        read_export(exported)


def test_reading_an_export_calls_no_pickle_loader(exported, monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("pickle.load called")

    monkeypatch.setattr(pickle, "load", refuse)
    monkeypatch.setattr(pickle, "loads", refuse)
    export = read_export(exported)
    assert export.reward is not None and export.clip[4:8] == b"ftyp"
    with zipfile.ZipFile(exported) as zf:
        assert io.BytesIO(zf.read("reward.pt")).read(2) == b"PK"  # torch's zip format, read with weights_only=True


def _local_source(toy_roots, tmp_path, rounds_of):
    """An RBA-Local export source over an untrained local reward saved under ``tmp_path`` (and the model)."""
    import torch

    from rba.core.artifacts import save_model, weights_sha
    from rba.data.export_zip import ExportSource
    from rba.learn.local_reward import LocalReward

    torch.manual_seed(0)
    arch = {"state_dim": 4, "num_attributes": 2, "embed_dim": 2, "hidden": 16, "layers": 2, "lstm_hidden": 8,
            "lstm_layers": 1, "anchor_stride": 2}
    model = LocalReward(4, torch.eye(2), 16, 2, 8, 1, 2).eval()
    card = {"domain": "toy", "kind": "local_reward", "representation": "onehot", "weights_sha": weights_sha(model),
            "attributes": [{"name": "amplitude"}, {"name": "pace"}], "architecture": arch}
    save_model(model, card, tmp_path / "models")
    serve = SkillLibrary.load("toy", "serve", toy_roots[0])
    rounds, chosen = rounds_of(serve.ids)
    return ExportSource("toy", "local", "onehot", card["weights_sha"], "builtin", tmp_path / "models", serve, chosen,
                        rounds, clip=b"clip"), model, serve


def test_a_local_export_conditions_on_the_last_asked_change(toy_roots, tmp_path):
    import numpy as np
    import torch

    from rba.data.export_zip import write_export
    from rba.learn.common import Ragged

    def rounds_of(ids):
        less_amp_more_pace = [{"attribute": "amplitude", "direction": "less"},
                              {"attribute": "pace", "direction": "more"}]
        return [{"step": 0, "feedback": [{"attribute": "pace", "direction": "more"}], "rollout_before": ids[1],
                 "rollout_after": ids[2]},
                {"step": 1, "feedback": less_amp_more_pace, "rollout_before": ids[2], "rollout_after": ids[4]},
                {"step": 2, "feedback": "satisfied", "rollout_before": ids[4], "rollout_after": ids[4]}], ids[4]

    src, model, serve = _local_source(toy_roots, tmp_path, rounds_of)
    write_export(tmp_path / "local.zip", src)
    export = read_export(tmp_path / "local.zip")
    assert export.profile.zeta is None  # RBA-Local has no ranker
    assert export.profile.reward["condition"] == {"anchor_rollout": serve.ids[2], "changes": [
        {"attribute": "amplitude", "direction": -1}, {"attribute": "pace", "direction": 1}]}
    anchor, states = serve.trajectory(2), torch.as_tensor(serve.trajectory(4))
    with torch.no_grad():
        phi = model.encode(Ragged.from_numpy(anchor, np.array([0, len(anchor)])), torch.tensor([0]))
        expected = sum(model(states, model.condition(phi, torch.tensor([a]), torch.tensor([h])),
                             torch.zeros(len(states), dtype=torch.int64)) for a, h in ((0, -1), (1, 1))) / 2
    np.testing.assert_allclose(export.reward.rewards(serve.trajectory(4)), expected.numpy(), rtol=1e-5, atol=1e-6)


def test_a_local_session_satisfied_at_once_exports_no_reward(toy_roots, tmp_path):
    from rba.data.export_zip import write_export

    def rounds_of(ids):
        return [{"step": 0, "feedback": "satisfied", "rollout_before": ids[0], "rollout_after": ids[0]}], ids[0]

    src, _, _ = _local_source(toy_roots, tmp_path, rounds_of)
    write_export(tmp_path / "local.zip", src)
    export = read_export(tmp_path / "local.zip")
    assert export.reward is None and export.profile.reward is None
    assert "satisfied with its first clip" in export.profile.reward_note
    with zipfile.ZipFile(tmp_path / "local.zip") as zf:
        assert sorted(zf.namelist()) == ["README.md", "clip.mp4", "profile.json"]


def test_a_global_export_refits_the_rewards_last_layer_for_the_chosen_clip(app_env, exported, toy_roots):
    """The exported rθ is the trained one with only its last layer re-fitted for v*; it orders the library near v*
    by ζσ distance better than the trained weights; ``refit=None`` exports the trained weights (to compare)."""
    import dataclasses

    import numpy as np
    import torch

    from rba.core.artifacts import BUILDERS, load_model, weights_sha
    from rba.data.export_zip import ExportSource, build_export
    from rba.learn.common import Ragged
    from rba.learn.global_reward import LibraryScorer, RefitConfig

    export, trained = read_export(exported), load_model("toy", "global_reward", "onehot", toy_roots[1])
    card, refit = export.reward.card, export.reward.card["refit"]
    assert refit["from_weights_sha"] == trained.card["weights_sha"] and refit["library"] == "serve"
    assert card["weights_sha"] == weights_sha(export.reward.model) != trained.card["weights_sha"]
    last = f"f.{len(trained.model.f) - 1}"
    weights = export.reward.model.state_dict()
    assert {k for k, v in trained.model.state_dict().items() if not torch.equal(v, weights[k])} == {
        f"{last}.weight", f"{last}.bias"}
    assert refit["loss_after"] < refit["loss_before"]

    serve = app_env["serve"]
    data = Ragged.from_numpy(serve.states, serve.state_offsets)
    zeta = load_model("toy", "ranker", "onehot", toy_roots[1]).model.score(data)
    v_star = np.array(export.profile.reward["condition"]["zeta"])
    with torch.no_grad():
        standard = trained.model.zeta_norm(torch.as_tensor(np.vstack([zeta, v_star]), dtype=torch.float32)).numpy()
    dist = np.linalg.norm(standard[:-1] - standard[-1], axis=1)
    near = np.argsort(dist)[:40]

    def concordance(model) -> float:
        ret = LibraryScorer(model, data).returns(v_star)[near]
        i, j = np.triu_indices(len(near), 1)
        return float(np.mean((ret[i] - ret[j]) * (dist[near][j] - dist[near][i]) > 0))

    assert concordance(export.reward.model) > concordance(trained.model)

    src = ExportSource("toy", "global", "onehot", app_env["version"], "builtin", toy_roots[1], serve,
                       app_env["chosen"], [], clip=b"clip")
    _, sixty = build_export(dataclasses.replace(src, refit=RefitConfig(nearest=60)))  # the toy library has 300
    assert sixty.card["refit"]["trajectories"] == 60
    nearest_60 = BUILDERS["global_reward"](sixty.card)
    nearest_60.load_state_dict(sixty.weights)
    assert concordance(nearest_60) > concordance(trained.model)  # fitted on the 60 nearest v*, not any 60

    _, plain = build_export(dataclasses.replace(src, refit=None))
    assert "refit" not in plain.card and all(torch.equal(v, trained.model.state_dict()[k])
                                              for k, v in plain.weights.items())


def test_a_domain_that_keeps_its_trained_reward_exports_it_unless_the_source_asks(app_env, toy_roots, monkeypatch):
    """``Domain.export_refit`` False (the walker's) exports rθ's trained weights by default; a source's explicit
    ``RefitConfig`` still re-fits (the benchmark compares both)."""
    from dataclasses import replace

    import torch

    from rba.core.artifacts import load_model
    from rba.data.export_zip import DOMAIN_REFIT, ExportSource, build_export
    from rba.domains import get_domain
    from rba.learn.global_reward import RefitConfig

    assert get_domain("walker").export_refit is False and get_domain("toy").export_refit is True
    trained = load_model("toy", "global_reward", "onehot", toy_roots[1]).model.state_dict()
    src = ExportSource("toy", "global", "onehot", app_env["version"], "builtin", toy_roots[1], app_env["serve"],
                       app_env["chosen"], [], clip=b"clip")
    assert src.refit == DOMAIN_REFIT and "refit" in build_export(src)[1].card  # the toy domain re-fits
    monkeypatch.setattr(type(get_domain("toy")), "export_refit", False)
    assert src.refit_config() is None
    _, kept = build_export(src)
    assert "refit" not in kept.card and all(torch.equal(v, trained[k]) for k, v in kept.weights.items())
    _, asked = build_export(replace(src, refit=RefitConfig()))
    assert "refit" in asked.card


@pytest.mark.parametrize("version", ["0123456789ab-{reward}", "{ranker}", "{ranker}{reward}"],
                         ids=["other ranker", "no reward", "run together"])
def test_an_export_refuses_models_that_are_not_the_sessions(app_env, toy_roots, version):
    """The session's model version names each model's weights sha, dash-separated; models changed since are refused
    with the model set named, and so is a version that merely contains their shas (a substring check passed it)."""
    from rba.core.artifacts import load_model
    from rba.data.export_zip import ExportSource, build_export

    sha = {k: load_model("toy", k, "onehot", toy_roots[1]).card["weights_sha"] for k in ("ranker", "global_reward")}
    assert app_env["version"] == f"{sha['ranker']}-{sha['global_reward']}"
    version = version.format(ranker=sha["ranker"], reward=sha["global_reward"])
    src = ExportSource("toy", "global", "onehot", version, "builtin", toy_roots[1], app_env["serve"],
                       app_env["chosen"], [], clip=b"clip")
    with pytest.raises(ExportError, match=rf"model of set 'builtin' is no longer the one session model {version} "):
        build_export(src)
