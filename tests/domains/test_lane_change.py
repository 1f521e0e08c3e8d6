"""Lane change proxies against hand-checkable cases."""

import numpy as np
import pytest

from rba.domains import get_domain
from rba.domains.lane_change import CAR_LENGTH, LANE_WIDTH, STATE_FEATURES


@pytest.fixture(scope="module")
def domain():
    return get_domain("lane_change")


def test_gap_is_the_distance_when_the_change_starts(domain):
    for gap in (4.0, 12.5, 30.0):
        r = domain.rollout({"lateral_gain": 1.0, "gap": gap}, seed=0)
        assert r.proxies["gap"] == pytest.approx(gap, abs=0.05)
        dx = r.states[0, STATE_FEATURES.index("follower_dx")]
        assert dx == pytest.approx(-(gap + CAR_LENGTH), abs=0.5)  # behind, one car length more


def test_sharpness_grows_with_the_lateral_gain_and_the_car_ends_in_the_new_lane(domain):
    rollouts = [domain.rollout({"lateral_gain": g, "gap": 15.0}, seed=0) for g in (0.4, 1.0, 2.2)]
    sharp = [r.proxies["sharpness"] for r in rollouts]
    assert sharp == sorted(sharp) and sharp[-1] > 3 * sharp[0]
    for r in rollouts:
        assert r.success and abs(r.replay[-1, 1] - LANE_WIDTH) < 0.5
        assert r.states[0, STATE_FEATURES.index("ego_y")] == pytest.approx(0.0, abs=1e-6)  # starts in lane 0


def test_no_change_before_it_is_asked(domain):
    r = domain.rollout({"lateral_gain": 2.2, "gap": 10.0}, seed=0)
    before = r.replay[: 2 * 15 - 1]  # the first 2 s at 15 fps
    assert np.abs(before[:, 1]).max() < 1e-6 and np.abs(before[:, 2]).max() < 1e-6
