"""Lane change proxies against hand-checkable cases."""

import numpy as np
import pytest

from rba.domains import get_domain
from rba.domains.lane_change import CAR_LENGTH, CHANGE_AT, DECIDE_EVERY, LANE_WIDTH, SIM_HZ, STATE_FEATURES


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


def test_image_frames_keep_the_follower_in_view_at_the_widest_gap():
    """The image states can only encode ``gap`` if both cars are in view when the change starts.

    (Afterwards the follower brakes for the ego and may drop out of the frame; that is fine.)
    """
    image = get_domain("lane_change_image")
    r = get_domain("lane_change").rollout({"lateral_gain": 1.0, "gap": 30.0}, seed=0)
    frames = image.frames(r)  # [T, 3, 64, 64] uint8, cars darker than the road
    for frame in frames[: int(CHANGE_AT * SIM_HZ / DECIDE_EVERY) + 1, -1]:  # 5 Hz states up to t = 2 s
        cols = np.flatnonzero((frame < 80).any(0))
        blobs = 1 + np.count_nonzero(np.diff(cols) > 1)
        assert blobs == 2, f"expected the ego and the follower, saw car pixels in columns {cols}"


def test_a_frame_vae_trained_on_another_view_is_refused(monkeypatch):
    from rba.core import artifacts
    from rba.domains.lane_change_image import LaneChangeImage

    old_card = {"architecture": {"view_m": 60.0, "ego_at": 0.5}}  # the centred view of before
    monkeypatch.setattr(artifacts, "load_model", lambda *a, **k: artifacts.Artifact(None, old_card))
    with pytest.raises(ValueError, match="trained on another view"):
        LaneChangeImage().rollout({"lateral_gain": 1.0, "gap": 10.0}, seed=0)
