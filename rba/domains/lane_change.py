"""Lane change on highway-env: a deterministic two-car scene, one lane change per clip.

The ego car cruises in lane 0 at 25 m/s; an IDM follower (lane changes off) drives in lane 1,
``gap`` metres behind (bumper to bumper). At t = 2 s the ego is told to change to lane 1; its
lateral controller gain ``KP_LATERAL`` (highway-env's steering loop) sets how sharply it does.
Simulation 15 Hz, decisions 5 Hz as in highway-env; the follower brakes after the cut-in.

Attributes: ``sharpness`` = peak yaw rate of the ego during the clip (rad/s); ``gap`` = the
distance to the following car when the change starts (m). The gain is capped at 2.2 (≈ 15 m/s²
lateral): highway-env has no tyre limits.

States (5 Hz, kinematic): ego lateral position, lateral speed, heading, peak yaw rate over the
last 0.2 s, speed; follower offset (dx, dy) and speed. Replay (15 fps): both cars' x, y, heading.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from types import MappingProxyType

import numpy as np

from rba.domains.base import AttributeSpec, Domain, FeedbackPhrases, ParamSpace, Rollout, stack_samples

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")  # 'dummy' renders black frames in highway-env 1.12

SIM_HZ = 15  # simulation steps per second
DECIDE_EVERY = 3  # sim steps per decision (5 Hz)
DURATION = 8.0  # s per clip
CHANGE_AT = 2.0  # s: when the lane change is asked for
EGO_X0 = 100.0  # m, ego start along the road
SPEED = 25.0  # m/s, both cars
CAR_LENGTH = 5.0  # m: gap = centre distance − one car length
LANE_WIDTH = 4.0  # m (highway-env's default)
VIEW_METRES = 80.0  # m of road across the rendered frame

PARAM_RANGES = {
    "lateral_gain": (0.4, 2.2),  # KP_LATERAL [1/s]
    "gap": (4.0, 30.0),  # m behind the ego when the change starts
}
STATE_FEATURES = (
    "ego_y", "ego_vy", "ego_heading", "ego_peak_yaw_rate", "ego_speed",  # m, m/s, rad, rad/s, m/s
    "follower_dx", "follower_dy", "follower_speed",  # m (follower − ego), m, m/s
)


def _make_env(width: int = 320, height: int = 240, view: float = VIEW_METRES, ego_at: float = 0.5):
    import gymnasium as gym
    import highway_env  # noqa: F401  (registers highway-v0)

    config = {"lanes_count": 2, "vehicles_count": 0, "simulation_frequency": SIM_HZ,
              "policy_frequency": SIM_HZ // DECIDE_EVERY, "duration": DURATION + 1, "screen_width": width,
              "screen_height": height, "scaling": width / view, "centering_position": [ego_at, 0.5],
              "offscreen_rendering": True, "action": {"type": "DiscreteMetaAction"}}
    env = gym.make("highway-v0", render_mode="rgb_array", config=config)
    env.reset(seed=0)
    return env


def _draw(env) -> np.ndarray:
    """``env.render()`` as an HxWx3 uint8 array, read back row by row: highway-env reads the
    surface column-major (``surfarray``) and the transposed copy took ~0.5 ms of a ~1.1 ms
    frame; ``pygame.image.tobytes`` gives the same pixels in one pass."""
    import pygame

    viewer = env.unwrapped.viewer
    if viewer is None:  # the first frame: env.render() makes the viewer
        return np.ascontiguousarray(env.render())
    viewer.display()
    surface = viewer.sim_surface
    width, height = surface.get_size()
    return np.frombuffer(pygame.image.tobytes(surface, "RGB"), np.uint8).reshape(height, width, 3)


# free-text feedback's anchors (rba.interpret): both sides written with the same nouns
FEEDBACK_PHRASES = MappingProxyType({
    "sharpness": FeedbackPhrases(
        more=("sharp turn", "swerve abruptly", "quick lane change", "snap into the lane", "jerk the wheel",
              "aggressive swerve", "sudden move across", "hard steering"),
        less=("smooth turn", "gradual lane change", "ease into the lane", "gentle swerve", "drift slowly across",
              "wide sweeping move across", "relaxed steering", "soft steering"),
        names=("steering sharpness", "how sharp the swerve is")),
    "gap": FeedbackPhrases(
        more=("leave plenty of room", "big gap", "wait for a wide gap", "keep far from the car behind",
              "generous space", "safe distance", "wait longer before changing lanes", "roomy"),
        less=("cut in close", "small gap", "tight squeeze", "pull right in front of the car behind", "tailgate",
              "tiny space", "change lanes sooner", "close distance"),
        names=("gap to the car behind", "distance to the car behind", "room")),
})


class LaneChange(Domain):
    name = "lane_change"
    attributes = (
        AttributeSpec("sharpness", "How sharply the car swerves into the other lane: a quick, abrupt turn is sharp.",
                      "rad/s"),
        AttributeSpec("gap", "How much room the car leaves to the car behind it in the new lane when it starts "
                      "changing lanes.", "m"),
    )
    state_dim = len(STATE_FEATURES)
    param_names = tuple(PARAM_RANGES)
    frame_rate = float(SIM_HZ)
    feedback_phrases = FEEDBACK_PHRASES
    serve_size = 3600  # 1,200 leaves 19 % of test targets with no serve clip within the high-precision ε

    def __init__(self) -> None:
        self._local = threading.local()  # one highway-env per thread (simulation and rendering)

    def _env(self, width: int = 320, height: int = 240, view: float = VIEW_METRES, ego_at: float = 0.5):
        envs = self._local.__dict__.setdefault("envs", {})
        key = (width, height, view, ego_at)
        if key not in envs:
            envs[key] = _make_env(*key)
        return envs[key]

    def sample_params(self, rng: np.random.Generator) -> dict[str, float]:
        return {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in PARAM_RANGES.items()}

    def param_space(self) -> ParamSpace:
        return ParamSpace.box(PARAM_RANGES)

    def _scene(self, env, gap: float, gain: float):
        """The two cars, placed on a freshly reset road: (ego, follower)."""
        from highway_env.vehicle.behavior import IDMVehicle
        from highway_env.vehicle.controller import MDPVehicle

        road = env.unwrapped.road
        lane0, lane1 = road.network.get_lane(("0", "1", 0)), road.network.get_lane(("0", "1", 1))
        ego = MDPVehicle(road, lane0.position(EGO_X0, 0.0), lane0.heading_at(EGO_X0), SPEED,
                         target_lane_index=("0", "1", 0), target_speed=SPEED)
        ego.KP_LATERAL = gain  # per instance: the class attribute is shared
        # at 25 m/s both, the gap is unchanged until the change starts
        follower = IDMVehicle(road, lane1.position(EGO_X0 - gap - CAR_LENGTH, 0.0), 0.0, SPEED,
                              target_lane_index=("0", "1", 1), target_speed=SPEED, enable_lane_change=False)
        road.vehicles = [ego, follower]
        env.unwrapped.vehicle = ego
        return ego, follower

    def rollout(self, params: dict[str, float], seed: int) -> Rollout:
        env = self._env()
        road = env.unwrapped.road
        ego, follower = self._scene(env, float(params["gap"]), float(params["lateral_gain"]))
        steps = int(DURATION * SIM_HZ)
        change_step = int(CHANGE_AT * SIM_HZ)
        replay = np.zeros((steps, 6))
        headings = np.zeros(steps + 1)
        headings[0] = ego.heading
        states, raw, gap_at_change = [], [], float("nan")
        crashed = False
        for k in range(steps):
            if k % DECIDE_EVERY == 0:
                if k == change_step:
                    gap_at_change = float(ego.position[0] - follower.position[0] - CAR_LENGTH)
                ego.act("LANE_RIGHT" if k == change_step else None)
            road.act()
            road.step(1.0 / SIM_HZ)
            crashed |= bool(ego.crashed or follower.crashed)
            headings[k + 1] = ego.heading
            replay[k] = (*ego.position, ego.heading, *follower.position, follower.heading)
            raw.append([*ego.position, *ego.velocity, ego.heading, *follower.position, *follower.velocity,
                        follower.heading])
            if (k + 1) % DECIDE_EVERY == 0:
                yaw = np.abs(np.diff(headings[max(k + 1 - DECIDE_EVERY, 0): k + 2])).max() * SIM_HZ
                states.append([ego.position[1], ego.speed * np.sin(ego.heading), ego.heading, yaw, ego.speed,
                               follower.position[0] - ego.position[0], follower.position[1] - ego.position[1],
                               follower.speed])
        yaw_rate = np.abs(np.diff(headings)) * SIM_HZ
        final_y = replay[-1, 1]
        success = not crashed and abs(final_y - LANE_WIDTH) < 0.5 and abs(replay[-1, 2]) < 0.1
        states = stack_samples(raw, DECIDE_EVERY) if self.raw_states else np.asarray(states, dtype=np.float32)
        return Rollout("", self.name, dict(params), seed, states, replay,
                       {"sharpness": float(yaw_rate.max()), "gap": gap_at_change}, bool(success),
                       info={"final_lateral_m": float(final_y), "crashed": float(crashed)})

    def render(self, rollout: Rollout, width: int, height: int, view: float = VIEW_METRES,
               frames: np.ndarray | None = None, ego_at: float = 0.5) -> Iterator[np.ndarray]:
        """Frames of ``rollout`` (or only the replay rows ``frames``), ``view`` metres of road across,
        the ego car ``ego_at`` of the way across from the left (traffic drives rightwards)."""
        env = self._env(int(width), int(height), view, ego_at)
        ego, follower = self._scene(env, 10.0, 1.0)
        rows = rollout.replay if frames is None else rollout.replay[frames]
        for ex, ey, eh, fx, fy, fh in rows:
            ego.position, ego.heading = np.array([ex, ey]), float(eh)
            follower.position, follower.heading = np.array([fx, fy]), float(fh)
            yield _draw(env)


class LaneChangeRaw(LaneChange):
    """Lane change's raw view (``--states raw``): each 5 Hz state is both cars' x, y, vx, vy and heading as
    highway-env holds them (ego, then follower) at the three 15 Hz simulation steps it spans.

    No yaw rate and no offsets: ``sharpness`` (the peak yaw rate) is in the headings 1/15 s apart, ``gap`` in
    the two cars' x at the 2 s state when the change starts.
    """

    name = "lane_change_raw"
    raw_states = True
    state_dim = DECIDE_EVERY * 10
