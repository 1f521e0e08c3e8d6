"""ζσ over the skill's parameters (rba.generate.surface) and the generating agent that reads and makes clips on it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rba.generate.cma import SearchConfig, is_generated, surface_search
from rba.generate.surface import ZetaSurface
from rba.interact import generating_agent
from rba.interact.generating_agent import REPEAT, GeneratingGlobalAgent
from rba.interact.global_agent import GlobalContext
from tests.fakes import recording_simulator
from tests.test_generate import BUDGET, TARGET, _eps, _gen, cli_context_option, cli_refuses
from tests.toy import Toy


@pytest.fixture(scope="module")
def ctx(gap_roots) -> GlobalContext:
    return GlobalContext.load("toy", "onehot", *gap_roots)


def _plane(units: np.ndarray) -> np.ndarray:
    return np.stack([units @ [1.0, -2.0, 0.5], 3.0 - units[:, 1]], axis=1)


def test_the_surface_is_exact_on_a_plane_and_averages_noise_away():
    rng = np.random.default_rng(0)
    units, points = rng.random((600, 3)), rng.uniform(0.2, 0.8, (50, 3))
    np.testing.assert_allclose(ZetaSurface(units, _plane(units), 32)(points), _plane(points), atol=1e-6)
    noisy = _plane(units) + rng.normal(0.0, 0.1, (600, 2))
    err = np.abs(ZetaSurface(units, noisy, 64)(points) - _plane(points))
    assert err.std() < 0.05  # the clips' own noise is 0.1: the fit through 64 of them halves it at least
    assert ZetaSurface(units, noisy, 64)(points[0]).shape == (1, 2)


def test_the_surface_refuses_what_it_cannot_fit():
    units = np.zeros((10, 3))
    shapes = r"units \[N, d\] and zeta \[N, k\] of one library, got \(10, 3\) and \(9, 2\)"
    with pytest.raises(ValueError, match=shapes):
        ZetaSurface(units, np.zeros((9, 2)), 4)
    with pytest.raises(ValueError, match="a local plane needs at least 2 neighbours, got 1"):
        ZetaSurface(units, np.zeros((10, 2)), 1)
    with pytest.raises(ValueError, match="points have 2 parameters; the surface has 3"):
        ZetaSurface(units, np.zeros((10, 2)), 4)(np.zeros(2))


def test_the_library_is_read_on_the_surface_and_the_base_context_is_left_alone(ctx, gap_roots):
    before = ctx.serve_zeta.copy()
    gen = _gen(ctx, gap_roots, surface=16)
    units = np.array([gen._space.to_unit(dict(zip(ctx.serve.param_names, p, strict=True))) for p in ctx.serve.params])
    np.testing.assert_allclose(gen.base.serve_zeta, gen.zeta_surface(units))
    assert not np.allclose(gen.base.serve_zeta, ctx.serve_zeta)  # smoothed: the clips' own noise is gone
    np.testing.assert_array_equal(ctx.serve_zeta, before)  # a library-only agent keeps ζσ of the states
    assert _gen(ctx, gap_roots, surface=0).zeta_surface is None


def test_a_clip_made_on_the_surface_costs_one_simulation(ctx, gap_roots):
    gen = _gen(ctx, gap_roots, surface=16)
    start = dict(zip(ctx.serve.param_names, map(float, ctx.serve.params[0]), strict=True))
    target = gen.zeta_surface(np.array([0.3, 0.6]))[0]  # a point of the surface: reachable
    progress = []
    jobs = []
    found = surface_search("toy", [start], gen.zeta_surface, gen.distance(target), recording_simulator(jobs),
                           config=SearchConfig(), on_progress=lambda k, n: progress.append((k, n)))
    assert len(jobs) == found.simulations == 1 and found.rollout is not None and is_generated(found.rollout.id)
    assert found.objective < 0.02 and progress == [(1, 1)]
    assert gen.generations == 1 and _gen(ctx, gap_roots, surface=0).generations == SearchConfig().generations == 6
    assert np.all(np.abs(gen.zetas([found.rollout])[0] - target) <= 0.02 * (ctx.bounds[1] - ctx.bounds[0]))


def test_generation_on_the_surface_reaches_the_target_the_library_lacks(ctx, gap_roots):
    agent = GeneratingGlobalAgent(_gen(ctx, gap_roots, surface=16))
    from rba.interact.evaluate import simulate

    trial = simulate(agent, TARGET, _eps(ctx), ctx.serve, seed=0, max_feedback=BUDGET)
    assert trial.success and any(is_generated(r) for r in trial.shown_ids)
    assert any(s["simulations"] == 1 for s in agent.searches)  # made on the surface
    for g in agent.generated.values():  # the belief reads a made clip at ζ̃ of its parameters
        np.testing.assert_allclose(g["zeta"], agent.ctx.zeta_surface(agent.ctx._space.to_unit(g["params"]))[0])


def test_on_the_surface_the_clip_made_last_starts_the_search(ctx, gap_roots):
    """Made clips stay in one region of the parameters: the last one shown (by round, then as stored) starts the next
    search, the nearest clips follow; without a surface the nearest clip starts, as before."""
    from rba.generate.cma import ZetaDistance

    target = ctx.serve_zeta[5]
    made = {"gen-a": {"params": {"amplitude": 0.9, "pace": 0.9}, "seed": 0, "zeta": list(target), "round": 4},
            "gen-b": {"params": {"amplitude": 0.1, "pace": 0.1}, "seed": 0, "zeta": list(target + 9.0), "round": 7},
            "gen-c": {"params": {"amplitude": 0.5, "pace": 0.2}, "seed": 0, "zeta": list(target + 9.0), "round": 6}}
    gen = _gen(ctx, gap_roots, surface=16)
    dist: ZetaDistance = gen.distance(target)
    starts = GeneratingGlobalAgent(gen, generated=made)._starts(dist)
    assert starts[0] == made["gen-b"]["params"] and made["gen-a"]["params"] in starts[1:]  # last, then the nearest
    assert len(starts) == 4 and made["gen-c"]["params"] not in starts  # far from the target, not the last
    old = {k: {kk: vv for kk, vv in g.items() if kk != "round"} for k, g in made.items()}  # a state from before
    assert GeneratingGlobalAgent(gen, generated=old)._starts(dist)[0] == made["gen-c"]["params"]  # the last stored
    plain = _gen(ctx, gap_roots, surface=0)
    nearest = GeneratingGlobalAgent(plain, generated=made)._starts(plain.distance(target))
    assert made["gen-a"]["params"] in nearest[:2] and made["gen-b"]["params"] not in nearest  # at 0 from the target


def _on_the_surface(ctx, gap_roots, **options):
    """A generating context on a 16-clip surface, the first 4 serve clips as starts, and a target on the surface."""
    gen = _gen(ctx, gap_roots, surface=16, **options)
    starts = [dict(zip(ctx.serve.param_names, map(float, ctx.serve.params[i]), strict=True)) for i in range(4)]
    return gen, starts, gen.zeta_surface(np.array([0.3, 0.6]))[0]


def test_a_clip_the_surface_makes_again_is_made_by_the_zeta_search(ctx, gap_roots):
    gen, starts, target = _on_the_surface(ctx, gap_roots)
    jobs = []
    gen.simulate = recording_simulator(jobs)
    first, _, _ = gen.generate(target, starts, 0)
    assert len(jobs) == first.simulations == 1
    near = {k: v + REPEAT / 4 * (Toy().param_space().high[k] - Toy().param_space().low[k])
            for k, v in first.rollout.params.items()}
    again, _, _ = gen.generate(target, starts, 0, judged=[near])
    assert again.rollout.id != first.rollout.id  # CMA-ES on ζσ of simulated clips ...
    assert len(jobs) - 1 == again.simulations > 2  # ... after the surface's clip, which counts too


def test_the_zeta_search_after_a_repeated_clip_gets_what_is_left_of_the_bound(ctx, gap_roots, monkeypatch):
    """The app bounds a search in time; the surface's clip set aside took part of it, and the person waits for both
    (the walker's answers that fell back took 1.3-1.6 s at its 1 s bound: generation_latency.md)."""
    gen, starts, target = _on_the_surface(ctx, gap_roots, config=SearchConfig(seconds=1.0))
    first, _, _ = gen.generate(target, starts, 0)
    bounds = []
    real = generating_agent.search
    monkeypatch.setattr(generating_agent, "search", lambda *a, **k: bounds.append(a[4].seconds) or real(*a, **k))
    slow = dataclasses.replace(first, seconds=0.4)  # the surface's clip took 0.4 s ...
    monkeypatch.setattr(generating_agent, "surface_search", lambda *a, **k: slow)
    again, _, _ = gen.generate(target, starts, 0, judged=[first.rollout.params])
    assert bounds == [pytest.approx(0.6)] and again.seconds >= 0.4  # ... so the ζσ search gets 0.6 s of the 1 s
    monkeypatch.setattr(generating_agent, "surface_search", lambda *a, **k: dataclasses.replace(first, seconds=5.0))
    late, _, _ = gen.generate(target, starts, 0, judged=[first.rollout.params])
    # nothing left: it still makes a clip
    assert bounds[-1] == generating_agent.MIN_SECONDS and late.rollout is not None


def test_the_surface_is_the_domains_unless_asked(ctx, gap_roots, monkeypatch):
    monkeypatch.setattr(Toy, "zeta_surface", 8)
    assert _gen(ctx, gap_roots).zeta_surface.neighbours == 8
    assert _gen(ctx, gap_roots, surface=0).zeta_surface is None
    for bad in (1, -3):
        with pytest.raises(ValueError, match=rf"fits a plane through 2 or more clips \(0: none\), got {bad}"):
            _gen(ctx, gap_roots, surface=bad)


def test_cli_zeta_surface_setting(gap_roots, monkeypatch, capsys, tmp_path):
    assert cli_context_option(gap_roots, monkeypatch, tmp_path, {"zeta_surface": 12}, "surface") == [
        12, Toy.zeta_surface]
    cli_refuses(capsys, tmp_path, "zeta_surface", (1, -2, "many", 2.5, True), "0 (no surface) or a whole number of "
                "clips ≥ 2")


def test_the_spread_is_the_domains_unless_asked(ctx, gap_roots, monkeypatch):
    monkeypatch.setattr(Toy, "generate_spread", 0.3)
    assert _gen(ctx, gap_roots).spread == 0.3
    assert _gen(ctx, gap_roots, spread=0.0).spread == 0.0
    with pytest.raises(ValueError, match=r"spread is a share of the belief's half interquartile range \(≥ 0\), got -1"):
        _gen(ctx, gap_roots, spread=-1.0)


def test_a_copy_of_the_context_keeps_its_surface_and_reads_the_library_once(ctx, gap_roots):
    """The app copies the context for every step (``dataclasses.replace``): the copy must not fit the surface again
    on the library it already smoothed."""
    gen = _gen(ctx, gap_roots, surface=16)
    copy = dataclasses.replace(gen, on_progress=None)
    assert copy.zeta_surface is gen.zeta_surface
    np.testing.assert_array_equal(copy.base.serve_zeta, gen.base.serve_zeta)
