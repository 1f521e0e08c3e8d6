"""Snake proxies against hand-checkable cases."""

import numpy as np
import pytest

from rba.domains import get_domain
from rba.domains.snake import LINK_LENGTH, LINKS, body_metrics, fold_geometry, fold_shape

SHAPE = {"amplitude": 0.9, "wavelength": 7.0, "span": 9.0}


@pytest.fixture(scope="module")
def domain():
    return get_domain("snake")


def test_a_straight_snake_has_no_width_and_no_compression():
    assert fold_geometry(np.zeros(LINKS - 1)) == pytest.approx((0.0, 0.0), abs=1e-12)
    line = np.stack([np.arange(LINKS) * LINK_LENGTH, np.zeros(LINKS)], 1)
    assert body_metrics(line) == pytest.approx((0.0, 0.0), abs=1e-12)


def test_a_u_turn_is_fully_compressed_along_one_axis():
    half = LINKS // 2
    points = np.concatenate([np.stack([np.arange(half) * LINK_LENGTH, np.zeros(half)], 1),
                             np.stack([np.arange(half)[::-1] * LINK_LENGTH, np.full(half, 0.05)], 1)])
    width, compression = body_metrics(points)
    assert width == pytest.approx(0.05, abs=1e-9)
    assert compression > 0.9


def test_a_deeper_fold_is_wider_and_more_compressed(domain):
    shallow, deep = (domain.rollout({**SHAPE, "amplitude": a, "period": 2.5}, seed=0) for a in (0.4, 1.2))
    assert deep.proxies["bend_width"] > 1.5 * shallow.proxies["bend_width"]
    assert deep.proxies["compression"] > 2 * shallow.proxies["compression"]
    assert fold_shape(1.2, 7.0, 9.0)[:2].tolist() == [0.0, 0.0]  # the anchored head stays straight


def test_a_shorter_cycle_is_faster_and_the_snake_goes_forward(domain):
    slow, fast = (domain.rollout({**SHAPE, "period": p}, seed=0) for p in (4.0, 1.6))
    assert fast.proxies["speed"] > 1.8 * slow.proxies["speed"]
    assert slow.success and fast.success and fast.info["forward_m"] > 0.1
