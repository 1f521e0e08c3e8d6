"""ζσ re-fitted on a session's answers (rba.interact.refit, the generating agent's ``refit``) on the toy domain."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rba.cli import main
from rba.core.artifacts import load_model
from rba.generate.cma import is_generated
from rba.interact import generating_agent
from rba.interact.base import AttributeFeedback
from rba.interact.generating_agent import GeneratingGlobalAgent, GenerationContext
from rba.interact.global_agent import GlobalContext
from rba.interact.refit import fit_head, ordered_pairs, refit_heads
from rba.interact.users import parse_user
from rba.learn.common import Ragged
from tests.test_generate import TARGET, _eps, cli_context_option, gen_config_file
from tests.toy import Toy


@pytest.fixture(scope="module")
def ctx(gap_roots) -> GlobalContext:
    return GlobalContext.load("toy", "onehot", *gap_roots)


@pytest.fixture(scope="module")
def ranker(gap_roots):
    return load_model("toy", "ranker", "onehot", gap_roots[1]).model


def _gen(ctx, gap_roots, **options) -> GenerationContext:
    """A re-fitting context; from the first answer on unless ``refit_after`` is given (the toy's sessions are short)."""
    return GenerationContext.load(ctx, gap_roots[1], **{"refit": True, "refit_after": 1, **options})


def test_summed_features_and_heads_reproduce_the_rankers_scores(ctx, ranker):
    data = Ragged.from_numpy(ctx.serve.states, ctx.serve.state_offsets)
    phi, lengths = ranker.summed_features(data)
    assert phi.shape == (ranker.num_attributes, len(ctx.serve), ranker.f[-1].in_features)
    trained = ranker.trained_head()
    np.testing.assert_allclose(ranker.zeta_of(phi, lengths, *trained), ranker.score(data), atol=1e-4)
    same = ranker.with_heads(*trained)
    np.testing.assert_allclose(same.score(data), ranker.score(data), atol=1e-4)
    weight, bias = trained[0].copy(), trained[1].copy()
    weight[1] *= -1
    flipped = ranker.with_heads(weight, bias).score(data)
    assert ranker.heads is None  # a copy: the trained ranker is untouched
    np.testing.assert_allclose(flipped[:, 0], ranker.score(data)[:, 0], atol=1e-4)  # only attribute 1's head moved
    assert not np.allclose(flipped[:, 1], ranker.score(data)[:, 1])
    with pytest.raises(ValueError, match=r"weight has shape \[2, 3\]; expected \[2, "):
        ranker.with_heads(np.zeros((2, 3)), bias)


def test_only_named_opposite_directions_make_ordered_pairs():
    higher, lower = ordered_pairs([1, -1, 1, -1])  # "more" = the clip is below the target
    assert sorted(zip(higher.tolist(), lower.tolist(), strict=True)) == [(1, 0), (1, 2), (3, 0), (3, 2)]
    assert len(ordered_pairs([1, 1, 1])[0]) == 0


def test_a_fitted_head_orders_the_pairs_the_trained_one_got_wrong_and_the_pull_holds_it():
    rng = np.random.default_rng(0)
    phi, lengths = rng.normal(size=(30, 8)), np.full(30, 10.0)
    w_true = rng.normal(size=8)
    truth = phi @ w_true
    higher, lower = np.nonzero(truth[:, None] > truth[None, :] + 1.0)
    w0 = -0.1 * w_true + 0.05 * rng.normal(size=8)  # a head that orders them the wrong way round
    before = np.mean((phi @ w0)[higher] > (phi @ w0)[lower])
    w, b = fit_head(phi, lengths, higher, lower, w0, 0.0, clip=20.0)
    after = np.mean((phi @ w + lengths * b)[higher] > (phi @ w + lengths * b)[lower])
    assert before < 0.1 and after > 0.95
    held, _ = fit_head(phi, lengths, higher, lower, w0, 0.0, clip=20.0, pull=1e6)
    np.testing.assert_allclose(held, w0, atol=1e-3)


def test_an_attribute_nobody_answered_keeps_its_trained_head(ranker, ctx):
    data = Ragged.from_numpy(ctx.serve.states, ctx.serve.state_offsets)
    phi, lengths = ranker.summed_features(data)
    ids = ctx.serve.ids
    answered = [(ids[i], [(0, 1 if i % 2 else -1)]) for i in range(6)]  # attribute 0 only
    weight, bias = refit_heads(ranker, answered, lambda rid: (phi[:, ids.index(rid)], lengths[ids.index(rid)]))
    trained = ranker.trained_head()
    np.testing.assert_array_equal(weight[1], trained[0][1])
    assert bias[1] == trained[1][1] and not np.allclose(weight[0], trained[0][0])


def _session(agent: GeneratingGlobalAgent, ctx, rounds: int):
    user = parse_user("paper").build(TARGET, _eps(ctx) / 6, ctx.serve, 0)
    rid = agent.first_query()
    for _ in range(rounds):
        i = ctx.serve.index_of(rid) if not is_generated(rid) else user.add_clip(
            [agent.rollout(rid).proxies[a] for a in ctx.serve.attribute_names])
        rid = agent.update(user.respond(i))
    return user, rid


def test_answers_refit_the_agents_zeta_and_everything_it_reads_moves_with_it(ctx, gap_roots):
    agent = GeneratingGlobalAgent(_gen(ctx, gap_roots, threshold=0.0, spread=0.0))
    _session(agent, ctx, 3)
    assert len(agent.answered) == 3 and agent.ctx.ranker.heads is not None
    assert agent.inner.ctx is agent.ctx.base
    assert not np.allclose(agent.ctx.base.serve_zeta, ctx.serve_zeta)  # the library read under the new heads
    for rid, made in agent.generated.items():  # made clips too, at the ζ their states score under them
        np.testing.assert_allclose(made["zeta"], agent.ctx.ranker.score(
            Ragged.from_numpy(agent.rollout(rid).states, np.array([0, len(agent.rollout(rid).states)])))[0],
            atol=1e-4)
    first_id, asked = agent.answered[0]
    a, h = asked[0]
    z = agent._zeta_of(first_id)[a]
    assert agent.inner.answers[0] == (a, pytest.approx(z), h)  # the first answer sits where its clip is read now


def test_a_session_shorter_than_refit_after_is_the_session_without_refit(ctx, gap_roots):
    agents = [GeneratingGlobalAgent(_gen(ctx, gap_roots, threshold=0.0, spread=0.0, refit=on, refit_after=3))
              for on in (True, False)]
    (user, rid), (_, rid_off) = [_session(agent, ctx, 2) for agent in agents]
    refitting = agents[0]
    assert rid == rid_off and len(refitting.answered) == 2 and refitting.ctx.ranker.heads is None
    np.testing.assert_array_equal(refitting.ctx.base.serve_zeta, ctx.serve_zeta)
    i = ctx.serve.index_of(rid) if not is_generated(rid) else user.add_clip(
        [refitting.rollout(rid).proxies[a] for a in ctx.serve.attribute_names])
    refitting.update(user.respond(i))  # the third answer: the first fit
    assert len(refitting.answered) == 3 and refitting.ctx.ranker.heads is not None
    with pytest.raises(ValueError, match=r"refit_after counts the answers before the first re-fit \(≥ 1\), got 0"):
        _gen(ctx, gap_roots, refit_after=0)


@pytest.mark.parametrize("prior_width", [0.0, 0.05], ids=["uniform", "library-prior"])
def test_a_refitting_session_round_trips_through_json_and_continues_identically(ctx, gap_roots, prior_width):
    """With a library prior the belief depends on where the re-fitted ζσ reads the serve clips: a restored agent
    must not keep beliefs it computed before its first re-fit."""
    agent = GeneratingGlobalAgent(_gen(ctx, gap_roots, threshold=0.0, spread=0.0, prior_width=prior_width))
    user, rid = _session(agent, ctx, 3)
    agent_before = json.loads(json.dumps(agent.state_dict()))
    fresh = _gen(ctx, gap_roots, threshold=0.0, spread=0.0, prior_width=prior_width)  # a restarted process
    stored = json.loads(json.dumps(agent.state_dict()))
    restored = GeneratingGlobalAgent.from_state(stored, fresh)
    assert restored.state_dict() == agent.state_dict()
    np.testing.assert_array_equal(restored.ctx.base.serve_zeta, agent.ctx.base.serve_zeta)
    i = ctx.serve.index_of(rid) if not is_generated(rid) else user.add_clip(
        [agent.rollout(rid).proxies[a] for a in ctx.serve.attribute_names])
    np.testing.assert_array_equal(restored.inner.target, agent.inner.target)
    answer = user.respond(i)
    assert restored.update(answer) == agent.update(answer)
    assert restored.state_dict() == agent.state_dict()
    assert stored == agent_before  # the stored state it came from did not move with it


def test_a_session_restored_in_the_same_process_reads_its_fitted_heads_instead_of_fitting(ctx, gap_roots,
                                                                                          monkeypatch):
    gen = _gen(ctx, gap_roots, threshold=0.0, spread=0.0)
    agent = GeneratingGlobalAgent(gen)
    _session(agent, ctx, 2)

    def no_fit(*args, **kwargs):
        raise AssertionError("fitted again")

    monkeypatch.setattr(generating_agent, "refit_heads", no_fit)
    restored = GeneratingGlobalAgent.from_state(json.loads(json.dumps(agent.state_dict())), gen)
    np.testing.assert_array_equal(restored.ctx.base.serve_zeta, agent.ctx.base.serve_zeta)


def test_refit_is_the_domains_unless_asked_and_not_with_a_surface(ctx, gap_roots, monkeypatch):
    assert GenerationContext.load(ctx, gap_roots[1]).refit is False  # the toy's default
    monkeypatch.setattr(Toy, "session_refit", True)
    assert GenerationContext.load(ctx, gap_roots[1]).refit is True
    agent = GeneratingGlobalAgent(GenerationContext.load(ctx, gap_roots[1], refit=False))
    agent.first_query()
    agent.update([AttributeFeedback("amplitude", 1)])
    assert agent.answered == [] and agent.ctx.ranker.heads is None
    with pytest.raises(ValueError, match="use one"):
        GenerationContext.load(ctx, gap_roots[1], surface=8)


def test_cli_session_refit_setting(gap_roots, monkeypatch, capsys, tmp_path):
    assert cli_context_option(gap_roots, monkeypatch, tmp_path, {"session_refit": True}, "refit") == [True, False]
    assert cli_context_option(gap_roots, monkeypatch, tmp_path, {"session_refit": False}, "refit") == [False, False]
    capsys.readouterr()
    both = gen_config_file(tmp_path, {"session_refit": True, "zeta_surface": 8})
    assert main(["eval", "--domain", "toy", "--targets", "1", "--gen-config", str(both)]) == 2
    assert "a session's re-fit reads ζσ of each clip's states" in capsys.readouterr().err
