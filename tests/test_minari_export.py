"""Minari datasets of skill libraries: ``rba export --format minari``, read back with ``minari.load_dataset``.

Each shipped domain's serve library round-trips on a fixed subset (``SUBSET``: its first, last and two clips
in between, as tests/test_resimulate.py picks them): the whole libraries take minutes per domain (walker
and snake about 0.4 s per clip), so ``benchmarks/minari_export.py`` exports and loads them whole. The toy's
whole serve library goes through the command line.
"""

from __future__ import annotations

import hashlib

import gymnasium as gym
import minari
import numpy as np
import pytest

import rba.gym
from rba.cli import main
from rba.data.export_zip import read_export
from rba.data.library import SkillLibrary
from rba.data.minari_export import (
    STATES_ATOL,
    STATES_RTOL,
    MinariExportError,
    library_source,
    write_dataset,
)
from rba.domains import get_domain
from rba.gym import ExportedReward, env_id

SHIPPED = ("walker", "lane_change", "manipulator", "snake")
PER_DOMAIN = 4  # clips of each shipped serve library round-tripped here (the benchmark does the whole ones)


def subset(n: int) -> list[int]:
    """The fixed clips of a library of ``n``: first, last and two in between."""
    return sorted({int(i) for i in np.linspace(0, n - 1, PER_DOMAIN).round()})


def load(monkeypatch, root, dataset_id: str) -> minari.MinariDataset:
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))  # load_dataset reads its folder from here only
    return minari.load_dataset(dataset_id)


def check_round_trip(ds: minari.MinariDataset, library: SkillLibrary, indices: list[int]) -> None:
    """Every episode is its clip: rollout id, seed and params, recorded observations = the stored states, and the
    dataset's actions stepped in a fresh env from its seed and options give its observations bit for bit."""
    domain = library.domain
    env = gym.make(env_id(domain))
    d = get_domain(domain)
    assert ds.total_episodes == len(indices)
    metas = list(ds.storage.get_episode_metadata(range(len(indices))))
    for i, episode, meta in zip(indices, ds.iterate_episodes(), metas, strict=True):
        assert meta["rollout_id"] == library.ids[i] and meta["seed"] == int(library.seeds[i])
        params = {k: float(v) for k, v in meta["options"]["params"].items()}
        assert params == dict(zip(library.param_names, library.params[i].tolist(), strict=True))
        obs, actions = episode.observations, episode.actions
        assert obs.shape == (len(actions) + 1, d.state_dim) and obs.dtype == np.float64
        assert actions.shape == (len(obs) - 1, *env.action_space.shape)
        recorded = episode.infos["recorded"]
        np.testing.assert_allclose(obs[recorded].astype(np.float32), library.trajectory(i), rtol=STATES_RTOL,
                                   atol=STATES_ATOL)
        assert not episode.terminations.any() and episode.truncations[-1] and not episode.truncations[:-1].any()
        again, _ = env.reset(seed=meta["seed"], options={"params": params})
        replayed = [again] + [env.step(a)[0] for a in actions]
        np.testing.assert_array_equal(np.array(replayed), obs)


@pytest.mark.parametrize("domain", SHIPPED)
def test_a_shipped_serve_library_round_trips(domain, tmp_path, monkeypatch):
    library = SkillLibrary.load(domain, "serve")
    picked = subset(len(library))
    written = write_dataset(tmp_path, library_source(domain, "serve", indices=picked))
    assert written.dataset_id == f"rba/{domain}-serve-v0" and written.path == tmp_path / "rba" / f"{domain}-serve-v0"
    ds = load(monkeypatch, tmp_path, written.dataset_id)
    check_round_trip(ds, library, picked)
    assert all(not episode.rewards.any() for episode in ds.iterate_episodes())
    about = ds.storage.metadata["rba"]
    assert about["source"] == "library" and about["split"] == "serve" and about["domain"] == domain
    assert about["library_version"] == library.version and about["rewards"]["kind"] == "zero"
    assert ds.total_steps == written.steps and ds.spec.env_spec.id == env_id(domain)
    assert not [p for p in (tmp_path / "rba").iterdir() if p.name.startswith(".")]  # no temporary left


def test_the_command_line_exports_a_whole_library(toy_env, tmp_path, monkeypatch, capsys):
    rba.gym.register_envs()
    out = tmp_path / "datasets"
    assert main(["export", "--format", "minari", "--domain", "toy", "--split", "serve", "--out", str(out)]) == 0
    assert "wrote rba/toy-serve-v0 (300 episodes" in capsys.readouterr().out
    library = SkillLibrary.load("toy", "serve")
    check_round_trip(load(monkeypatch, out, "rba/toy-serve-v0"), library, list(range(len(library))))
    assert "rba/toy-serve-v0" in minari.list_local_datasets()
    assert main(["export", "--format", "minari", "--domain", "toy", "--split", "serve", "--out", str(out)]) == 2
    assert f"{out / 'rba' / 'toy-serve-v0'} exists already; remove it or give another --out" in capsys.readouterr().err


def test_profile_rewards_are_the_exported_reward(exported_toy, tmp_path, monkeypatch):
    export = read_export(exported_toy)
    library = SkillLibrary.load("toy", "serve", exported_toy.parent / "data")
    picked = [0, 5, 17]
    written = write_dataset(tmp_path, library_source("toy", "serve", exported_toy.parent / "data", picked),
                            profile=exported_toy)
    ds = load(monkeypatch, tmp_path, written.dataset_id)
    about = ds.storage.metadata["rba"]["rewards"]
    assert about["profile_sha256"] == hashlib.sha256(exported_toy.read_bytes()).hexdigest()
    assert about["kind"] == "global_reward" and about["profile_rollout_id"] == export.profile.rollout_id
    for i, episode in zip(picked, ds.iterate_episodes(), strict=True):
        rollout = library.rollout(i)
        assert episode.rewards.sum() == pytest.approx(export.reward.total(rollout.states), rel=1e-5)
        env = ExportedReward(exported_toy, gym.make(env_id("toy")))  # the wrapper, step by step
        policy = get_domain("toy").skill_policy(rollout.params, rollout.seed)
        obs, _ = env.reset(seed=rollout.seed, options={"params": rollout.params})
        paid = []
        for _ in episode.actions:
            obs, reward, *_ = env.step(policy(obs))
            paid.append(reward)
        # rθ is float32: the dataset's batch of states and the wrapper's one at a time round apart by its epsilon
        np.testing.assert_allclose(episode.rewards, paid, rtol=1e-6, atol=1e-6)


def test_a_profile_of_another_domain_is_refused(exported_toy, tmp_path):
    with pytest.raises(MinariExportError, match="the profile's reward is for 'toy', these clips are 'walker''s"):
        write_dataset(tmp_path, library_source("walker", "serve", indices=[0]), profile=exported_toy)
    assert not (tmp_path / "rba").exists() or not any((tmp_path / "rba").iterdir())


def test_a_clip_that_resimulates_differently_writes_nothing(toy_roots, tmp_path):
    source = library_source("toy", "serve", toy_roots[0], [0, 1])
    clip = source.clips[1]
    source.clips[1] = type(clip)(clip.rollout_id, clip.params, clip.seed, clip.states + 1e-3, clip.proxies)
    with pytest.raises(MinariExportError, match=r"toy clip serve-00001 re-simulated differently from the stored one "
                                                r"\(states differ by up to 0.001\)"):
        write_dataset(tmp_path, source)
    assert list((tmp_path / "rba").iterdir()) == []  # the half-built dataset is gone


@pytest.mark.parametrize(("argv", "message"), [
    (["--format", "minari", "--out", "x"], "--format minari exports one of: --session ID"),
    (["--format", "minari", "--split", "serve", "--out", "x"], "--split needs --domain D"),
    (["--format", "minari", "--labels", "--split", "serve", "--domain", "walker", "--out", "x"],
     "got --split --labels"),
    (["--format", "minari", "--session", "s", "--domain", "walker", "--out", "x"],
     "--session takes its domain from the session"),
    (["--format", "minari", "--domain", "walker_raw", "--split", "serve", "--out", "x"],
     "domain 'walker_raw' has no step interface (its states are not what the skill's policy reads), so it has no "
     "Minari dataset; valid: walker,"),
    (["--format", "minari", "--domain", "walker", "--split", "serve", "--out", "x", "--profile", "nope.zip"],
     "no file 'nope.zip'"),
    (["--format", "minari", "sid", "out.zip"], "--format minari takes no positional arguments"),
    (["sid", "out.zip", "--split", "serve"], "--split: only with --format minari; the zip export is `rba export "
                                             "SESSION_ID OUT.zip`"),
    (["sid"], "the zip export is `rba export SESSION_ID OUT.zip`; --format minari exports one of"),
])
def test_bad_combinations_exit_2_naming_what_is_valid(argv, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["export", *argv]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


@pytest.fixture(scope="module")
def exported_toy(toy_roots, tmp_path_factory):
    """An export zip of a toy serve clip with a global reward (its re-fit takes tens of seconds: made once), beside a
    copy of the toy data (``data/``)."""
    import shutil

    from rba.core.fileio import load_json
    from rba.data.export_zip import ExportSource, write_export

    data, models, _ = toy_roots
    root = tmp_path_factory.mktemp("profile")
    shutil.copytree(data / "toy", root / "data" / "toy")
    serve = SkillLibrary.load("toy", "serve", data)
    version = "-".join(load_json(models / "toy" / f"{kind}-onehot.json")["weights_sha"]
                       for kind in ("ranker", "global_reward"))
    rounds = [{"step": 0, "feedback": "satisfied", "rollout_before": serve.ids[5], "rollout_after": serve.ids[5]}]
    src = ExportSource("toy", "global", "onehot", version, "builtin", models, serve, serve.ids[5], rounds,
                       clip=b"\0\0\0\x20ftypisom")
    out = root / "toy.zip"
    write_export(out, src)
    return out
