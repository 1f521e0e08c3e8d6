"""The walker's skill: three scripted steps, made by a gait controller on the physics' named getters.

Skill
-----
The walker starts standing with its feet together and takes three alternating steps
(right, left, right) of commanded length ``step_length``; the first step covers L from
feet-together, the later swings cover 2L. Every physics step (2.5 ms) a Python PD
controller tracks joint targets from planar inverse kinematics:

* stance legs: IK from each planted ankle to the *planned* hip position, so the stance
  PD pushes the body along a planned hip path (the hip reaches the midpoint between the
  feet by the end of each swing; for long steps the hip is lowered and the torso leans
  forward so the trailing leg stays inside the −20° hip-extension limit);
* swing leg: IK from the *actual* hip to a swing-foot path: lift, travel (duration
  ``swing_duration`` + 0.4 s per metre travelled) at clearance ``swing_height``, then hover
  6 cm above the floor until the foot is slow, then descend at the constant commanded
  ``landing_speed`` toward a point 3 cm below the floor (so the commanded speed is what
  the foot has when it touches down); feet are kept flat through the ankle targets;
* feed-forward torques: Jacobian-transpose weight support on each stance leg (its share
  of body weight, split in double support by where the hip is) and MuJoCo's bias forces
  (gravity, Coriolis) on the swing leg. Torques go through the model's motors, clipped to
  their gear limits (hip 100, knee 50, ankle 20 N·m).

Assist
------
Without help the scripted gait falls before the first touchdown, so the torso is
assisted: spring-dampers on the root degrees of freedom (``data.qfrc_applied`` on
rootz/rootx/rooty) pull the torso toward the planned path: 4000 N/m & 300 N·s/m on
height, 3000 N/m & 300 N·s/m horizontally and 800 N·m/rad & 60 N·m·s/rad on pitch. With
the gait tracking well the assist is small: its vertical force is typically ≈ 10-15 % of
body weight (RMS) — see ``Rollout.info['assist_rms_vertical_frac']``. It keeps balance;
the legs carry the body and produce the steps and landings.

Code
----
:class:`GaitPlan` is what the parameters command; a :class:`GaitController`'s ``control(t, physics)`` gives each
physics step's :class:`Command`; :func:`start` puts the walker in the plan's start pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from rba.domains.walker.physics import WalkerGeometry, WalkerPhysics, WalkerReading

# ---------------------------------------------------------------- controller constants
KP_HIP, KP_KNEE, KP_ANKLE = 600.0, 400.0, 100.0  # joint stiffness (N·m/rad)
KD_HIP, KD_KNEE, KD_ANKLE = 30.0, 20.0, 4.0  # joint damping (N·m·s/rad)
ASSIST_KZ, ASSIST_DZ = 4000.0, 300.0  # torso height spring (N/m), damper (N·s/m)
ASSIST_KX, ASSIST_DX = 3000.0, 300.0  # torso horizontal spring (N/m), damper (N·s/m)
ASSIST_KP, ASSIST_DP = 800.0, 60.0  # torso pitch spring (N·m/rad), damper (N·m·s/rad)
HIP_HEIGHT_MAX = 0.90  # planned hip height for short steps (m)
LEG_REACH = 0.90  # planned hip-to-ankle distance in double support (m), < 0.95 (straight)
MAX_LEAN = 0.16  # forward torso lean for the longest steps (rad)
LEAN_FULL_STEP = 1.2  # step length at which the lean is MAX_LEAN (m)
HOVER_CLEARANCE = 0.06  # foot height above the floor where the descent starts (m)
HOVER_SLOW = 0.15  # foot speed below which the hover ends (m/s)
HOVER_MIN, HOVER_MAX = 0.05, 0.4  # hover duration bounds (s)
DESCENT_DEPTH = 0.03  # the descent aims this far below the floor (m)
DESCENT_TIMEOUT = 1.5  # give up on a touchdown after this long (s)
SWING_PER_METRE = 0.4  # extra swing time per metre travelled (s/m)
SETTLE_TIME = 0.3  # standing before the first step (s)
DOUBLE_SUPPORT = 0.25  # double support between steps (s)
WEIGHT_SHIFT = 0.12  # last part of double support where the weight moves off the next swing foot (s)
FINAL_STAND = 0.6  # standing after the last touchdown (s)
N_STEPS = 3  # steps per clip
LANDING_WINDOW = 0.05  # window before touchdown for the landing speed (s)
INIT_JOINT_NOISE = 0.02  # seed-dependent initial joint perturbation, std (rad)
INIT_VEL_NOISE = 0.05  # seed-dependent initial joint velocity perturbation, std (rad/s)
# phases of the gait
STAND, TRAVEL, HOVER, DESCENT, FINAL = 0, 1, 2, 3, 4  # settle/double support, swing travel, ..., final stand
SWINGING = (TRAVEL, HOVER, DESCENT)

# the skill's parameters, which GaitPlan.from_params reads
PARAM_RANGES = {
    "step_length": (0.12, 1.0),  # commanded step length (m)
    "landing_speed": (0.1, 1.4),  # commanded descent speed of the landing foot (m/s)
    "swing_duration": (0.4, 0.8),  # base swing duration (s), +0.4 s per metre travelled
    "swing_height": (0.06, 0.15),  # swing foot clearance at mid swing (m)
}


def _smooth(u: float) -> tuple[float, float]:
    """Smoothstep on [0, 1] (clipped) and its derivative w.r.t. u."""
    if u <= 0.0:
        return 0.0, 0.0
    if u >= 1.0:
        return 1.0, 0.0
    return u * u * (3.0 - 2.0 * u), 6.0 * u * (1.0 - u)


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else (hi if x > hi else x)


@dataclass(frozen=True, slots=True)
class GaitPlan:
    """The commanded gait (from the skill parameters) and what follows from it for the whole clip."""

    step_length: float  # m
    landing_speed: float  # m/s
    swing_duration: float  # s, before SWING_PER_METRE
    swing_height: float  # m
    lean: float  # planned forward torso lean (rad)
    hip_height: float  # planned hip height (m)
    ground_ankle_z: float  # ankle height of a flat foot on the floor (m)

    @classmethod
    def from_params(cls, params: dict[str, float], geometry: WalkerGeometry) -> GaitPlan:
        """Long steps lower the hip (the trailing leg stays inside its hip limit) and lean the torso forward."""
        step_len = float(params["step_length"])
        half = 0.5 * step_len
        ground = geometry.ground_ankle_z
        return cls(
            step_length=step_len,
            landing_speed=float(params["landing_speed"]),
            swing_duration=float(params["swing_duration"]),
            swing_height=float(params["swing_height"]),
            lean=MAX_LEAN * min(1.0, step_len / LEAN_FULL_STEP),
            hip_height=min(HIP_HEIGHT_MAX, ground + math.sqrt(max(LEG_REACH**2 - half * half, 0.25))),
            ground_ankle_z=ground,
        )

    @property
    def hover_z(self) -> float:
        """Swing ankle height where the hover before the descent holds it (m)."""
        return self.ground_ankle_z + HOVER_CLEARANCE

    @property
    def floor_target(self) -> float:
        """Ankle height the descent aims for, below the floor (m)."""
        return self.ground_ankle_z - DESCENT_DEPTH

    @property
    def peak_z(self) -> float:
        """Swing ankle height at mid swing (m)."""
        return self.ground_ankle_z + max(self.swing_height, HOVER_CLEARANCE)

    def start_pose(self, geometry: WalkerGeometry) -> list[float]:
        """qpos standing with the feet together, the foot centres under the hip at x = 0."""
        a, b = geometry.leg_ik(-geometry.ankle_to_foot, self.ground_ankle_z - self.hip_height)
        lean = self.lean
        q0 = [self.hip_height + geometry.torso_to_hip * math.cos(lean) - geometry.torso_z0,
              geometry.torso_to_hip * math.sin(lean), lean]
        return q0 + [a + lean, b - a, -b] * 2


@dataclass(frozen=True)
class Touchdown:
    """A swing foot's landing."""

    t: float  # s
    feet_distance: float  # horizontal distance between the foot centres (m)
    landing_speed: float  # the swing foot's peak speed in the LANDING_WINDOW before (m/s)
    forced: bool  # the descent timed out instead of touching the floor


class Command(NamedTuple):
    """One physics step's action: normalised motor commands and the torso assist's forces."""

    ctrl: tuple[float, ...]  # right hip, knee, ankle, left hip, knee, ankle, in [-1, 1]
    assist: tuple[float, float, float]  # rootz force (N), rootx force (N), rooty torque (N·m)


class GaitController:
    """Three scripted steps: the phase machine, the planned hip path, IK + PD on the legs, the torso assist.

    ``control(t, physics)`` is called once per physics step (after ``physics.observe()``); it
    advances the phases, records touchdowns and returns the step's :class:`Command`.
    """

    def __init__(self, plan: GaitPlan, physics: WalkerReading) -> None:
        self.plan = plan
        self.touchdowns: list[Touchdown] = []
        self.t_end: float | None = None  # set at the last touchdown: the clip ends FINAL_STAND later
        self._geo = physics.geometry
        self._weight = physics.body_weight()
        self._landing_window = round(LANDING_WINDOW / physics.timestep())  # physics steps
        self._hover_z, self._floor_target, self._peak_z = plan.hover_z, plan.floor_target, plan.peak_z
        self._cos_lean, self._sin_lean = math.cos(plan.lean), math.sin(plan.lean)
        self._phase, self._phase_t0 = STAND, 0.0
        self._step_i = 0  # index of the next / current step
        self._swing = 0  # the swing (or next swing) leg: 0 right, 1 left
        self._sw_x0 = self._sw_z0 = self._sw_xT = 0.0  # swing ankle start (x, z) and landing x
        self._swing_t0, self._swing_dur = 0.0, 1.0
        self._desc_z0 = 0.0
        self._hip_from = self._hip_to = 0.0  # planned hip x at the start and end of the swing
        self._hip_xd = self._hip_vd = 0.0  # planned hip x and its velocity now
        self._speeds: list[float] = []  # swing foot speed at each physics step of this swing

    def finished(self, t: float) -> bool:
        return self.t_end is not None and t >= self.t_end

    def control(self, t: float, physics: WalkerReading) -> Command:
        self._advance(t, physics)
        in_swing = self._phase in SWINGING
        if in_swing:
            s, ds = _smooth((t - self._swing_t0) / self._swing_dur)
            self._hip_xd = self._hip_from + (self._hip_to - self._hip_from) * s
            self._hip_vd = (self._hip_to - self._hip_from) * ds / self._swing_dur
        else:
            self._hip_vd = 0.0
        target = self._swing_target(t) if in_swing else None
        share_r = self._right_share(t, physics, in_swing)
        ctrl = self._leg(0, physics, target, share_r) + self._leg(1, physics, target, 1.0 - share_r)
        return Command(ctrl, self._assist(physics))

    # ---------------------------------------------------------------- phase machine
    def _wait(self) -> float:
        """Standing time before the next swing."""
        return SETTLE_TIME if self._step_i == 0 else DOUBLE_SUPPORT

    def _advance(self, t: float, physics: WalkerReading) -> None:
        speed = physics.foot_speeds()
        if self._phase == STAND and self._step_i < N_STEPS and t - self._phase_t0 >= self._wait():
            self._start_swing(t, physics)
        if self._phase in SWINGING:
            self._speeds.append(speed[self._swing])
        if self._phase == TRAVEL and t - self._swing_t0 >= self._swing_dur:
            self._phase, self._phase_t0 = HOVER, t
        if self._phase == HOVER:
            dt_h = t - self._phase_t0
            if (dt_h >= HOVER_MIN and speed[self._swing] < HOVER_SLOW) or dt_h >= HOVER_MAX:
                self._phase, self._phase_t0 = DESCENT, t
                self._desc_z0 = self._hover_z
        if self._phase == DESCENT:
            forced = t - self._phase_t0 >= DESCENT_TIMEOUT
            if physics.foot_clearances()[self._swing] < 0.0 or forced:
                self._touch_down(t, physics, forced)

    def _start_swing(self, t: float, physics: WalkerReading) -> None:
        """Lift the next swing foot: it lands step_length ahead of the stance foot (of the start for step 0)."""
        swing = self._swing = self._step_i % 2
        self._phase, self._phase_t0 = TRAVEL, t
        ankles = physics.ankle_positions()
        self._sw_x0, self._sw_z0 = ankles[swing]
        st_x = ankles[1 - swing][0]
        self._sw_xT = (-self._geo.ankle_to_foot if self._step_i == 0 else st_x) + self.plan.step_length
        self._swing_dur = self.plan.swing_duration + SWING_PER_METRE * abs(self._sw_xT - self._sw_x0)
        self._swing_t0 = t
        # the hip ends the swing over the feet's midpoint
        self._hip_from, self._hip_to = self._hip_xd, 0.5 * (st_x + self._sw_xT) + self._geo.ankle_to_foot
        self._speeds = []

    def _touch_down(self, t: float, physics: WalkerReading, forced: bool) -> None:
        peak = max(self._speeds[-self._landing_window:]) if self._speeds else 0.0
        (rfx, _), (lfx, _) = physics.foot_positions()
        self.touchdowns.append(Touchdown(t, abs(rfx - lfx), peak, forced))
        self._step_i += 1
        self._phase, self._phase_t0 = (STAND, t) if self._step_i < N_STEPS else (FINAL, t)
        if self._phase == FINAL:
            self.t_end = t + FINAL_STAND

    # ---------------------------------------------------------------- targets
    def _swing_target(self, t: float) -> tuple[float, float, float, float]:
        """Swing ankle target x, vx, z, vz: lift, travel at clearance, hover, then a constant-speed descent."""
        x0, xT = self._sw_x0, self._sw_xT
        if self._phase == HOVER:
            return xT, 0.0, self._hover_z, 0.0
        if self._phase == DESCENT:
            tz, tvz = self._desc_z0 - self.plan.landing_speed * (t - self._phase_t0), -self.plan.landing_speed
            return (xT, 0.0, self._floor_target, 0.0) if tz <= self._floor_target else (xT, 0.0, tz, tvz)
        dur, z0, peak, hover = self._swing_dur, self._sw_z0, self._peak_z, self._hover_z
        u = (t - self._swing_t0) / dur
        sx, dsx = _smooth((u - 0.15) / 0.85)
        tx = x0 + (xT - x0) * sx
        tvx = (xT - x0) * dsx / (0.85 * dur)
        if u < 0.3:
            sz, dsz = _smooth(u / 0.3)
            return tx, tvx, z0 + (peak - z0) * sz, (peak - z0) * dsz / (0.3 * dur)
        if u < 0.65:
            return tx, tvx, peak, 0.0
        sz, dsz = _smooth((u - 0.65) / 0.35)
        return tx, tvx, peak + (hover - peak) * sz, (hover - peak) * dsz / (0.35 * dur)

    def _right_share(self, t: float, physics: WalkerReading, in_swing: bool) -> float:
        """The right leg's share of the body weight: by where the planned hip is between the ankles,
        moved off the next swing foot in the last WEIGHT_SHIFT of double support."""
        if in_swing:
            return 0.0 if self._swing == 0 else 1.0
        (rax, _), (lax, _) = physics.ankle_positions()
        span = rax - lax
        share_r = 0.5 if abs(span) < 0.05 else _clip((self._hip_xd - lax) / span, 0.0, 1.0)
        if self._phase == STAND and self._step_i < N_STEPS:
            left_t = self._wait() - (t - self._phase_t0)
            if left_t < WEIGHT_SHIFT:  # unload the next swing foot
                f = max(left_t, 0.0) / WEIGHT_SHIFT
                share_r = share_r * f if self._step_i % 2 == 0 else 1.0 - (1.0 - share_r) * f
        return share_r

    # ---------------------------------------------------------------- torques
    def _leg(self, leg: int, physics: WalkerReading, target: tuple[float, float, float, float] | None,
             share: float) -> tuple[float, float, float]:
        """Motor commands of one leg: PD toward IK targets plus feed-forward, clipped to the gears.

        The swing leg reaches from the actual hip to ``target`` (feed-forward: the bias forces);
        a stance leg reaches from its planted ankle to the planned hip (feed-forward: its ``share``
        of the body weight, through the Jacobian transpose)."""
        geo, plan, j = self._geo, self.plan, 3 * leg
        if target is not None and leg == self._swing:
            tx, tvx, tz, tvz = target
            hx, hz = physics.hip_position()
            al, be = geo.leg_ik(tx - hx, tz - hz)
            da, db = geo.leg_rates(al, be, tvx - self._hip_vd, tvz)
            qh = al + physics.torso_pitch()
            ff = physics.bias_forces()[j:j + 3]
        else:
            ankx, ankz = physics.ankle_positions()[leg]
            dx, dz = ankx - self._hip_xd, ankz - plan.hip_height
            al, be = geo.leg_ik(dx, dz)
            da, db = geo.leg_rates(al, be, -self._hip_vd, 0.0)
            qh = al + plan.lean
            w = self._weight * share
            ff = (-w * dx, -w * geo.shank * math.sin(be), 0.0)
        q, v = physics.joint_angles(), physics.joint_velocities()
        (lo_h, lo_k, lo_a), (hi_h, hi_k, hi_a) = geo.joint_low, geo.joint_high
        # clipped inline, as below: this runs twice per physics step
        qh = lo_h if qh < lo_h else (hi_h if qh > hi_h else qh)
        qk = be - al
        qk = lo_k if qk < lo_k else (hi_k if qk > hi_k else qk)
        qa = -be
        qa = lo_a if qa < lo_a else (hi_a if qa > hi_a else qa)
        gear_h, gear_k, gear_a = geo.gear
        th_h = (KP_HIP * (qh - q[j]) + KD_HIP * (da - v[j]) + ff[0]) / gear_h
        th_k = (KP_KNEE * (qk - q[j + 1]) + KD_KNEE * ((db - da) - v[j + 1]) + ff[1]) / gear_k
        th_a = (KP_ANKLE * (qa - q[j + 2]) + KD_ANKLE * (-db - v[j + 2]) + ff[2]) / gear_a
        return (-1.0 if th_h < -1.0 else (1.0 if th_h > 1.0 else th_h),
                -1.0 if th_k < -1.0 else (1.0 if th_k > 1.0 else th_k),
                -1.0 if th_a < -1.0 else (1.0 if th_a > 1.0 else th_a))

    def _assist(self, physics: WalkerReading) -> tuple[float, float, float]:
        """Spring-dampers pulling the torso toward the planned path (height, x, pitch)."""
        plan, to_hip = self.plan, self._geo.torso_to_hip
        vz, vx, vpitch = physics.torso_velocity()
        tz_d = plan.hip_height + to_hip * self._cos_lean
        tx_d = self._hip_xd + to_hip * self._sin_lean
        fz = ASSIST_KZ * (tz_d - physics.torso_height()) - ASSIST_DZ * vz
        fx = ASSIST_KX * (tx_d - physics.torso_x()) + ASSIST_DX * (self._hip_vd - vx)
        tp = ASSIST_KP * (plan.lean - physics.torso_pitch()) - ASSIST_DP * vpitch
        return fz, fx, tp


def start(physics: WalkerPhysics, params: dict[str, float], seed: int) -> GaitPlan:
    """Reset ``physics`` to the skill's start (standing for the gait ``params`` plan, perturbed by ``seed``)."""
    plan = GaitPlan.from_params(params, physics.geometry)
    rng = np.random.default_rng(seed)  # a small seed-dependent perturbation of the start
    pose = np.array(plan.start_pose(physics.geometry)) + np.concatenate([[0.0] * 3,
                                                                          rng.normal(0.0, INIT_JOINT_NOISE, 6)])
    physics.reset(pose, np.concatenate([[0.0] * 3, rng.normal(0.0, INIT_VEL_NOISE, 6)]))
    return plan
