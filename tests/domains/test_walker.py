"""Walker domain: proxies follow the commanded gait, rollouts are deterministic, render works."""

from __future__ import annotations

import numpy as np
import pytest

from rba.domains.walker import FRAME_RATE, STATE_EVERY, Walker

BASE = {"step_length": 0.5, "landing_speed": 0.5, "swing_duration": 0.5, "swing_height": 0.08}


@pytest.fixture(scope="module")
def walker() -> Walker:
    return Walker()


def _run(walker: Walker, seed: int = 0, **overrides: float):
    return walker.rollout({**BASE, **overrides}, seed)


def test_contract(walker: Walker) -> None:
    assert walker.attribute_names == ("step_size", "softness")
    params = walker.sample_params(np.random.default_rng(0))
    assert tuple(params) == walker.param_names
    r = walker.rollout(params, 3)
    assert r.id == "" and r.domain == "walker" and r.seed == 3
    assert r.states.dtype == np.float32 and r.states.ndim == 2 and r.states.shape[1] == walker.state_dim
    assert r.replay.dtype == np.float64 and r.replay.shape[1] == 9
    # states every STATE_EVERY physics steps and frames at FRAME_RATE cover the same clip
    expected = FRAME_RATE * STATE_EVERY * walker.physics().timestep()
    assert abs(len(r.replay) / len(r.states) - expected) < 0.05 * expected
    assert set(r.proxies) == {"step_size", "softness"}
    assert all(np.isfinite(v) for v in r.proxies.values())
    assert np.isfinite(r.states).all()


def test_step_size_follows_command(walker: Walker) -> None:
    short, long = _run(walker, step_length=0.2), _run(walker, step_length=0.8)
    assert short.success and long.success
    assert short.proxies["step_size"] == pytest.approx(0.2, abs=0.05)
    assert long.proxies["step_size"] == pytest.approx(0.8, abs=0.05)
    # landing softness barely depends on the step length
    assert abs(short.proxies["softness"] - long.proxies["softness"]) < 0.15


def test_softness_follows_landing_speed(walker: Walker) -> None:
    gentle, stomp = _run(walker, landing_speed=0.15), _run(walker, landing_speed=1.2)
    assert gentle.success and stomp.success
    assert gentle.proxies["softness"] > stomp.proxies["softness"] + 0.6
    assert -gentle.proxies["softness"] == pytest.approx(0.15, abs=0.08)  # landing speed, m/s
    assert abs(gentle.proxies["step_size"] - stomp.proxies["step_size"]) < 0.05


def test_deterministic(walker: Walker) -> None:
    a, b = _run(walker, seed=7), Walker().rollout({**BASE}, 7)
    assert np.array_equal(a.states, b.states) and np.array_equal(a.replay, b.replay)
    assert a.proxies == b.proxies and a.success == b.success
    c = _run(walker, seed=8)  # the seed perturbs the start a little
    assert not np.array_equal(a.states, c.states)


def test_render_frames(walker: Walker) -> None:
    r = _run(walker)
    r.replay = r.replay[::40][:3]  # a few frames keep the test fast
    frames = list(walker.render(r, 96, 64))
    assert len(frames) == len(r.replay)
    for f in frames:
        assert f.dtype == np.uint8 and f.shape == (64, 96, 3)
        assert f.std() > 1.0  # not a constant image
    again = list(walker.render(r, 96, 64))
    assert all(np.array_equal(f, g) for f, g in zip(frames, again, strict=True))
