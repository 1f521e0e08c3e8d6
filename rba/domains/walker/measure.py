"""What a walker rollout records as it runs, and the attributes' measurements from it.

Attributes (proxies grow with the attribute)
--------------------------------------------
* ``step_size``: horizontal distance between the two foot geom centres at touchdown
  (first foot–floor contact of the descending foot), mean over the later two steps.
* ``softness``: minus the swing foot's peak speed in the last 50 ms before touchdown,
  mean over the later two steps.

Code
----
A :class:`Recording` keeps the states (``STATE_FEATURES``), replay frames, raw samples and falls of a rollout;
:func:`measure` turns it and the gait's touchdowns into proxies, success and diagnostics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rba.domains.base import Marker, Overlay
from rba.domains.walker.gait import LANDING_WINDOW, N_STEPS, GaitPlan, Touchdown
from rba.domains.walker.physics import WalkerPhysics

# ---------------------------------------------------------------- fall / success criteria
MIN_TORSO_HEIGHT = 0.7  # torso centre height (m)
MAX_PITCH = 1.0  # |torso pitch| (rad)
LIFT = 0.01  # m of clearance a foot rises above before its next floor contact is a touchdown (observed_touchdowns)
STEP_LIFT = 0.03  # m a foot rises before its landing is a step's, in the overlays' 30 fps frames (a dragged rear
# foot rises about 1 cm)

# ---------------------------------------------------------------- sampling & recording
STATE_EVERY = 40  # physics steps per state sample (10 Hz: foot speed features carry the fast part)
RAW_EVERY = 10  # physics steps per raw sample (40 Hz): the raw view stacks STATE_EVERY // RAW_EVERY per state
FRAME_RATE = 30.0  # replay / rendered frames per second

# what a state holds, in order (units in brackets)
STATE_FEATURES = (
    *("torso_height", "torso_pitch", "torso_x_from_start"),  # torso centre [m], pitch [rad, + = forward], x [m]
    *("torso_vz", "torso_vx", "torso_pitch_rate"),  # [m/s, m/s, rad/s]
    *("right_hip", "right_knee", "right_ankle", "left_hip", "left_knee", "left_ankle"),  # joint angles [rad]
    *("right_hip_vel", "right_knee_vel", "right_ankle_vel"),  # [rad/s]
    *("left_hip_vel", "left_knee_vel", "left_ankle_vel"),  # [rad/s]
    *("right_foot_dx", "right_foot_dz", "left_foot_dx", "left_foot_dz"),  # foot centre - torso centre [m]
    *("right_foot_vx", "right_foot_vz", "left_foot_vx", "left_foot_vz"),  # foot centre velocity [m/s]
    *("right_foot_clearance", "left_foot_clearance"),  # lowest point of each foot above the floor [m]
    *("right_foot_peak_speed", "left_foot_peak_speed"),  # max foot speed over the preceding 50 ms [m/s]
)


@dataclass
class Recording:
    """What a rollout keeps as it runs besides its states: replay frames (30 fps), raw samples, falls, assist."""

    x_start: float  # torso x at the start (m)
    frames: list[list[float]] = field(default_factory=list)  # qpos per replay frame
    raw: list[list[float]] = field(default_factory=list)  # qpos + qvel per raw sample (40 Hz): the raw view
    fall_reason: str = ""  # empty while standing
    assist_sq: float = 0.0  # sum over physics steps of the assist's vertical force squared (N²)
    n_steps: int = 0  # physics steps simulated
    _peaks: list[float] = field(init=False, default_factory=lambda: [0.0, 0.0])  # foot peak speeds since the last state
    _next_frame: int = field(init=False, default=0)  # physics step of the next replay frame

    def record(self, step: int, physics: WalkerPhysics, keep: bool) -> list[float]:
        """Physics step ``step``'s state (STATE_FEATURES: the foot peak speeds since the last state sample); its
        replay frame and raw sample are kept when ``keep``."""
        (sp_r, sp_l), peaks = physics.foot_speeds(), self._peaks
        if sp_r > peaks[0]:
            peaks[0] = sp_r
        if sp_l > peaks[1]:
            peaks[1] = sp_l
        if keep and step == self._next_frame:
            self.frames.append(physics.qpos())
            self._next_frame = round(len(self.frames) / FRAME_RATE / physics.timestep())
        if keep and step % RAW_EVERY == 0:
            self.raw.append(physics.qpos() + physics.qvel())
        state = state_features(physics, peaks[0], peaks[1], self.x_start)
        if step % STATE_EVERY == 0:
            peaks[:] = [0.0, 0.0]
        return state

    def check_fall(self, physics: WalkerPhysics) -> None:
        """Fallen: the torso low or pitched, or the torso or a thigh touching the floor."""
        if self.fall_reason:
            return
        if physics.torso_height() < MIN_TORSO_HEIGHT or abs(physics.torso_pitch()) >= MAX_PITCH:
            self.fall_reason = "torso low or pitched"
        elif physics.thigh_lowest_point() < 0.0 or physics.torso_lowest_point() < 0.0:
            self.fall_reason = "torso/thigh floor contact"

    def count(self, assist_z: float) -> None:
        """One physics step simulated, with ``assist_z`` N of vertical assist."""
        self.assist_sq += assist_z * assist_z
        self.n_steps += 1


def state_features(physics: WalkerPhysics, peak_r: float, peak_l: float, x_start: float) -> list[float]:
    """One state, in STATE_FEATURES order."""
    torso_x, torso_z = physics.torso_x(), physics.torso_height()
    (rfx, rfz), (lfx, lfz) = physics.foot_positions()
    return [
        torso_z, physics.torso_pitch(), torso_x - x_start, *physics.torso_velocity(),
        *physics.joint_angles(), *physics.joint_velocities(),
        rfx - torso_x, rfz - torso_z, lfx - torso_x, lfz - torso_z,
        *physics.foot_velocities(),
        *physics.foot_clearances(),
        peak_r, peak_l,
    ]  # fmt: skip


@dataclass(frozen=True)
class Measurement:
    proxies: dict[str, float]
    success: bool
    info: dict[str, float]


def measure(recording: Recording, touchdowns: list[Touchdown], plan: GaitPlan, weight: float,
            dt: float) -> Measurement:
    """Proxies (over the later two touchdowns), success and diagnostics of a finished rollout."""
    fallen = bool(recording.fall_reason)
    steps_taken = len(touchdowns) == N_STEPS and not any(td.forced for td in touchdowns)
    info = {
        "n_touchdowns": float(len(touchdowns)),
        "fallen": float(fallen),
        "assist_rms_vertical_frac": math.sqrt(recording.assist_sq / max(recording.n_steps, 1)) / weight,
        "duration_s": recording.n_steps * dt,
        "hip_height_plan_m": plan.hip_height,
        "lean_plan_rad": plan.lean,
    }
    for i, td in enumerate(touchdowns):
        info[f"touchdown{i}_t_s"] = td.t
        info[f"touchdown{i}_feet_distance_m"] = td.feet_distance
        info[f"touchdown{i}_landing_speed_mps"] = td.landing_speed
    if fallen:
        info["fall_reason_" + recording.fall_reason.replace(" ", "_").replace("/", "_")] = 1.0
    return Measurement(touchdown_proxies(touchdowns), steps_taken and not fallen, info)


def observed_touchdowns(observations: np.ndarray, dt: float) -> list[Touchdown]:
    """The touchdowns of any policy's episode from its per-physics-step observations (``STATE_FEATURES``): a foot
    lifted above ``LIFT`` whose clearance then drops below 0, measured as ``GaitController`` measures its own (feet
    distance then, the foot's peak speed over ``LANDING_WINDOW``); never ``forced``."""
    obs = np.asarray(observations, dtype=np.float64)
    f = {name: i for i, name in enumerate(STATE_FEATURES)}
    clearance = obs[:, [f["right_foot_clearance"], f["left_foot_clearance"]]]
    speed = np.hypot(obs[:, [f["right_foot_vx"], f["left_foot_vx"]]], obs[:, [f["right_foot_vz"], f["left_foot_vz"]]])
    distance = np.abs(obs[:, f["right_foot_dx"]] - obs[:, f["left_foot_dx"]])
    window = round(LANDING_WINDOW / dt)
    lifted, touchdowns = [False, False], []
    for k, row in enumerate(clearance):
        for foot in (0, 1):
            if row[foot] > LIFT:
                lifted[foot] = True
            elif row[foot] < 0.0 and lifted[foot]:
                lifted[foot] = False
                peak = float(speed[max(0, k - window + 1): k + 1, foot].max())
                touchdowns.append(Touchdown(k * dt, float(distance[k]), peak, False))
    return touchdowns


def touchdown_proxies(touchdowns: list[Touchdown]) -> dict[str, float]:
    """The attributes' proxies: feet distance and minus the landing speed, means over the later two touchdowns."""
    later = touchdowns[1:] if len(touchdowns) > 1 else touchdowns
    if not later:
        return {"step_size": 0.0, "softness": -0.0}
    return {"step_size": float(np.mean([td.feet_distance for td in later])),
            "softness": -float(np.mean([td.landing_speed for td in later]))}



def walker_overlays(right: np.ndarray, left: np.ndarray, frame_rate: float) -> list[Overlay]:
    """The page's overlays from the foot geoms' tracks (centre x, y and lowest z per frame, float[F, 3] each): a
    footprint at each touchdown with the stride (feet distance) then, and the landing speed (the foot's peak speed
    over ``LANDING_WINDOW`` before it). Touchdowns are read off the frames (a foot on the floor lifted
    ``STEP_LIFT`` above it, then back within ``LIFT``), so the texts are frame-rate readings of what the proxies
    measure at the physics rate."""
    feet = np.stack([right, left])  # [2, F, 3]
    low = feet[..., 2]  # each foot's lowest point; the floor is at z = 0
    speed = np.zeros(low.shape)
    speed[:, 1:] = np.linalg.norm(np.diff(feet, axis=1), axis=2) * frame_rate
    window = max(1, round(LANDING_WINDOW * frame_rate))
    prints, landings, lifted, stood = [], [], [False, False], [False, False]
    for k in range(low.shape[1]):
        for foot in (0, 1):
            if low[foot, k] > STEP_LIFT:
                lifted[foot] = stood[foot]  # a step starts from the floor: the clip's first settling is none
            elif low[foot, k] < LIFT:
                stood[foot] = True
                if not lifted[foot]:
                    continue
                lifted[foot] = False
                x, y, z = feet[foot, k]
                stride = abs(feet[0, k, 0] - feet[1, k, 0])
                prints.append(Marker(k, (float(x), float(y), float(z)), f"{stride:.2f} m"))
                peak = speed[foot, max(1, k - window + 1): k + 1].max(initial=0.0)
                landings.append(Marker(k, (float(x), float(y), float(z)), f"≈ {peak:.2f} m/s"))
    return [Overlay("step_size", "Footprints and stride length at each touchdown", tuple(prints),
                    tuple(m.pos for m in prints) or None),
            Overlay("softness", "Landing speed at each touchdown (lower is softer)", tuple(landings))]
