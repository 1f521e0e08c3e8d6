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

Stepping (``rba.gym``): :class:`LaneChangeSim` is the scene under the ego's (acceleration, steering) per
15 Hz simulation step, applied as given (the follower drives itself); :class:`LaneChangePolicy` is the skill:
highway-env's own lane keeping with the gain, on a mirror car set to the observed lateral position, heading
and speed (on the straight road it reads nothing else), told to change lanes at 2 s. The observation at
each step is the state vector then; every 3rd is one the rollout records. ``rollout`` is ``run_skill`` of the
two: one code path. The raw view and ``lane_change_image`` get no env: the mirror car needs the ego's speed,
which their states hold only as a velocity (raw) or not at all (image latents).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from rba.domains.base import (
    ALL_FRAMES,
    AttributeSpec,
    Domain,
    FeedbackPhrases,
    Marker,
    Overlay,
    Rollout,
    SkillPolicy,
    SkillSim,
    run_skill,
    stack_samples,
)

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
STEPS = int(DURATION * SIM_HZ)  # simulation steps per clip
CHANGE_STEP = int(CHANGE_AT * SIM_HZ)
EGO_Y, EGO_HEADING, EGO_SPEED, FOLLOWER_DX = (STATE_FEATURES.index(name) for name in
                                              ("ego_y", "ego_heading", "ego_speed", "follower_dx"))
ACCELERATION, STEERING = 0, 1  # the action's columns


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


def _ego(road):
    """The ego car where the clip starts: cruising in lane 0 (its lane keeping is the policy's, not this car's)."""
    from highway_env.vehicle.controller import MDPVehicle

    lane0 = road.network.get_lane(("0", "1", 0))
    return MDPVehicle(road, lane0.position(EGO_X0, 0.0), lane0.heading_at(EGO_X0), SPEED,
                      target_lane_index=("0", "1", 0), target_speed=SPEED)


def _scene(env, gap: float):
    """The two cars, placed on a freshly reset road: (ego, follower)."""
    from highway_env.vehicle.behavior import IDMVehicle

    road = env.unwrapped.road
    ego = _ego(road)
    # at 25 m/s both, the gap is unchanged until the change starts
    lane1 = road.network.get_lane(("0", "1", 1))
    follower = IDMVehicle(road, lane1.position(EGO_X0 - gap - CAR_LENGTH, 0.0), 0.0, SPEED,
                          target_lane_index=("0", "1", 1), target_speed=SPEED, enable_lane_change=False)
    road.vehicles = [ego, follower]
    env.unwrapped.vehicle = ego
    return ego, follower


def lane_change_proxies(headings: list[float], gap: float) -> dict[str, float]:
    """The attributes' proxies: the ego's peak yaw rate over its headings per step, the gap at the change."""
    return {"sharpness": float((np.abs(np.diff(headings)) * SIM_HZ).max()), "gap": gap}


class LaneChangePolicy:
    """The lane change as ``policy(obs) -> action`` (``SkillPolicy``): see the module docstring."""

    def __init__(self, params: dict[str, float], network) -> None:
        from highway_env.road.road import Road

        self._car = _ego(Road(network=network))
        self._car.KP_LATERAL = float(params["lateral_gain"])  # per instance: the class attribute is shared
        self._k = 0
        self._headings: list[float] = []
        self._gap = float("nan")
        self.done = False

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        o, k, car = np.asarray(obs, dtype=np.float64), self._k, self._car
        self._headings.append(o[EGO_HEADING])
        if k == CHANGE_STEP:
            self._gap = float(-o[FOLLOWER_DX] - CAR_LENGTH)
        if k == STEPS:
            self.done = True
            return np.zeros(2)
        car.position = np.array([car.position[0], o[EGO_Y]])
        car.heading, car.speed = o[EGO_HEADING], o[EGO_SPEED]
        car.act("LANE_RIGHT" if k == CHANGE_STEP else None)
        self._k += 1
        return np.array([car.action["acceleration"], car.action["steering"]])

    def measured(self) -> dict[str, float]:
        return lane_change_proxies(self._headings, self._gap)


class LaneChangeSim:
    """The two-car scene under the ego's per-step (acceleration, steering) (``SkillSim``), on ``env``'s road."""

    max_steps = STEPS

    def __init__(self, env) -> None:
        from highway_env.vehicle.controller import ControlledVehicle
        from highway_env.vehicle.kinematics import Vehicle

        self._env = env
        # any steering the car has, and more acceleration than its speed controller asks at any speed it reaches
        accel = ControlledVehicle.KP_A * (Vehicle.MAX_SPEED - Vehicle.MIN_SPEED)
        self.action_low = np.array([-accel, -ControlledVehicle.MAX_STEERING_ANGLE])
        self.action_high = np.array([accel, ControlledVehicle.MAX_STEERING_ANGLE])

    def reset(self, params: dict[str, float], seed: int) -> tuple[np.ndarray, bool]:
        self.ego, self.follower = _scene(self._env, float(params["gap"]))
        self.headings = [self.ego.heading]
        self.replay: list[tuple[float, ...]] = []  # both cars' x, y, heading per step
        self.raw: list[list[float]] = []  # both cars' x, y, vx, vy, heading per step: the raw view
        self.crashed = False
        self._k = 0
        return self._observe(), False

    def step(self, action: np.ndarray) -> tuple[np.ndarray, bool]:
        from highway_env.vehicle.kinematics import Vehicle

        ego, follower = self.ego, self.follower
        a = np.asarray(action, dtype=np.float64)
        Vehicle.act(ego, {"steering": float(a[STEERING]), "acceleration": float(a[ACCELERATION])})  # as given
        follower.act()
        self._env.unwrapped.road.step(1.0 / SIM_HZ)
        self._k += 1
        self.crashed |= bool(ego.crashed or follower.crashed)
        self.headings.append(ego.heading)
        self.replay.append((*ego.position, ego.heading, *follower.position, follower.heading))
        self.raw.append([*ego.position, *ego.velocity, ego.heading, *follower.position, *follower.velocity,
                         follower.heading])
        return self._observe(), self._k % DECIDE_EVERY == 0

    def _observe(self) -> np.ndarray:
        """The state vector now (the peak yaw rate over the last DECIDE_EVERY steps, 0 before the first)."""
        ego, follower, recent = self.ego, self.follower, self.headings[-(DECIDE_EVERY + 1):]
        yaw = np.abs(np.diff(recent)).max() * SIM_HZ if len(recent) > 1 else 0.0
        return np.array([ego.position[1], ego.speed * np.sin(ego.heading), ego.heading, yaw, ego.speed,
                         follower.position[0] - ego.position[0], follower.position[1] - ego.position[1],
                         follower.speed])


@dataclass(frozen=True)
class Car:
    """One vehicle as highway-env draws it: a rectangle of ``length`` x ``width`` m in ``rgb`` (0..255)."""

    length: float
    width: float
    rgb: tuple[int, int, int]
    agent: bool  # the car whose behaviour is tuned


@dataclass(frozen=True)
class RoadView:
    """What the page needs to draw a clip as highway-env's renderer draws it (``rba.media.clip_data``): the
    frame is ``view_metres`` of road across, centred so that car ``centre_on`` sits at ``centring`` (fractions of
    the frame's width and height); each replay row holds every car's x, y and heading in ``cars``' order."""

    view_metres: float
    centring: tuple[float, float]
    centre_on: int
    lane_width: float
    lines: tuple[tuple[float, str], ...]  # (y in m, "continuous" | "striped") of each painted line
    stripe: tuple[float, float]  # a striped line's stripe length and spacing (m)
    road_rgb: tuple[int, int, int]
    line_rgb: tuple[int, int, int]
    cars: tuple[Car, ...]

    def poses(self, replay: np.ndarray) -> np.ndarray:
        """float[F, cars, 3]: each car's x, y (m) and heading (rad) per frame."""
        return np.asarray(replay, dtype=np.float64).reshape(len(replay), len(self.cars), 3)


def road_view(env, view: float, ego_at: float) -> RoadView:
    """The two-car scene of ``env`` (made by ``_make_env``) as highway-env's renderer draws it."""
    from highway_env.road.graphics import LaneGraphics, WorldSurface
    from highway_env.road.lane import LineType
    from highway_env.vehicle.graphics import VehicleGraphics

    kinds = {LineType.CONTINUOUS_LINE: "continuous", LineType.CONTINUOUS: "continuous",
             LineType.STRIPED: "striped"}
    lines = sorted({(float(lane.position(0.0, (side - 0.5) * lane.width)[1]), kinds[kind])
                    for lanes in env.unwrapped.road.network.graph.values() for group in lanes.values()
                    for lane in group for side, kind in enumerate(lane.line_types) if kind in kinds})
    ego, follower = _scene(env, 10.0)
    cars = tuple(Car(float(v.LENGTH), float(v.WIDTH), tuple(int(c) for c in VehicleGraphics.get_color(v)[:3]),
                     v is ego) for v in (ego, follower))
    return RoadView(view, (ego_at, 0.5), 0, LANE_WIDTH, tuple(lines),
                    (LaneGraphics.STRIPE_LENGTH, LaneGraphics.STRIPE_SPACING), WorldSurface.GREY, WorldSurface.WHITE,
                    cars)


def lane_change_overlays(replay: np.ndarray, proxies: Mapping[str, float]) -> list[Overlay]:
    """The page's overlays from the replay (both cars' x, y, heading per frame): the ego's path with a marker where
    it turns fastest (its peak yaw rate), and the gap to the follower when the change starts."""
    rows = np.asarray(replay, dtype=np.float64)
    turn = int(np.argmax(np.abs(np.diff(rows[:, 2])))) + 1
    ex, _, _, fx, fy, _ = rows[CHANGE_STEP - 1]
    gap = ((float(fx + CAR_LENGTH / 2), float(fy), 0.0), (float(ex - CAR_LENGTH / 2), float(fy), 0.0))
    path = tuple((float(x), float(y), 0.0) for x, y in rows[:, :2])
    return [Overlay("sharpness", "The car's path and where it turns fastest",
                    (Marker(turn, path[turn], f"{proxies['sharpness']:.2f} rad/s"),), path),
            Overlay("gap", "The gap to the car behind when the change starts",
                    (Marker(CHANGE_STEP - 1, gap[1], f"{proxies['gap']:.1f} m"),), gap)]


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


# free-text feedback's anchors (rba.interact.free_text): both sides written with the same nouns
FEEDBACK_PHRASES = MappingProxyType({
    "sharpness": FeedbackPhrases(
        more=("sharp turn", "swerve abruptly", "quick lane change", "snap into the lane", "jerk the wheel",
              "aggressive swerve", "sudden move across", "hard steering", "switch lanes sharply"),
        less=("smooth turn", "gradual lane change", "ease into the lane", "gentle swerve", "drift slowly across",
              "wide sweeping move across", "relaxed steering", "soft steering", "switch lanes gently"),
        names=("steering sharpness", "sharpness of the swerve")),
    "gap": FeedbackPhrases(
        more=("leave plenty of room", "big gap", "wait for a wide gap", "keep far from the car behind",
              "generous space", "safe distance", "wait longer before changing lanes", "roomy"),
        less=("cut in close", "small gap", "tight squeeze", "pull right in front of the car behind", "tailgate",
              "tiny space", "change lanes sooner", "close distance"),
        names=("gap to the car behind", "distance to the car behind", "room")),
})


class LaneChange(Domain):
    name = "lane_change"
    description = "A car on a highway changes lanes in front of another car; tune how sharply and with how much room."
    attributes = (
        AttributeSpec("sharpness", "How sharply the car swerves into the other lane: a quick, abrupt turn is sharp.",
                      "rad/s"),
        AttributeSpec("gap", "How much room the car leaves to the car behind it in the new lane when it starts "
                      "changing lanes.", "m"),
    )
    state_dim = len(STATE_FEATURES)
    param_names = tuple(PARAM_RANGES)
    param_ranges = PARAM_RANGES
    frame_rate = float(SIM_HZ)
    feedback_phrases = FEEDBACK_PHRASES
    # serve_size: the default 1,200; the generating agent makes what it lacks (decision 0020)
    # zeta_noise: the default hard step (decision 0006)

    def __init__(self) -> None:
        self._local = threading.local()  # one highway-env per thread (simulation and rendering)

    def _env(self, width: int = 320, height: int = 240, view: float = VIEW_METRES, ego_at: float = 0.5):
        envs = self._local.__dict__.setdefault("envs", {})
        key = (width, height, view, ego_at)
        if key not in envs:
            envs[key] = _make_env(*key)
        return envs[key]

    def rollout(self, params: dict[str, float], seed: int) -> Rollout:
        env = self._env()
        sim = LaneChangeSim(env)
        states = run_skill(sim, LaneChangePolicy(params, env.unwrapped.road.network), params, seed)
        replay = np.array(sim.replay, dtype=np.float64)
        before_change = replay[CHANGE_STEP - 1]  # where the cars are when the change starts
        proxies = lane_change_proxies(sim.headings, float(before_change[0] - before_change[3] - CAR_LENGTH))
        final_y = replay[-1, 1]
        success = not sim.crashed and abs(final_y - LANE_WIDTH) < 0.5 and abs(replay[-1, 2]) < 0.1
        states = stack_samples(sim.raw, DECIDE_EVERY) if self.raw_states else np.asarray(states, dtype=np.float32)
        return Rollout("", self.name, dict(params), seed, states, replay, proxies, bool(success),
                       info={"final_lateral_m": float(final_y), "crashed": float(sim.crashed)})

    def clip_view(self, rollout: Rollout | None = None) -> RoadView:
        return road_view(self._env(), VIEW_METRES, 0.5)

    def clip_overlays(self, rollout: Rollout, track: Mapping[str, np.ndarray]) -> list[Overlay]:
        return lane_change_overlays(rollout.replay, rollout.proxies)

    def render(self, rollout: Rollout, width: int, height: int, frames: slice | np.ndarray = ALL_FRAMES,
               view: float = VIEW_METRES, ego_at: float = 0.5) -> Iterator[np.ndarray]:
        """Frames of ``rollout`` (or only the replay rows ``frames``), ``view`` metres of road across,
        the ego car ``ego_at`` of the way across from the left (traffic drives rightwards)."""
        env = self._env(int(width), int(height), view, ego_at)
        ego, follower = _scene(env, 10.0)
        rows = rollout.replay[frames]
        for ex, ey, eh, fx, fy, fh in rows:
            ego.position, ego.heading = np.array([ex, ey]), float(eh)
            follower.position, follower.heading = np.array([fx, fy]), float(fh)
            yield _draw(env)

    def simulator(self) -> SkillSim:
        return LaneChangeSim(_make_env())

    def skill_policy(self, params: dict[str, float], seed: int) -> SkillPolicy:
        return LaneChangePolicy(params, self._env().unwrapped.road.network)

    def observed_proxies(self, observations: np.ndarray) -> dict[str, float]:
        """The peak yaw rate over the observed headings and the gap when the change is asked for, as
        :class:`LaneChangePolicy` measures them (whoever steers)."""
        obs = np.asarray(observations, dtype=np.float64)
        if len(obs) <= CHANGE_STEP:
            raise ValueError(f"a lane change is measured from its first {CHANGE_STEP + 1} observations (the gap at "
                             f"{CHANGE_AT:g} s); got {len(obs)}")
        return lane_change_proxies(obs[:, EGO_HEADING].tolist(), float(-obs[CHANGE_STEP, FOLLOWER_DX] - CAR_LENGTH))


class LaneChangeRaw(LaneChange):
    """Lane change's raw view (``--states raw``): each 5 Hz state is both cars' x, y, vx, vy and heading as
    highway-env holds them (ego, then follower) at the three 15 Hz simulation steps it spans.

    No yaw rate and no offsets: ``sharpness`` (the peak yaw rate) is in the headings 1/15 s apart, ``gap`` in
    the two cars' x at the 2 s state when the change starts.
    """

    name = "lane_change_raw"
    raw_states = True
    state_dim = DECIDE_EVERY * 10
    # no env: see the module docstring
    simulator, skill_policy, observed_proxies = Domain.simulator, Domain.skill_policy, Domain.observed_proxies
