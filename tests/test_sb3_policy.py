"""examples/sb3_policy: the env pays the export's reward, a tiny SB3 run saves a model that loads, and the report
measures the learned policy against the profile beside its references."""

from __future__ import annotations

import importlib.util
import json
import sys

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO, SAC

from rba.core.settings import REPO_ROOT
from rba.data.export_zip import read_export
from rba.data.library import SkillLibrary
from rba.gym import run_episode


def _example():
    spec = importlib.util.spec_from_file_location("sb3_policy_train", REPO_ROOT / "examples/sb3_policy/train.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


train = _example()


@pytest.fixture(autouse=True)
def one_torch_thread():
    """Training on one torch thread, as the example and the benchmark run (SAC's small updates on several threads of
    a busy machine take 100 times longer); the test process gets its own setting back."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def toy_exports(toy_roots, tmp_path_factory):
    """Exports of two toy serve rollouts far apart in their attributes: the profile and a wrong one."""
    data, models, _ = toy_roots
    serve = SkillLibrary.load("toy", "serve", data)
    amplitude = serve.proxies[:, 0]
    chosen, wrong = serve.ids[int(np.argmin(amplitude))], serve.ids[int(np.argmax(amplitude))]
    folder = tmp_path_factory.mktemp("exports")
    return tuple(train.export_library_rollout("toy", rid, folder / f"{rid}.zip", data_root=data, models_root=models)
                 for rid in (chosen, wrong))


def test_the_training_env_pays_the_exports_reward_and_not_another_profiles(toy_exports):
    export, wrong = (read_export(path) for path in toy_exports)
    steps = train.skill_steps(export.profile)
    env = train.training_env(export, steps)
    rng = np.random.default_rng(0)
    episode = run_episode(env, lambda obs: rng.uniform(-1, 1, 2), seed=123, params={"amplitude": 2.0, "pace": 3.0})
    assert len(episode.rewards) == steps == 24  # the toy's skill runs to the env's end
    np.testing.assert_allclose(episode.observations[0], [0, 0, 0, 1])  # the profile's start, whatever reset asked
    states = episode.states  # the toy records every observation after the reset's: step k pays rθ(its state)
    np.testing.assert_allclose(episode.rewards, export.reward.rewards(states), rtol=1e-6)
    assert not np.allclose(episode.rewards, wrong.reward.rewards(states), rtol=1e-2)


@pytest.mark.parametrize("algo", ["PPO", "SAC"])
def test_a_tiny_run_saves_a_model_that_loads_and_reports_its_distance(toy_exports, toy_roots, tmp_path, algo):
    out = tmp_path / algo
    report = train.train(toy_exports[0], algo, 256, seed=1, out=out, every=64, data_root=toy_roots[0])
    saved = json.loads((out / "report.json").read_text())
    assert saved == json.loads(json.dumps(report))
    assert report["steps"] >= 256 and report["wall_seconds"] > 0 and len(report["load_average"]) == 3
    attrs = ["amplitude", "pace"]
    for name in ("trained", "untrained", "random", "skill"):
        r = report[name]
        for a in attrs:
            assert r["in_epsilon"][a] == pytest.approx(r["distance"][a] / report["epsilon"][a])
            assert r["distance"][a] == pytest.approx(abs(r["proxies"][a] - report["profile"][a]))
    assert report["skill"]["within"] and max(report["skill"]["in_epsilon"].values()) < 0.2
    assert report["random"]["episodes"] == train.RANDOM_EPISODES
    assert [c["steps"] for c in report["curve"]] == [64, 128, 192, 256]
    assert all(set(c["in_epsilon"]) == set(attrs) and c["seconds"] <= report["wall_seconds"] for c in report["curve"])

    model = {"PPO": PPO, "SAC": SAC}[algo].load(out / "model.zip", device="cpu")
    again = train.measure(read_export(toy_exports[0]), train.act_with(model), report["episode_steps"],
                          report["epsilon"])
    assert again.proxies == pytest.approx(report["trained"]["proxies"], rel=1e-9)  # the saved policy was measured
    assert again.reward == pytest.approx(report["trained"]["reward"], rel=1e-6)


def test_bad_arguments_say_what_is_valid(capsys, tmp_path):
    with pytest.raises(SystemExit) as neither:
        train.parse_args([])
    assert neither.value.code == 2
    assert "give --export ZIP, or --domain and --rollout" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        train.parse_args(["--domain", "walker_raw", "--rollout", "serve-00001"])
    assert "one without an rba.gym env; valid: walker" in capsys.readouterr().err
    assert train.main(["--domain", "lane_change", "--rollout", "shown-00001", "--out", str(tmp_path)]) == 2
    assert "names no library: <split>-<number>" in capsys.readouterr().err


def test_the_example_runs_on_a_shipped_domain(tmp_path, capsys):
    """From a fresh clone: a lane change of the test library exported with the shipped models, a few hundred
    steps of PPO, the summary printed."""
    assert train.main(["--domain", "lane_change", "--rollout", "test-00007", "--steps", "256",
                       "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["domain"] == "lane_change" and report["steps"] >= 256
    assert report["skill"]["within"] and max(report["skill"]["in_epsilon"].values()) < 1e-6
    assert (tmp_path / "model.zip").is_file()
    assert read_export(tmp_path / "export.zip").profile.rollout_id == "test-00007"
    assert "PPO on lane_change test-00007" in capsys.readouterr().out


def test_the_benchmark_reports_steps_time_and_distance(toy_env, tmp_path):
    from tests.benchmark_scripts import load_benchmark

    rollout = SkillLibrary.load("toy", "serve").ids[3]
    bench = load_benchmark("sb3_policy")
    assert bench.main(["--runs", f"toy:{rollout}:PPO", "--steps", "128", "--every", "64",
                       "--out", str(tmp_path / "r")]) == 0
    report = json.loads((tmp_path / "r.json").read_text())
    (run,) = report["runs"]
    assert run["rollout_id"] == rollout and run["steps"] >= 128
    assert {"load_average_before", "load_average_after"} <= set(report)
    text = (tmp_path / "r.md").read_text()
    assert f"| toy {rollout} PPO | {run['steps']} |" in text and "| skill | amplitude" in text
    assert [c["steps"] for c in run["curve"]] == [64, 128] and "| 128 | " in text
    with pytest.raises(SystemExit):
        bench.parse_args(["--runs", "toy:serve-00003:A2C"])
