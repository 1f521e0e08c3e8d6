"""The PbRL baseline on the toy domain: the ensemble, its query rule, the agent and evaluation."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from rba.domains import get_domain
from rba.interact import Preference, load_context, new_agent, restore_agent
from rba.interact.evaluate import evaluate, run_preference_trial
from rba.interact.pbrl_agent import PbRLContext, stride_states
from rba.interact.users import PreferenceTeacher
from rba.learn.pbrl import PbRLConfig, RewardEnsemble, choose_pair, fit_preferences, returns


@pytest.fixture(scope="module")
def ctx(toy_roots):
    data, models, _ = toy_roots
    return load_context("toy", "pbrl", "onehot", data, models)


def make_teacher(ctx, row=0, noise=0.0):
    target = ctx.serve.proxies[row] + np.array([0.05, -0.05])
    eps = get_domain("toy").epsilons(ctx.serve.proxies)
    return PreferenceTeacher(target, eps, ctx.attribute_names, ctx.serve.proxies, noise)


def test_ensemble_weights_roundtrip_and_check_size():
    a = RewardEnsemble(4, 3, 16, 3, generator=torch.Generator().manual_seed(1))
    b = RewardEnsemble(4, 3, 16, 3).load_base64(a.to_base64())
    x = torch.randn(7, 4)
    assert torch.equal(a(x), b(x)) and a(x).shape == (3, 7)
    with pytest.raises(ValueError, match="this architecture needs"):
        RewardEnsemble(4, 3, 8, 3).load_base64(a.to_base64())


def test_stride_keeps_every_nth_state_of_each_trajectory():
    states = np.arange(10, dtype=np.float32)[:, None]
    kept, offsets = stride_states(states, np.array([0, 3, 10]), 2)
    assert kept[:, 0].tolist() == [0, 2, 3, 5, 7, 9] and offsets.tolist() == [0, 2, 6]


def test_reward_learned_from_teacher_labels_beats_chance_on_held_out_pairs(ctx):
    teacher = make_teacher(ctx, row=5)
    rng = np.random.default_rng(0)
    n = len(ctx.serve)
    pairs = rng.integers(n, size=(160, 2))
    labels = np.array([[a, b, teacher.prefer(a, b)] for a, b in pairs], dtype=np.float64)
    train, held = labels[:100], labels[100:]
    cfg = PbRLConfig(steps_per_label=200)
    model = RewardEnsemble(ctx.states.shape[1], cfg.members, cfg.hidden, cfg.layers,
                           generator=torch.Generator().manual_seed(0))
    fit_preferences(model, ctx.states, ctx.offsets, train, cfg, torch.Generator().manual_seed(0))
    with torch.no_grad():
        ret = returns(model, ctx.states, ctx.seg, n).mean(0).numpy()
    decided = held[held[:, 2] != 0.5]
    predicted = ret[decided[:, 0].astype(int)] > ret[decided[:, 1].astype(int)]
    assert np.mean(predicted == (decided[:, 2] == 1.0)) >= 0.75  # chance 0.5


def test_pairs_come_from_the_best_candidates_and_are_never_repeated():
    ret = np.array([[5.0, 4.0, 3.0, -9.0], [5.0, 1.0, 3.0, -9.0], [5.0, 7.0, 3.0, -9.0]])
    cfg = PbRLConfig(candidates=3)
    rng = np.random.default_rng(0)
    a, b = choose_pair(ret, cfg, set(), rng)
    assert {a, b} == {0, 1}  # members disagree most about 0 vs 1; rollout 3 is not a candidate
    assert {*choose_pair(ret, cfg, {(1, 0)}, rng)} != {0, 1}
    with pytest.raises(ValueError, match="unknown query rule 'greedy'"):
        PbRLConfig(query="greedy")


def test_state_roundtrips_through_json_and_continues_identically(ctx):
    teacher = make_teacher(ctx, row=9)
    agent = new_agent("pbrl", ctx)
    agent.first_query()

    def step(ag):
        a, b = ag.query_pair()
        label = teacher.prefer(ctx.serve.index_of(a), ctx.serve.index_of(b))
        return (a, b), ag.update(Preference(a if label == 1.0 else b if label == 0.0 else None))

    for _ in range(3):
        step(agent)
    agent.query_pair()  # a pending question survives the round trip too
    clone = restore_agent(json.loads(json.dumps(agent.state_dict())), ctx)
    assert clone.state_dict() == agent.state_dict()
    for _ in range(3):
        assert step(clone) == step(agent)
    assert clone.state_dict() == agent.state_dict()


def test_bad_answers_give_clear_errors(ctx):
    agent = new_agent("pbrl", ctx)
    with pytest.raises(RuntimeError, match="before first_query"):
        agent.update(Preference(None))
    agent.first_query()
    with pytest.raises(ValueError, match="no A/B question is pending"):
        agent.update(Preference(None))
    agent.query_pair()
    with pytest.raises(ValueError, match="is not in the pending pair"):
        agent.update(Preference("serve-99999"))
    with pytest.raises(ValueError, match="this agent takes A/B answers"):
        agent.update([])
    with pytest.raises(ValueError, match="unknown representation 'braille'"):
        PbRLContext.load("toy", "braille")


def test_teacher_driven_trials_succeed(toy_roots, ctx):
    data, models, _ = toy_roots
    result = evaluate("toy", "pbrl", targets=6, seed=1, data_root=data, models_root=models, context=ctx)
    assert result.success_rate >= 0.8, [t.feedback_count for t in result.trials]


def test_noisy_teacher_path_is_seeded(ctx):
    def run():
        teacher = make_teacher(ctx, row=3, noise=0.2)
        return run_preference_trial(new_agent("pbrl", ctx), teacher, ctx.serve, max_feedback=15).shown_ids

    assert run() == run()


def test_cli_evaluates_pbrl_and_all_methods(toy_roots, tmp_path, monkeypatch, capsys):
    from rba.cli import main
    from rba.core import methods
    from rba.learn.training import LocalTrainConfig, train_local

    data, models, _ = toy_roots
    local_models = tmp_path / "models"
    for kind in ("ranker", "global_reward"):  # global models from the shared fixture, plus a tiny local one
        for suffix in (".pt", ".json"):
            src = models / "toy" / f"{kind}-onehot{suffix}"
            (local_models / "toy").mkdir(parents=True, exist_ok=True)
            (local_models / "toy" / src.name).write_bytes(src.read_bytes())
    from rba.learn.local_reward import LocalRewardConfig

    train_local("toy", "onehot", LocalTrainConfig(reward=LocalRewardConfig(steps=60, hidden=32, lstm_hidden=16)),
                data_root=data, models_root=local_models)
    monkeypatch.setenv("RBA_DATA_DIR", str(data))
    monkeypatch.setenv("RBA_MODELS_DIR", str(local_models))
    assert main(["eval", "--domain", "toy", "--method", "pbrl", "--targets", "2"]) == 0
    assert "| toy | pbrl | onehot | normal |" in capsys.readouterr().out
    real = methods.get_method  # one-hot only: no language models were trained
    monkeypatch.setattr(methods, "get_method", lambda name: replace(real(name), reps=real(name).reps[:1]))
    out = tmp_path / "all.json"
    assert main(["eval", "--domain", "toy", "--all-methods", "--targets", "2", "--json", str(out)]) == 0
    table = capsys.readouterr().out
    every = ["global", "local", "pbrl", "random", "oracle"]  # the reference rows too
    assert [r["method"] for r in json.loads(out.read_text())] == every
    assert all(f"| toy | {m} | onehot |" in table for m in every)
