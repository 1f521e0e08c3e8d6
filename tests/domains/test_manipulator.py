"""Manipulator proxies against hand-checkable cases."""

import numpy as np
import pytest

from rba.domains import get_domain
from rba.domains.manipulator import quadratic_residual


@pytest.fixture(scope="module")
def domain():
    return get_domain("manipulator")


def test_quadratic_residual_is_zero_on_a_parabola_and_grows_with_jitter():
    t = np.linspace(0, 1, 50)
    smooth = np.stack([t, 3 * t**2 - t], 1)
    assert quadratic_residual(smooth) == pytest.approx(0.0, abs=1e-12)
    jitter = smooth + 0.001 * np.random.default_rng(0).standard_normal(smooth.shape)
    assert quadratic_residual(jitter) > 3e-4


def test_zero_tremor_has_the_lowest_instability(domain):
    inst = [domain.rollout({"duration": 1.2, "tremor": s}, seed=0).proxies["instability"] for s in (0.0, 0.01, 0.03)]
    assert inst == sorted(inst) and inst[2] > 3 * inst[0]


def test_a_shorter_lift_is_faster_and_the_ball_rises_with_the_hand(domain):
    fast, slow = (domain.rollout({"duration": d, "tremor": 0.0}, seed=0) for d in (0.6, 2.4))
    assert fast.proxies["speed"] > 3 * slow.proxies["speed"]
    for r in (fast, slow):
        assert r.success and r.info["ball_rise_m"] > 0.45
