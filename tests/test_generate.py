"""Behaviours beyond the library (rba.generate.cma, rba.interact.generating_agent) on the toy domain.

The toy serve library gets a gap: no clip within ε of a target inside it. RBA-Global over the library
alone cannot succeed there; with generation it makes a clip that does, seeded and deterministically.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import rba.interact.evaluate as evaluate_module
from rba.cli import main
from rba.compute import SimJob
from rba.domains import ParamSpace, domain_target, get_domain
from rba.generate.cma import (
    SearchConfig,
    ZetaDistance,
    _out_of_time,
    _simulate_until,
    generated_id,
    in_process,
    is_generated,
    replay,
    search,
)
from rba.generate.config import GenerationConfig
from rba.interact import generating_agent, global_agent
from rba.interact.base import AttributeFeedback
from rba.interact.bisection import posterior, quantile
from rba.interact.evaluate import beyond_targets, evaluate, simulate
from rba.interact.generating_agent import (
    POOL_KEEP,
    RETRY_AFTER,
    GeneratingGlobalAgent,
    GenerationContext,
    generating_agents,
)
from rba.interact.global_agent import GlobalAgent, GlobalContext
from rba.interact.users import parse_user
from tests.conftest import serve_subset_roots
from tests.fakes import recording_simulator
from tests.toy import Toy

TARGET = np.array([0.7, 2.4])  # amplitude, pace: inside the gap, away from where the first query lands
BUDGET = 30  # attribute feedbacks a trial may use


@pytest.fixture(scope="module")
def ctx(gap_roots) -> GlobalContext:
    return GlobalContext.load("toy", "onehot", *gap_roots)


def _gen(ctx, gap_roots, **options) -> GenerationContext:
    return GenerationContext.load(ctx, gap_roots[1], **options)


def _eps(ctx) -> np.ndarray:
    return get_domain("toy").epsilons(ctx.serve.proxies, "normal")


def test_the_library_lacks_the_target_and_library_only_fails(ctx):
    eps = _eps(ctx)
    assert not (np.abs(ctx.serve.proxies - TARGET) <= eps).all(1).any()
    trial = simulate(GlobalAgent(ctx), TARGET, eps, ctx.serve, seed=0, max_feedback=BUDGET)
    assert not trial.success and trial.feedback_count >= BUDGET


def test_generation_reaches_the_target_the_library_lacks(ctx, gap_roots):
    agent = GeneratingGlobalAgent(_gen(ctx, gap_roots))
    trial = simulate(agent, TARGET, _eps(ctx), ctx.serve, seed=0, max_feedback=BUDGET)
    assert trial.success and trial.feedback_count < BUDGET
    assert is_generated(trial.shown_ids[-1]) and trial.shown_ids[-1] in agent.generated
    made = agent.rollout(trial.shown_ids[-1])
    assert trial.shown[-1] == made.proxies  # the user judged the generated clip's own measured proxies
    assert all(np.abs(np.array([made.proxies["amplitude"], made.proxies["pace"]]) - TARGET) <= _eps(ctx))
    again = simulate(GeneratingGlobalAgent(_gen(ctx, gap_roots)), TARGET, _eps(ctx), ctx.serve, seed=0,
                     max_feedback=BUDGET)
    assert again.shown_ids == trial.shown_ids and again.shown == trial.shown  # seeded: the same every time


def test_a_generated_id_replays_to_identical_states(ctx, gap_roots):
    progress: list[tuple[int, int]] = []
    start = dict(zip(ctx.serve.param_names, map(float, ctx.serve.params[0]), strict=True))
    dist = _gen(ctx, gap_roots).distance(ctx.serve_zeta[0] + 0.1)
    found = search("toy", [start], dist, config=SearchConfig(budget=16, popsize=8), on_progress=
                   lambda k, n: progress.append((k, n)))
    assert progress == [(1, 2), (2, 2)] and found.simulations == 16
    ranked = [found.rollout, *found.runners_up]  # every finished candidate, best first, each with its own id
    assert len(ranked) == 16 and len({x.id for x in ranked}) == 16 and all(is_generated(x.id) for x in ranked)
    assert np.all(np.diff(dist(ranked)) >= 0) and dist([found.rollout])[0] == found.objective
    r = found.rollout
    assert r.id == generated_id("toy", r.params, r.seed) and is_generated(r.id)
    again = replay("toy", json.loads(json.dumps(r.params)), r.seed)
    assert again.id == r.id
    np.testing.assert_array_equal(again.states, r.states)
    np.testing.assert_array_equal(again.replay, r.replay)
    assert generated_id("toy", {**r.params, "pace": r.params["pace"] + 1e-12}, r.seed) != r.id


def test_a_candidate_scored_nan_is_never_the_best(ctx, gap_roots):
    """An objective that gives NaN for a candidate (a reward on states it never saw) counts it as failed: sorted
    among the others NaN would put any of them first, with another candidate's objective reported."""
    start = dict(zip(ctx.serve.param_names, map(float, ctx.serve.params[0]), strict=True))
    dist = _gen(ctx, gap_roots).distance(ctx.serve_zeta[0] + 0.1)
    scored: list[float] = []

    def every_third_nan(rollouts):
        f = dist(rollouts)
        f[:: 3] = np.nan
        scored.extend(f)
        return f

    found = search("toy", [start], every_third_nan, config=SearchConfig(budget=16, popsize=8))
    ranked = [found.rollout, *found.runners_up]
    assert len(ranked) == np.isfinite(scored).sum() == 10  # the NaN-scored candidates are dropped
    assert found.objective == np.nanmin(scored) == dist([found.rollout])[0]
    assert np.all(np.diff(dist(ranked)) >= 0)


def test_the_time_bound_predicts_the_next_generation_from_the_mean_of_those_before():
    assert not _out_of_time(1.0, 2, 1.6) and _out_of_time(1.0, 2, 1.4)  # two took 1 s: a third ends at 1.5 s
    assert not _out_of_time(9.0, 1, None)  # no bound: the budget alone
    for bad in (0.0, -1.0, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="a search's time bound must be a number of seconds > 0"):
            SearchConfig(seconds=bad)


def test_a_search_bounded_in_time_stops_before_a_generation_that_would_end_late(ctx, gap_roots):
    """``SearchConfig.seconds``: the app's searches end about when promised, whatever the budget."""
    start = dict(zip(ctx.serve.param_names, map(float, ctx.serve.params[0]), strict=True))
    dist = _gen(ctx, gap_roots).distance(ctx.serve_zeta[0] + 0.1)

    def slow(jobs):  # a generation takes ≥ 0.3 s: a second one would end after 0.5 s
        time.sleep(0.3)
        return in_process(jobs)

    bounded = search("toy", [start], dist, slow, SearchConfig(budget=32, popsize=8, seconds=0.5))
    assert bounded.generations == 1 and bounded.simulations == 8 and bounded.rollout is not None
    unbounded = search("toy", [start], dist, slow, SearchConfig(budget=32, popsize=8))
    assert unbounded.generations == 4 and unbounded.simulations == 32


def test_a_generation_running_past_the_bound_ends_with_what_was_simulated_by_then(ctx, gap_roots):
    """One slow generation cannot hold the clip: the search shows the best candidate that arrived in time
    and does not start one that would end late (``_simulate_until``); without a bound every candidate is
    simulated."""
    start = dict(zip(ctx.serve.param_names, map(float, ctx.serve.params[0]), strict=True))
    dist = _gen(ctx, gap_roots).distance(ctx.serve_zeta[0] + 0.1)
    started: list[int] = []

    def slow(jobs):  # each candidate takes 0.1 s, one after another: 8 take 0.8 s
        for i, rollout in enumerate(in_process(jobs)):
            started.append(i)
            time.sleep(0.1)
            yield rollout

    bounded = search("toy", [start], dist, slow, SearchConfig(budget=32, popsize=8, seconds=0.25))
    # at 0.2 s a third would end at 0.3 s, after the bound (before: 3 or 4 simulated, up to 0.4 s)
    assert bounded.generations == 1 and 1 <= bounded.simulations <= 2 and bounded.rollout is not None
    assert len(started) == bounded.simulations  # the stream was closed: the rest were never simulated
    assert bounded.seconds < 0.25 + 0.1
    started.clear()
    unbounded = search("toy", [start], dist, slow, SearchConfig(budget=16, popsize=8))
    assert unbounded.simulations == len(started) == 16


def test_a_search_hands_over_no_job_that_would_end_after_its_deadline(ctx, gap_roots):
    """A backend takes the next job as soon as a worker is free, before the search has seen the rollout that freed
    it, and runs what it took to the end (``LocalCompute``): once a candidate succeeded, the search gives it no job
    that would end after the deadline if it took as long as those before, so nothing outlives the search."""
    start = dict(zip(ctx.serve.param_names, map(float, ctx.serve.params[0]), strict=True))
    jobs = [SimJob(domain_target("toy"), start, seed=i) for i in range(8)]
    taken: list[SimJob] = []

    def take(stream) -> SimJob | None:
        job = next(stream, None)
        if job is not None:
            taken.append(job)
        return job

    def one_worker(stream):  # each job takes 0.1 s; the freed worker takes the next before handing this one's over
        stream = iter(stream)
        job = take(stream)
        while job is not None:
            time.sleep(0.1)
            (rollout,) = in_process([job])
            job = take(stream)
            yield rollout

    took: list[float] = []
    got = _simulate_until(one_worker, jobs, time.perf_counter() + 0.25, took)
    # at 0.1 s no rollout was seen (the 2nd is taken); at 0.2 s a 3rd would end at 0.3 s. Before: 4 taken, 3 shown
    assert len(got) == len(taken) == len(took) == 2
    assert all(t > 0.09 for t in took)  # from hand-over to arrival
    taken.clear()
    assert len(_simulate_until(one_worker, jobs, math.inf, [])) == len(taken) == 8


def test_fixed_parameters_keep_the_start_clips_value(ctx, gap_roots, monkeypatch):
    monkeypatch.setattr(Toy, "param_space",
                        lambda self: ParamSpace.box({"amplitude": (0.2, 2.0), "pace": (0.5, 3.0)}, frozenset({"pace"})))
    start = {"amplitude": 0.5, "pace": 1.234}
    found = search("toy", [start], _gen(ctx, gap_roots).distance(np.zeros(2)), config=SearchConfig(budget=16))
    assert found.rollout.params["pace"] == 1.234 and found.rollout.params["amplitude"] != 0.5



def _seeds_simulated(dist: ZetaDistance, monkeypatch, noisy: bool | None, vary: bool | None) -> list[int]:
    """The seeds a 16-candidate toy search simulates, with the toy's skill ``noisy`` (None: as declared) and the
    config's ``vary_seed``."""
    if noisy is not None:
        monkeypatch.setattr(Toy, "noisy_skill", noisy)
    jobs: list = []
    config = SearchConfig(budget=16, sim_seed=7, vary_seed=vary)
    search("toy", [{"amplitude": 0.5, "pace": 1.2}], dist, recording_simulator(jobs), config)
    return [j.seed for j in jobs]


def test_a_clip_made_with_a_seed_of_its_own_replays_from_that_seed(ctx, gap_roots, monkeypatch):
    monkeypatch.setattr(Toy, "noisy_skill", True)
    start = dict(zip(ctx.serve.param_names, map(float, ctx.serve.params[0]), strict=True))
    dist = _gen(ctx, gap_roots).distance(ctx.serve_zeta[0] + 0.1)
    r = search("toy", [start], dist, config=SearchConfig(budget=16, sim_seed=100)).rollout
    assert 100 <= r.seed < 116 and r.id == generated_id("toy", r.params, r.seed)
    again = replay("toy", r.params, r.seed)
    assert again.id == r.id
    np.testing.assert_array_equal(again.states, r.states)
    assert not np.array_equal(replay("toy", r.params, r.seed + 1).states, r.states)  # the seed is part of the clip


def test_each_domain_generates_as_chosen_on_val():
    """``Domain.generate_spread`` (docs/decisions/0003: the walker and the manipulator search sooner),
    ``Domain.zeta_noise`` (docs/decisions/0006: the soft step; the manipulator's chosen with its spread) and
    ``Domain.session_refit``."""
    names = ("walker", "manipulator", "snake", "lane_change")
    assert {d: get_domain(d).generate_spread for d in names} == {"walker": 0.5, "manipulator": 0.5, "snake": 1.0,
                                                                 "lane_change": 1.0}
    assert {d: get_domain(d).zeta_noise for d in names} == {"walker": 0.04, "manipulator": 0.06, "snake": 0.03,
                                                            "lane_change": 0.0}
    # docs/decisions/0011: the snake's val answers fell by 41 %, the manipulator's rose
    assert [d for d in names if get_domain(d).session_refit] == ["snake"]
    # docs/decisions/0010: the manipulator's val answers fell by 7.5 %, the snake's rose
    assert {d: get_domain(d).belief_prior for d in names} == {"walker": 0.0, "manipulator": 0.05, "snake": 0.0,
                                                              "lane_change": 0.0}


def test_a_noisy_skills_candidates_each_get_a_seed_of_their_own(ctx, gap_roots, monkeypatch):
    dist = _gen(ctx, gap_roots).distance(np.zeros(2))
    assert not get_domain("toy").noisy_skill and get_domain("manipulator").noisy_skill
    assert _seeds_simulated(dist, monkeypatch, None, None) == [7] * 16  # candidates differ in parameters only
    assert _seeds_simulated(dist, monkeypatch, True, None) == list(range(7, 23))  # the domain's choice ...
    assert _seeds_simulated(dist, monkeypatch, True, False) == [7] * 16  # ... unless the search's config says
    assert _seeds_simulated(dist, monkeypatch, False, True) == list(range(7, 23))


def test_cli_noisy_skill_setting(gap_roots, monkeypatch, capsys, tmp_path):
    assert cli_context_option(gap_roots, monkeypatch, tmp_path, {"noisy_skill": True}, "config") == [
        SearchConfig(budget=8, vary_seed=True), SearchConfig(budget=8, vary_seed=Toy.noisy_skill)]  # the domain's
    cli_refuses(capsys, tmp_path, "noisy_skill", ("each", 1), "true or false")


def test_state_round_trips_through_json_and_continues_identically(ctx, gap_roots):
    agent = GeneratingGlobalAgent(_gen(ctx, gap_roots, threshold=0.0, spread=0.0))  # generate at every round
    user = parse_user("paper").build(TARGET, _eps(ctx) / 6, ctx.serve, 0)
    rid = agent.first_query()
    for _ in range(2):
        i = ctx.serve.index_of(rid) if not is_generated(rid) else user.add_clip(
            [agent.rollout(rid).proxies[a] for a in ctx.serve.attribute_names])
        rid = agent.update(user.respond(i))
    assert is_generated(rid) and agent.showing == rid
    fresh = _gen(ctx, gap_roots, threshold=0.0, spread=0.0)  # a restarted process: nothing in its store
    restored = GeneratingGlobalAgent.from_state(json.loads(json.dumps(agent.state_dict())), fresh)
    assert restored.state_dict() == agent.state_dict()
    np.testing.assert_array_equal(restored.rollout(rid).states, agent.rollout(rid).states)  # re-simulated
    answer = user.respond(user.add_clip([agent.rollout(rid).proxies[a] for a in ctx.serve.attribute_names]))
    assert restored.update(answer) == agent.update(answer)
    assert restored.state_dict() == agent.state_dict()  # a function of the answers: no wall-clock time in it
    assert len(agent.seconds) == len(agent.searches) > len(restored.seconds)  # timings stay with the object


def test_a_search_that_fell_short_is_not_run_again_for_a_target_near_its_own(ctx, gap_roots):
    agent = GeneratingGlobalAgent(_gen(ctx, gap_roots, threshold=1e-9, spread=0.0))  # no search ends this close
    agent.first_query()
    (first,) = agent.searches
    assert first["reached"] > 1e-9 and first["target"] == agent.inner.target.tolist()
    pooled = set(agent.pool)  # the search's runners-up
    assert 0 < len(pooled) <= POOL_KEEP
    # the same target: no second search; the nearest runner-up, nearer than the library's clip, is shown
    assert agent._choose(None, []) in pooled and len(agent.searches) == 1
    agent.inner.target = agent.inner.target + 0.5  # a target farther than the threshold: searched
    agent._choose(None, [])
    assert len(agent.searches) == 2
    restored = GeneratingGlobalAgent.from_state(json.loads(json.dumps(agent.state_dict())), agent.ctx)
    restored._choose(None, [])  # the failures are in the state: a restored agent skips too
    assert len(restored.searches) == 2
    restored.inner.rejected += [0] * (RETRY_AFTER - 1)
    restored._choose(None, [])
    assert len(restored.searches) == 2  # RETRY_AFTER - 1 rounds later: still skipped
    restored.inner.rejected.append(0)
    restored._choose(None, [])
    assert len(restored.searches) == 3  # RETRY_AFTER rounds later: searched again (another seed, other starts)


def test_a_searchs_runners_up_are_shown_later_without_a_search(ctx, gap_roots):
    agent = GeneratingGlobalAgent(_gen(ctx, gap_roots, threshold=1e-3, spread=0.0))
    made = agent.first_query()
    assert is_generated(made) and len(agent.searches) == 1 and made not in agent.pool
    assert 0 < len(agent.pool) <= POOL_KEEP and agent.searches[0]["simulations"] > len(agent.pool)
    runner_up, kept = next(iter(agent.pool.items()))
    agent.inner.target = np.array(kept["zeta"])  # a target on a runner-up: shown as it is, no second search
    assert agent._choose(None, []) == runner_up and len(agent.searches) == 1
    assert runner_up not in agent.pool and agent.generated[runner_up]["zeta"] == kept["zeta"]
    assert agent.generated[runner_up]["pooled"] and not agent.generated[made].get("pooled")
    rollout = agent.rollout(runner_up)  # a made clip like any other: (params, seed) remake it
    assert (rollout.params, rollout.seed) == (kept["params"], kept["seed"])
    restored = GeneratingGlobalAgent.from_state(json.loads(json.dumps(agent.state_dict())), agent.ctx)
    assert restored.pool == agent.pool and restored.state_dict() == agent.state_dict()


def test_the_pool_drops_the_oldest_search_s_clips_first(ctx, gap_roots, monkeypatch):
    monkeypatch.setattr(generating_agent, "POOL_SIZE", POOL_KEEP + 2)
    agent = GeneratingGlobalAgent(_gen(ctx, gap_roots, threshold=1e-9, spread=0.0))  # every search falls short
    agent.first_query()
    first = list(agent.pool)
    agent.inner.target = agent.inner.target + 0.5  # far from the first search's target: searched again
    agent._choose(None, [])
    assert len(agent.searches) == 2 and len(agent.pool) == POOL_KEEP + 2
    newest = [i for i in agent.pool if i not in first]
    assert len(newest) >= POOL_KEEP and list(agent.pool)[-len(newest):] == newest  # the new search's, all kept
    assert [i for i in agent.pool if i in first] == first[len(first) - (POOL_KEEP + 2 - len(newest)):]


def test_no_search_while_the_belief_is_wider_than_the_library_clips_miss(ctx, gap_roots):
    wide = GeneratingGlobalAgent(_gen(ctx, gap_roots, threshold=0.0))  # the default spread
    assert not is_generated(wide.first_query()) and wide.searches == []  # the prior: quartiles far apart
    eager = GeneratingGlobalAgent(_gen(ctx, gap_roots, threshold=0.0, spread=0.0))
    assert is_generated(eager.first_query()) and len(eager.searches) == 1
    sure = GeneratingGlobalAgent(_gen(ctx, gap_roots, threshold=0.0))
    sure.first_query()
    z, scale = sure.inner.target.copy(), ctx.bounds[1] - ctx.bounds[0]
    sure.inner.answers = [(a, float(z[a] + d * scale[a]), h) for a in range(len(z))
                          for d, h in ((-0.005, 1), (0.005, -1))] * 4
    assert (sure.inner.widths() / scale).max() < 0.02  # answers pin the target: the library clip's miss counts
    assert is_generated(sure._choose(None, [])) and len(sure.searches) == 1


def test_the_stored_zeta_is_the_rankers(ctx, gap_roots):
    gen = _gen(ctx, gap_roots, threshold=0.0, spread=0.0)
    agent = GeneratingGlobalAgent(gen)
    rid = agent.first_query()
    assert is_generated(rid)
    zeta = ZetaDistance(gen.ranker, np.zeros(2), np.ones(2)).zeta([agent.rollout(rid)])[0]
    np.testing.assert_allclose(agent.generated[rid]["zeta"], zeta)


def test_evaluate_with_and_without_generation(gap_roots):
    data, models = gap_roots
    off = evaluate("toy", "global", targets=4, data_root=data, models_root=models, split="test")
    on = evaluate("toy", "global", targets=4, data_root=data, models_root=models, split="test", generate=True,
                  gen_config=GenerationConfig(budget=16))
    assert off.generate is False and off.generation is None
    assert on.generate and set(on.generation) >= {"searches", "simulations", "seconds_mean", "seconds_p95"}
    # every made clip shown: a search's best, or a runner-up shown later without a search
    assert on.generation["shown"] + on.generation["pooled"] == sum(is_generated(r) for t in on.trials
                                                                   for r in t.shown_ids)
    assert on.success_rate >= off.success_rate
    assert [t.target for t in on.trials] == [t.target for t in off.trials]


def test_generation_is_refused_where_it_cannot_work(ctx, gap_roots):
    with pytest.raises(ValueError, match="valid with generation: global"):
        generating_agents("local", ctx, gap_roots[1])
    with pytest.raises(ValueError, match="a myopic user cannot judge generated clips; with generation use: paper"):
        evaluate("toy", "global", targets=1, data_root=gap_roots[0], models_root=gap_roots[1], user="myopic",
                 generate=True)
    with pytest.raises(ValueError, match="unknown objective 'proxies'; valid: zeta, reward"):
        _gen(ctx, gap_roots, objective="proxies")


def test_reward_objective_also_generates(ctx, gap_roots):
    agent = GeneratingGlobalAgent(_gen(ctx, gap_roots, objective="reward"))
    trial = simulate(agent, TARGET, _eps(ctx), ctx.serve, seed=0, max_feedback=BUDGET)
    assert agent.searches and any(is_generated(r) for r in trial.shown_ids)


@pytest.mark.parametrize(("extra", "generates"), [
    ([], True),  # on by default for RBA-Global with a user who can judge new clips
    (["--no-generate"], False),
    (["--user", "myopic"], False),  # judges clip ends by a map fitted over the library: not new clips
    (["--method", "oracle"], False),  # no generating agent
])
def test_cli_generates_by_default_where_it_can(gap_roots, monkeypatch, tmp_path, extra, generates):
    monkeypatch.setenv("RBA_DATA_DIR", str(gap_roots[0]))
    monkeypatch.setenv("RBA_MODELS_DIR", str(gap_roots[1]))
    out = tmp_path / "r.json"
    assert main(["eval", "--domain", "toy", "--targets", "1", "--workers", "1", "--json", str(out), *extra]) == 0
    result = json.loads(out.read_text())
    assert result["generate"] is generates and (result["generation"] is not None) is generates


def test_cli_generate_flag(gap_roots, monkeypatch, capsys, tmp_path):
    monkeypatch.setenv("RBA_DATA_DIR", str(gap_roots[0]))
    monkeypatch.setenv("RBA_MODELS_DIR", str(gap_roots[1]))
    out = tmp_path / "r.json"
    assert main(["eval", "--domain", "toy", "--targets", "2", "--generate", "--workers", "1",
                 "--gen-config", str(gen_config_file(tmp_path, {"budget": 16})), "--json", str(out)]) == 0
    assert json.loads(out.read_text())["generate"] is True and "generation: searches" in capsys.readouterr().out
    assert main(["eval", "--domain", "toy", "--all-methods", "--generate"]) == 2
    assert "give --method, not --all-methods" in capsys.readouterr().err
    assert main(["eval", "--domain", "toy", "--method", "pbrl", "--generate", "--workers", "1"]) == 2
    assert "method 'pbrl' cannot generate behaviours; valid with generation: global" in capsys.readouterr().err


@pytest.fixture(scope="module")
def narrow_roots(toy_roots, tmp_path_factory):
    """The toy data with a serve library less its clips in the outer tenth of each parameter's range: the
    skill reaches beyond what serve holds."""
    def middle(p):
        return (p[:, 0] > 0.38) & (p[:, 0] < 1.82) & (p[:, 1] > 0.75) & (p[:, 1] < 2.75)

    return serve_subset_roots(toy_roots, tmp_path_factory.mktemp("narrow"), middle)


def test_beyond_targets_leave_the_serve_range_by_at_most_the_share(narrow_roots):
    from rba.data.library import SkillLibrary

    serve = SkillLibrary.load("toy", "serve", narrow_roots[0])
    low, high = serve.proxies.min(0), serve.proxies.max(0)
    targets = beyond_targets(serve, 0.1, 8, seed=0)
    assert targets.shape == (8, 2)
    assert (((targets < low) | (targets > high)).any(1)).all()  # each outside the range on some attribute
    band = 0.1 * (high - low)
    assert ((targets >= low - band) & (targets <= high + band)).all()
    np.testing.assert_array_equal(beyond_targets(serve, 0.1, 8, seed=0), targets)  # seeded
    assert not np.array_equal(beyond_targets(serve, 0.1, 8, seed=1), targets)
    with pytest.raises(ValueError, match=r"must be in \(0, 0.5\]; got 0.7"):
        beyond_targets(serve, 0.7, 8)


def test_evaluate_beyond_the_range_with_and_without_generation(narrow_roots):
    data, models = narrow_roots
    options = dict(targets=4, data_root=data, models_root=models, precision="high", beyond=0.1)
    off = evaluate("toy", "global", **options)
    on = evaluate("toy", "global", **options, generate=True, gen_config=GenerationConfig(budget=16))
    assert off.split == on.split == "beyond" and off.beyond == 0.1
    assert [t.target for t in on.trials] == [t.target for t in off.trials]
    assert off.success_rate == 0.0  # no serve clip is within the high-precision ε of a target beyond its range
    assert on.success_rate > off.success_rate and on.generation["shown"] > 0


def test_cli_generate_spread_setting(gap_roots, monkeypatch, capsys, tmp_path):
    monkeypatch.setenv("RBA_DATA_DIR", str(gap_roots[0]))
    monkeypatch.setenv("RBA_MODELS_DIR", str(gap_roots[1]))
    searches = {}
    for spread in (0, None):
        out = tmp_path / f"{spread}.json"
        settings = {"budget": 16} | ({} if spread is None else {"generate_spread": spread})
        assert main(["eval", "--domain", "toy", "--targets", "2", "--workers", "1", "--json", str(out),
                     "--gen-config", str(gen_config_file(tmp_path, settings))]) == 0
        searches[spread] = json.loads(out.read_text())["generation"]["searches"]
    assert searches[0] > searches[None]  # spread 0: every clip off by the threshold searches, however unsure
    # inf would turn generation off without a word
    cli_refuses(capsys, tmp_path, "generate_spread", (-1.0, math.inf, "wide"), "a finite number ≥ 0")


def test_cli_seconds_setting(gap_roots, monkeypatch, capsys, tmp_path):
    monkeypatch.setenv("RBA_DATA_DIR", str(gap_roots[0]))
    monkeypatch.setenv("RBA_MODELS_DIR", str(gap_roots[1]))
    out = tmp_path / "r.json"
    config = gen_config_file(tmp_path, {"budget": 16, "generate_spread": 0, "seconds": 1e-9})
    assert main(["eval", "--domain", "toy", "--targets", "2", "--workers", "1", "--gen-config", str(config),
                 "--json", str(out)]) == 0
    generation = json.loads(out.read_text())["generation"]
    # out of time at once: each search ends at its first finished candidate, not after a whole generation of 8
    assert 0 < generation["searches"] <= generation["simulations"] < 8 * generation["searches"]
    cli_refuses(capsys, tmp_path, "seconds", (0, math.inf, "soon"), "a number of seconds > 0")


def test_cli_beyond_option(narrow_roots, monkeypatch, capsys, tmp_path):
    monkeypatch.setenv("RBA_DATA_DIR", str(narrow_roots[0]))
    monkeypatch.setenv("RBA_MODELS_DIR", str(narrow_roots[1]))
    out = tmp_path / "r.json"
    assert main(["eval", "--domain", "toy", "--targets", "2", "--beyond", "0.1", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["split"] == "beyond"
    with pytest.raises(SystemExit) as exit_:
        main(["eval", "--domain", "toy", "--beyond", "0.7"])
    assert exit_.value.code == 2
    assert "must be a share in (0, 0.5], e.g. 0.1 for 10 %; got 0.7" in capsys.readouterr().err


def test_evaluate_over_the_first_serve_rollouts_only(gap_roots, monkeypatch, capsys):
    from rba.data.library import SkillLibrary

    data, models = gap_roots
    small = evaluate("toy", "global", targets=3, data_root=data, models_root=models, serve_size=40)
    assert small.serve_size == 40
    assert evaluate("toy", "global", targets=1, data_root=data, models_root=models).serve_size > 40
    first = set(SkillLibrary.load("toy", "serve", data).ids[:40])
    assert {r for t in small.trials for r in t.shown_ids} <= first
    epsilons = []  # the task's ε is the whole library's, whatever the agent sees
    monkeypatch.setattr(evaluate_module, "simulate", lambda agent, target, eps, *rest: epsilons.append(eps) or
                        evaluate_module.Trial(target={}, success=False, feedback_count=0))
    for size in (40, None):
        evaluate("toy", "global", targets=1, data_root=data, models_root=models, serve_size=size)
    np.testing.assert_array_equal(*epsilons)
    monkeypatch.undo()
    monkeypatch.setenv("RBA_DATA_DIR", str(data))
    monkeypatch.setenv("RBA_MODELS_DIR", str(models))
    assert main(["eval", "--domain", "toy", "--all-methods", "--serve-size", "40"]) == 2
    assert "--serve-size works with one method (global): give --method" in capsys.readouterr().err
    with pytest.raises(ValueError, match="works with method global only, not 'oracle'"):
        evaluate("toy", "oracle", targets=1, data_root=data, models_root=models, serve_size=40)
    with pytest.raises(ValueError, match=r"the serve library has \d+ rollouts; asked for the first 100000"):
        evaluate("toy", "global", targets=1, data_root=data, models_root=models, serve_size=100_000)


def test_the_app_is_told_the_library_clip_before_each_search_and_only_then(ctx, gap_roots):
    """``on_search`` names, before a search runs, the serve clip the agent shows if it falls short (the app renders
    it meanwhile); a step that shows a library clip without searching says nothing."""
    told = []
    agent = GeneratingGlobalAgent(_gen(ctx, gap_roots, threshold=1e-9, spread=0.0, on_search=told.append))
    agent.first_query()  # no search ends this close: the library clip is shown
    assert len(agent.searches) == 1 and told == [ctx.serve.ids[agent.inner.shown]]
    agent._choose(None, [])  # a search fell short near this target: the library clip, no search, nothing said
    assert len(agent.searches) == 1 and len(told) == 1
    sure = GeneratingGlobalAgent(_gen(ctx, gap_roots, threshold=10.0, on_search=told.append))  # every clip is near
    sure.first_query()
    assert sure.searches == [] and len(told) == 1


def test_the_soft_step_is_the_domains_unless_asked_and_kept_in_the_state(ctx, gap_roots, monkeypatch):
    monkeypatch.setattr(Toy, "zeta_noise", 0.04)
    agent = GeneratingGlobalAgent(_gen(ctx, gap_roots))
    assert agent.ctx.zeta_noise == agent.inner.zeta_noise == 0.04  # the domain's
    assert GeneratingGlobalAgent(_gen(ctx, gap_roots, zeta_noise=0.0)).inner.zeta_noise == 0.0  # asked
    agent.first_query()
    agent.update([AttributeFeedback("amplitude", 1)])
    state = json.loads(json.dumps(agent.state_dict()))
    restored = GeneratingGlobalAgent.from_state(state, _gen(ctx, gap_roots, zeta_noise=0.0))
    assert restored.inner.zeta_noise == 0.04  # a session keeps the belief it started with
    np.testing.assert_allclose(restored.inner.belief(0), agent.inner.belief(0))
    del state["zeta_noise"]  # a session from before the soft step
    assert GeneratingGlobalAgent.from_state(state, _gen(ctx, gap_roots)).inner.zeta_noise == 0.0
    with pytest.raises(ValueError, match=r"zeta_noise is a share of ζσ's range in \[0, 1\), got 1.5"):
        _gen(ctx, gap_roots, zeta_noise=1.5)


def test_the_belief_prior_is_the_domains_unless_asked_and_lies_where_the_clips_do(ctx, gap_roots, monkeypatch):
    monkeypatch.setattr(Toy, "belief_prior", 0.05)
    base = _gen(ctx, gap_roots).base
    assert base.prior_width == 0.05 and _gen(ctx, gap_roots, prior_width=0.0).base.prior_width == 0.0
    np.testing.assert_array_equal(_gen(ctx, gap_roots, prior_width=0.0).base.prior(0), ctx.prior(0))  # uniform
    # every serve clip at one ζσ (the toy's clips cover its whole range, where a kernel prior is nearly flat)
    middle = (ctx.bounds[0] + ctx.bounds[1]) / 2 + 0.2 * (ctx.bounds[1] - ctx.bounds[0])
    piled = replace(base, serve_zeta=np.broadcast_to(middle, base.serve_zeta.shape))
    for a in range(len(ctx.attribute_names)):
        grid, mass = piled.grid(a), np.exp(piled.prior(a))
        uniform = np.exp(ctx.prior(a)) / np.exp(ctx.prior(a)).sum()
        near = np.abs(grid - middle[a]) <= 3 * 0.05 * (ctx.bounds[1, a] - ctx.bounds[0, a])
        assert mass.sum() == pytest.approx(1.0) and uniform[near].sum() < 0.3
        assert mass[near].sum() > 0.95  # the kernel's mass where the clips are, the floor's beyond
        assert quantile(grid, mass, 0.5) == pytest.approx(middle[a], abs=0.01 * (grid[-1] - grid[0]))
        assert np.all(mass >= global_agent.PRIOR_FLOOR * uniform * (1 - 1e-9))  # no target ruled out
    agent = GeneratingGlobalAgent(_gen(ctx, gap_roots))
    assert agent.inner.target[0] == pytest.approx(quantile(base.grid(0), np.exp(base.prior(0)), 0.5))
    with pytest.raises(ValueError, match=r"prior_width is a share of ζσ's range in \[0, 1\), got 1.5"):
        _gen(ctx, gap_roots, prior_width=1.5)


def gen_config_file(tmp_path, settings: dict, suffix: str = ".toml") -> Path:
    """A ``--gen-config`` file holding ``settings`` (TOML, or JSON by ``suffix``)."""
    path = tmp_path / f"gen-{len(list(tmp_path.glob('gen-*')))}{suffix}"
    if suffix == ".json":
        path.write_text(json.dumps(settings))
    else:
        path.write_text("".join(f"{k} = {_toml(v)}\n" for k, v in settings.items()))
    return path


def _toml(value) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)  # inf, nan: TOML's own words
    return json.dumps(value)


def cli_context_option(gap_roots, monkeypatch, tmp_path, settings: dict, attribute: str) -> list:
    """The generating context's ``attribute`` as ``rba eval --gen-config`` sets it: with ``settings``, then
    without (a budget of 8 both times)."""
    monkeypatch.setenv("RBA_DATA_DIR", str(gap_roots[0]))
    monkeypatch.setenv("RBA_MODELS_DIR", str(gap_roots[1]))
    asked, load = [], GenerationContext.load.__func__

    def recording_load(cls, base, models_root=None, **options):
        gen = load(cls, base, models_root, **options)
        asked.append(getattr(gen, attribute))
        return gen

    monkeypatch.setattr(GenerationContext, "load", classmethod(recording_load))
    for extra in (settings, {}):
        config = gen_config_file(tmp_path, {"budget": 8, **extra})
        assert main(["eval", "--domain", "toy", "--targets", "1", "--workers", "1", "--gen-config", str(config)]) == 0
    return asked


def cli_refuses(capsys, tmp_path, key: str, bads: tuple, valid: str) -> None:
    """``rba eval --gen-config`` with ``key = BAD`` exits 2 saying what is valid, for each of ``bads``."""
    for bad in bads:
        with pytest.raises(SystemExit) as exit_:
            main(["eval", "--domain", "toy", "--gen-config", str(gen_config_file(tmp_path, {key: bad}))])
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert f"argument --gen-config: generation setting {key} must be {valid}, got {bad!r}" in err, err


def test_cli_zeta_noise_setting(gap_roots, monkeypatch, capsys, tmp_path):
    assert cli_context_option(gap_roots, monkeypatch, tmp_path, {"zeta_noise": 0.05}, "zeta_noise") == [
        0.05, Toy.zeta_noise]
    cli_refuses(capsys, tmp_path, "zeta_noise", (-0.1, 1.0, "wide"), "a share in [0, 1)")


def test_cli_belief_prior_setting(gap_roots, monkeypatch, capsys, tmp_path):
    assert cli_context_option(gap_roots, monkeypatch, tmp_path, {"belief_prior": 0.05}, "prior_width") == [
        0.05, Toy.belief_prior]
    cli_refuses(capsys, tmp_path, "belief_prior", (-0.1, 1.0, "wide"), "a share in [0, 1)")


def test_a_soft_step_keeps_answers_that_contradict_each_other_one_bump():
    grid, flat = np.linspace(0.0, 1.0, 401), np.zeros(401)
    answers = [(0.52, 1), (0.48, -1)]  # "more than at 0.52", then "less than at 0.48": ζσ ordered two clips wrongly
    hard, soft = posterior(grid, flat, answers, 0.1), posterior(grid, flat, answers, 0.1, width=0.05)
    between = (grid > 0.48) & (grid < 0.52)
    assert hard[between].max() < hard.max() / 8  # the hard step splits the belief in two, away from both clips
    assert between[np.argmax(soft)]  # the soft step: one bump, between them
    off = np.abs(grid[:, None] - np.array([0.48, 0.52])).min(1) > 1e-9
    sharp = posterior(grid, flat, answers, 0.1, width=1e-12)[off]
    np.testing.assert_allclose(sharp / sharp.sum(), hard[off] / hard[off].sum())  # the hard step is its limit
