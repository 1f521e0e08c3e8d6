"""RBA-Local on the toy domain: labels, the model, the agent, evaluation and the CLI."""

import json

import numpy as np
import pytest
import torch

from rba.core.artifacts import load_model
from rba.data.labels import LocalLabelConfig, local_pairs, validate_local_records
from rba.data.library import SkillLibrary
from rba.domains import get_domain
from rba.interact import AttributeFeedback, load_context, new_agent, restore_agent
from rba.interact.evaluate import evaluate
from rba.learn.local_reward import LocalRewardConfig
from rba.learn.training import LocalTrainConfig, train_local

TINY = LocalTrainConfig(LocalLabelConfig(), LocalRewardConfig(steps=150, hidden=64, lstm_hidden=32))


@pytest.fixture(scope="module")
def local_roots(toy_roots, tmp_path_factory):
    """(data_root, models_root, metrics) with a tiny one-hot local reward trained on the toy libraries."""
    data, _, _ = toy_roots
    models = tmp_path_factory.mktemp("local_models")
    metrics = train_local("toy", "onehot", TINY, data_root=data, models_root=models)
    return data, models, metrics


@pytest.fixture(scope="module")
def ctx(local_roots):
    data, models, _ = local_roots
    return load_context("toy", "local", "onehot", data, models)


def test_pairs_are_minimal_changes_of_train_clips(toy_roots):
    data, _, _ = toy_roots
    train = SkillLibrary.load("toy", "train", data)
    domain = get_domain("toy")
    eps = domain.epsilons(SkillLibrary.load("toy", "serve", data).proxies)
    cfg = LocalLabelConfig(per_attribute={"pace": (0.6, 1.2)})
    pairs = local_pairs(train.proxies, eps, domain.attribute_names, cfg)
    assert 0 < len(pairs) <= 200
    delta = (train.proxies[pairs.target] - train.proxies[pairs.anchor]) / eps
    for row, (a, h) in enumerate(zip(pairs.attr, pairs.direction, strict=True)):
        lo, hi = cfg.band(domain.attribute_names[a])
        assert lo <= h * delta[row, a] <= hi
        assert np.abs(np.delete(delta[row], a)).max() <= cfg.keep
    # every (attribute, direction) is asked about equally often
    counts = np.unique(pairs.attr * 2 + (pairs.direction > 0), return_counts=True)[1]
    assert len(counts) == 4 and counts.min() >= 0.6 * counts.max()
    again = local_pairs(train.proxies, eps, domain.attribute_names, cfg)
    assert np.array_equal(pairs.target, again.target)  # seeded


def test_uploaded_pairs_are_validated():
    ids = ["train-00000", "train-00001"]
    names = ("amplitude", "pace")
    ok = validate_local_records([{"anchor": ids[0], "target": ids[1], "attribute": "pace", "direction": -1}],
                                ids, names)
    assert ok.attr.tolist() == [1] and ok.direction.tolist() == [-1]
    bad = [({"anchor": "x", "target": ids[1], "attribute": "pace", "direction": 1}, "unknown rollout id 'x'"),
           ({"anchor": ids[0], "target": ids[1], "attribute": "speed", "direction": 1}, "unknown attribute 'speed'"),
           ({"anchor": ids[0], "target": ids[1], "attribute": "pace", "direction": 2}, "direction must be"),
           ({"anchor": ids[0], "target": ids[0], "attribute": "pace", "direction": 1}, "the same rollout"),
           ({"anchor": ids[0]}, "missing attribute, direction, target")]
    for record, message in bad:
        with pytest.raises(ValueError, match=message):
            validate_local_records([record], ids, names)


def test_model_beats_chance_on_held_out_pairs(local_roots):
    _, _, metrics = local_roots
    assert metrics["local_reward"]["pairs"] >= 10
    assert metrics["local_reward"]["target_vs_negative"] >= 0.85, metrics  # chance 0.5
    assert metrics["local_reward"]["target_vs_anchor"] >= 0.8, metrics
    assert metrics["argmax_over_serve"]["useful_edit_rate"] >= 0.6, metrics  # chance well below 0.1


def test_card_and_weights_load(local_roots):
    _, models, metrics = local_roots
    art = load_model("toy", "local_reward", "onehot", models)
    card = art.card
    assert card["kind"] == "local_reward" and card["training"]["labelled_pairs"] <= 200
    assert card["held_out"]["target_vs_negative"] == metrics["local_reward"]["target_vs_negative"]
    assert card["near_copy_radius"] > 0
    with pytest.raises(ValueError, match=r"states has shape \[3, 5\]; expected \[\*, 4\]"):
        art.model(torch.zeros(3, 5), torch.zeros(3, art.model.cond_dim))


def test_feedback_moves_the_asked_attribute_and_keeps_the_other(ctx):
    agent = new_agent("local", ctx)
    eps = get_domain("toy").epsilons(ctx.serve.proxies)
    first = ctx.serve.index_of(agent.first_query())
    nxt = ctx.serve.index_of(agent.update([AttributeFeedback("amplitude", 1)]))
    delta = (ctx.serve.proxies[nxt] - ctx.serve.proxies[first]) / eps
    assert 0 < delta[0] <= 2.5 and abs(delta[1]) <= 1.0, delta


def test_several_attributes_in_one_round_are_chained(ctx):
    agent = new_agent("local", ctx)
    eps = get_domain("toy").epsilons(ctx.serve.proxies)
    first = ctx.serve.index_of(agent.first_query())
    nxt = ctx.serve.index_of(agent.update([AttributeFeedback("amplitude", -1), AttributeFeedback("pace", 1)]))
    delta = (ctx.serve.proxies[nxt] - ctx.serve.proxies[first]) / eps
    assert delta[0] < 0 and delta[1] > 0, delta


def test_never_returns_the_anchor_or_a_near_copy(ctx):
    agent = new_agent("local", ctx)
    shown = ctx.serve.index_of(agent.first_query())
    for step in range(12):
        fb = [AttributeFeedback(("amplitude", "pace")[step % 2], 1 if step % 4 < 2 else -1)]
        nxt = ctx.serve.index_of(agent.update(fb))
        assert nxt != shown
        dist = ctx.scorer.phi_distances(ctx.scorer.phi[shown])[nxt]
        assert dist >= ctx.near_copy_radius
        assert nxt not in agent.seen
        shown = nxt


def test_state_roundtrips_through_json(ctx):
    agent = new_agent("local", ctx)
    agent.first_query()
    agent.update([AttributeFeedback("amplitude", 1)])
    clone = restore_agent(json.loads(json.dumps(agent.state_dict())), ctx)
    assert clone.state_dict() == agent.state_dict()
    for fb in ([AttributeFeedback("pace", -1)], [AttributeFeedback("amplitude", -1), AttributeFeedback("pace", 1)]):
        assert clone.update(fb) == agent.update(fb)


def test_bad_input_gives_clear_errors(ctx):
    agent = new_agent("local", ctx)
    with pytest.raises(RuntimeError, match="before first_query"):
        agent.update([AttributeFeedback("pace", 1)])
    agent.first_query()
    with pytest.raises(ValueError, match="unknown attribute 'speed'; valid: amplitude, pace"):
        agent.update([AttributeFeedback("speed", 1)])
    with pytest.raises(ValueError, match="unknown method 'lokal'; valid: global, local, pbrl"):
        new_agent("lokal", ctx)


def test_simulated_users_reach_targets(local_roots):
    data, models, _ = local_roots
    result = evaluate("toy", "local", "onehot", targets=10, seed=0, data_root=data, models_root=models)
    assert result.success_rate >= 0.9, [t.feedback_count for t in result.trials]
    assert result.avg_feedback < 8


def test_noisy_users_are_seeded_and_still_succeed(local_roots, ctx):
    data, models, _ = local_roots
    runs = [evaluate("toy", "local", "onehot", targets=6, seed=3, user="mistake:0.2", data_root=data,
                     models_root=models, context=ctx) for _ in range(2)]
    assert [t.shown_ids for t in runs[0].trials] == [t.shown_ids for t in runs[1].trials]
    assert runs[0].success_rate >= 0.8


def test_cli_trains_and_evaluates_local(toy_roots, tmp_path, monkeypatch, capsys):
    from rba.cli import main

    data, _, _ = toy_roots
    monkeypatch.setenv("RBA_DATA_DIR", str(data))
    monkeypatch.setenv("RBA_MODELS_DIR", str(tmp_path / "models"))
    assert main(["train", "toy", "--method", "local", "--rep", "onehot", "--preset", "tiny"]) == 0
    assert '"method": "local"' in capsys.readouterr().out
    assert (tmp_path / "models" / "toy" / "local_reward-onehot.json").exists()
    out = tmp_path / "r.json"
    assert main(["eval", "--domain", "toy", "--method", "local", "--targets", "3", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["method"] == "local" and len(result["trials"]) == 3
    assert "| toy | local | onehot | normal |" in capsys.readouterr().out
    assert main(["eval", "--domain", "toy", "--method", "local", "--rep", "language", "--targets", "1"]) == 2
    assert "no local_reward model (language)" in capsys.readouterr().err
