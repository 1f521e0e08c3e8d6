"""The Gymnasium MuJoCo adapter through its example (``examples/halfcheetah``): what the proxies measure, how far
they spread over the skill's box, and its ``rba.gym`` env. The contract itself: ``test_conformance``."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import rba.domains as domains
from rba.domains import get_domain, load_domain, register
from rba.gym import SkillEnv, run_policy
from tests.example_domain import NAME, example_target

TARGET = example_target()
from rba_halfcheetah.domain import DT, SETTLE, HalfCheetah  # noqa: E402 (importable once example_target ran)


@pytest.fixture(scope="module")
def cheetah() -> HalfCheetah:
    return load_domain(TARGET)


@pytest.fixture
def registered(monkeypatch):
    """The example registered by name (as its entry point does when installed), undone afterwards."""
    monkeypatch.setattr(domains.REGISTRY, "extra", dict(domains.REGISTRY.extra))
    register(NAME, TARGET)
    yield get_domain(NAME)
    get_domain.cache_clear()


def test_the_proxies_are_the_motion_the_clip_shows(cheetah):
    """speed: the torso's forward travel over the time after SETTLE; bounce: its height's 5-95 % range; both
    read off the replay the page renders (qpos: x, z, ...)."""
    for seed, params in enumerate(({"frequency": 2.0, "amplitude": 0.6}, {"frequency": 3.5, "amplitude": 0.3})):
        r = cheetah.rollout(params, seed)
        x, z = r.replay[SETTLE:, 0], r.replay[SETTLE:, 1]
        assert r.proxies["speed"] == pytest.approx((x[-1] - x[0]) / ((len(x) - 1) * DT), abs=0.05)
        assert r.proxies["bounce"] == pytest.approx(np.ptp(np.percentile(z, [5, 95])), rel=1e-9)


def test_the_proxies_spread_over_the_skills_box(cheetah):
    """The library covers a range a person can tell apart (several ε of normal precision, 1/7 of each range)."""
    rng = np.random.default_rng(0)
    rollouts = [cheetah.rollout(cheetah.sample_params(rng), seed) for seed in range(40)]
    kept = np.array([[r.proxies["speed"], r.proxies["bounce"]] for r in rollouts if r.success])
    assert len(kept) >= 32  # tipping over is the exception
    low, high = np.percentile(kept, [10, 90], axis=0)
    assert high[0] - low[0] > 0.5 and high[1] - low[1] > 0.05, (low, high)  # m/s, m
    assert abs(np.corrcoef(kept.T)[0, 1]) < 0.7  # two attributes, not one


def test_the_rba_gym_env_reproduces_the_rollout(registered):
    check_env(SkillEnv(NAME), skip_render_check=True)
    params, seed = {"frequency": 2.5, "amplitude": 0.5}, 3
    rollout, policy = registered.rollout(params, seed), registered.skill_policy(params, seed)
    states = run_policy(SkillEnv(NAME), policy, seed, params)
    np.testing.assert_array_equal(states.astype(np.float32), rollout.states)
    assert policy.measured() == rollout.proxies


def test_a_declared_shape_the_env_does_not_have_is_named(cheetah):
    class Wrong(HalfCheetah):
        state_dim = 5

    with pytest.raises(ValueError, match=r"declares state_dim 5 .* HalfCheetah-v5 has observations of shape \(17,\)"):
        Wrong().rollout({"frequency": 2.0, "amplitude": 0.4}, 0)


def test_mujoco_compile_warnings_leave_no_log_file(cheetah, tmp_path, monkeypatch):
    """HalfCheetah's XML has a deprecated attribute: MuJoCo would print it and write MUJOCO_LOG.TXT where we run."""
    monkeypatch.chdir(tmp_path)
    cheetah.rollout({"frequency": 2.0, "amplitude": 0.4}, 0)
    assert list(tmp_path.iterdir()) == []
