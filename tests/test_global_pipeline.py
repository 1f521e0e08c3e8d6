"""The RBA-Global pipeline on the toy domain: ζσ ranks, rθ finds targets, the agent converges."""

import json

import numpy as np
import pytest
import torch

from rba.core.artifacts import ModelNotFoundError, load_model
from rba.data.library import SkillLibrary
from rba.interact import AttributeFeedback, load_context, new_agent, restore_agent
from rba.interact.bisection import quantile
from rba.interact.evaluate import evaluate
from rba.interact.global_agent import GlobalAgent


def test_ranker_orders_held_out_clips(toy_roots):
    _, _, metrics = toy_roots
    for name in ("amplitude", "pace"):
        assert metrics["ranker"][name]["pairwise_accuracy"] > 0.9, metrics
        assert metrics["ranker"][name]["kendall_tau"] > 0.8


def test_reward_argmax_lands_near_targets(toy_roots):
    _, _, metrics = toy_roots
    assert metrics["argmax_within_epsilon"]["normal"] >= 0.6, metrics  # chance is ~0.05


def test_focus_weights_favour_triplets_near_the_target():
    from rba.learn.global_reward import focus_weights

    w = focus_weights(torch.tensor([0.0, 0.3, 3.0]), 0.3)
    assert torch.isclose(w.mean(), torch.tensor(1.0))
    assert w[0] > w[1] > w[2] and torch.isclose(w[0] / w[1], torch.tensor(np.e))
    assert focus_weights(torch.tensor([1.0]), None) is None
    with pytest.raises(ValueError, match="focus must be positive"):
        focus_weights(torch.tensor([1.0]), 0.0)


def test_cards_record_held_out_numbers(toy_roots):
    _, models, metrics = toy_roots
    card = json.loads((models / "toy" / "ranker-onehot.json").read_text())
    assert card["held_out"]["amplitude"] == metrics["ranker"]["amplitude"]
    assert card["training"]["labelled_clips"] <= 200
    art = load_model("toy", "global_reward", "onehot", models)
    assert art.card["zeta_bounds"][0][0] < art.card["zeta_bounds"][1][0]


def test_missing_model_error_names_the_command(tmp_path):
    with pytest.raises(ModelNotFoundError, match="rba train toy"):
        load_model("toy", "ranker", "onehot", tmp_path)


def test_predict_checks_shapes(toy_roots):
    _, models, _ = toy_roots
    reward = load_model("toy", "global_reward", "onehot", models).model
    with pytest.raises(ValueError, match=r"states has shape \[3, 5\]; expected \[\*, 4\]"):
        reward(torch.zeros(3, 5), torch.zeros(3, 2))


def test_agent_state_roundtrips_through_json(toy_roots):
    data, models, _ = toy_roots
    ctx = load_context("toy", "global", "onehot", data, models)
    agent = new_agent("global", ctx)
    agent.first_query()
    agent.update([AttributeFeedback("amplitude", 1)])
    state = json.loads(json.dumps(agent.state_dict()))
    clone = restore_agent(state, ctx)
    assert clone.state_dict() == agent.state_dict()
    fb = [AttributeFeedback("pace", -1)]
    assert clone.update(fb) == agent.update(fb)


def test_feedback_moves_the_asked_attribute(toy_roots):
    data, models, _ = toy_roots
    ctx = load_context("toy", "global", "onehot", data, models)
    agent = GlobalAgent(ctx)
    first = ctx.serve.index_of(agent.first_query())
    nxt = ctx.serve.index_of(agent.update([AttributeFeedback("amplitude", 1)]))
    assert nxt != first
    assert ctx.serve_zeta[nxt, 0] > ctx.serve_zeta[first, 0]
    assert ctx.serve.proxies[nxt, 0] > ctx.serve.proxies[first, 0]


def test_a_push_past_the_library_leaves_the_target_at_the_beliefs_median(toy_roots):
    """Asked for more than any clip has, the agent pushes its library query further, but only for that answer:
    its target (what generation aims at) stays the belief's median, on the belief's grid."""
    data, models, _ = toy_roots
    ctx = load_context("toy", "global", "onehot", data, models)
    agent = GlobalAgent(ctx)
    agent.first_query()
    queries = []
    argmax = agent._argmax
    agent._argmax = lambda query: queries.append(query.copy()) or argmax(query)
    top = int(np.argmax(ctx.serve_zeta[:, 0]))
    for _ in range(6):  # "more amplitude" about the library's most ample clip: nothing moves that way
        agent.shown = top
        agent.update([AttributeFeedback("amplitude", 1)])
        medians = [quantile(ctx.grid(a), agent.belief(a), 0.5) for a in range(2)]
        np.testing.assert_allclose(agent.target, medians)
    assert agent.target[0] > ctx.serve_zeta[top, 0]  # the belief did move past the clip
    pushed = np.array(queries)[:, 0]
    assert pushed.max() == ctx.grid(0)[-1]  # pushed to the grid's end, never past it
    restored = GlobalAgent.from_state({**agent.state_dict(), "target": [1e3, 1e3]}, ctx)  # an old state's target
    np.testing.assert_array_equal(restored.target, agent.target)  # the answers give it


def test_agent_rejects_unknown_attribute(toy_roots):
    data, models, _ = toy_roots
    agent = new_agent("global", load_context("toy", "global", "onehot", data, models))
    agent.first_query()
    with pytest.raises(ValueError, match="unknown attribute 'speed'; valid: amplitude, pace"):
        agent.update([AttributeFeedback("speed", 1)])


def test_simulated_users_reach_targets(toy_roots):
    data, models, _ = toy_roots
    result = evaluate("toy", "global", "onehot", targets=10, seed=0, data_root=data, models_root=models)
    assert result.success_rate >= 0.8, [t.feedback_count for t in result.trials]
    assert result.avg_feedback < 15
    test = SkillLibrary.load("toy", "test", data)
    for trial in result.trials:
        assert any(np.allclose(list(trial.target.values()), row) for row in test.proxies)


def test_default_preset_takes_a_domains_ranker_steps():
    from rba.learn.ranker import RankerConfig
    from rba.learn.training import GlobalTrainConfig

    assert GlobalTrainConfig.preset("default", 3, "lane_change_image").ranker.steps == 3200
    walker = GlobalTrainConfig.preset("default", 3, "walker").ranker
    assert (walker.steps, walker.seed) == (RankerConfig().steps, 3)
    assert GlobalTrainConfig.preset("tiny", 0, "lane_change_image").ranker.steps == 200  # CI stays tiny
