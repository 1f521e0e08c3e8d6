"""The walker domain: dm_control's planar ``walker`` taking three scripted steps.

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

Attributes (proxies grow with the attribute)
--------------------------------------------
* ``step_size``: horizontal distance between the two foot geom centres at touchdown
  (first foot–floor contact of the descending foot), mean over the later two steps.
* ``softness``: minus the swing foot's peak speed in the last 50 ms before touchdown,
  mean over the later two steps.

Code (dm_control suite style)
-----------------------------
:class:`WalkerGeometry` holds the dimensions read from the MuJoCo model; :class:`WalkerPhysics`
wraps model and data with named getters (``torso_height()``, ``hip_position()``,
``foot_positions()``...); :class:`GaitPlan` is what the parameters command; a
:class:`GaitController`'s ``control(t, physics)`` gives each physics step's :class:`Command`;
:class:`WalkerSim` steps the physics under those commands and records (:class:`Recording`), and :func:`measure`
turns the recording into proxies, success and diagnostics. The rollout is ``run_skill`` of the sim and a
:class:`GaitPolicy` reading the sim's own physics; :class:`WalkerSkillPolicy` (the last section) is the same
gait reading observations alone, for ``rba.gym``: one loop, two readers. The raw view gets no env: that
policy reads the feature view's observations (foot positions and speeds), which raw states do not hold.
"""


from __future__ import annotations

import math
import os
from types import MappingProxyType

os.environ.setdefault("MUJOCO_GL", "egl")

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

import mujoco
import numpy as np

from rba.domains.base import (
    ALL_FRAMES,
    AttributeSpec,
    Domain,
    FeedbackPhrases,
    ParamSpace,
    Reading,
    Rollout,
    SkillPolicy,
    SkillSim,
    run_skill,
    stack_samples,
)
from rba.domains.mujoco_render import Camera, Sky, ThreadRenderers

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
MAX_DURATION = 40.0  # s: a clip ends here even if the gait never finishes
# phases of the gait
STAND, TRAVEL, HOVER, DESCENT, FINAL = 0, 1, 2, 3, 4  # settle/double support, swing travel, ..., final stand
SWINGING = (TRAVEL, HOVER, DESCENT)

# ---------------------------------------------------------------- fall / success criteria
MIN_TORSO_HEIGHT = 0.7  # torso centre height (m)
MAX_PITCH = 1.0  # |torso pitch| (rad)

# ---------------------------------------------------------------- sampling & recording
STATE_EVERY = 40  # physics steps per state sample (10 Hz: foot speed features carry the fast part)
RAW_EVERY = 10  # physics steps per raw sample (40 Hz): the raw view stacks STATE_EVERY // RAW_EVERY per state
FRAME_RATE = 30.0  # replay / rendered frames per second

PARAM_RANGES = {
    "step_length": (0.12, 1.0),  # commanded step length (m)
    "landing_speed": (0.1, 1.4),  # commanded descent speed of the landing foot (m/s)
    "swing_duration": (0.4, 0.8),  # base swing duration (s), +0.4 s per metre travelled
    "swing_height": (0.06, 0.15),  # swing foot clearance at mid swing (m)
}

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
LEG_JOINTS = ("right_hip", "right_knee", "right_ankle", "left_hip", "left_knee", "left_ankle")


def _smooth(u: float) -> tuple[float, float]:
    """Smoothstep on [0, 1] (clipped) and its derivative w.r.t. u."""
    if u <= 0.0:
        return 0.0, 0.0
    if u >= 1.0:
        return 1.0, 0.0
    return u * u * (3.0 - 2.0 * u), 6.0 * u * (1.0 - u)


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else (hi if x > hi else x)


# ---------------------------------------------------------------- the model and its named quantities
@dataclass(frozen=True, slots=True)
class WalkerGeometry:
    """The walker's dimensions (m), joint limits (rad) and motor gears (N·m), read from the MuJoCo model.

    Each is the model's own number for the XML value (``body_pos``, ``geom_size``, ``jnt_pos``,
    ``jnt_range``, ``actuator_gear``), so the planar kinematics below compute exactly what they did
    with the XML's numbers typed in: MuJoCo's own ``geom_xpos`` differs in the last bits (quaternion
    composition), and the feedback controller amplifies such bits into different rollouts.
    """

    torso_z0: float  # torso body height when rootz = 0
    torso_to_hip: float  # torso centre down to the hip joints
    thigh: float  # hip to knee: the thigh capsule spans it
    shank: float  # knee to ankle: the leg capsule spans it
    ankle_to_foot: float  # ankle joint to foot geom centre, along the foot
    foot_radius: float
    foot_half: float  # foot capsule half-length
    thigh_radius: float
    torso_radius: float
    torso_half: float  # torso capsule half-length
    joint_low: tuple[float, float, float]  # hip, knee, ankle
    joint_high: tuple[float, float, float]
    gear: tuple[float, float, float]  # motor gear = torque limit (hip, knee, ankle)

    @classmethod
    def from_model(cls, model: mujoco.MjModel) -> WalkerGeometry:
        def idx(kind: mujoco.mjtObj, name: str) -> int:
            return mujoco.mj_name2id(model, kind, name)

        body, geom, joint = mujoco.mjtObj.mjOBJ_BODY, mujoco.mjtObj.mjOBJ_GEOM, mujoco.mjtObj.mjOBJ_JOINT
        legs = [idx(joint, j) for j in LEG_JOINTS[:3]]
        motors = [idx(mujoco.mjtObj.mjOBJ_ACTUATOR, j) for j in LEG_JOINTS[:3]]
        return cls(
            torso_z0=float(model.body_pos[idx(body, "torso"), 2]),
            torso_to_hip=-float(model.body_pos[idx(body, "right_thigh"), 2]),
            thigh=2.0 * float(model.geom_size[idx(geom, "right_thigh"), 1]),
            shank=2.0 * float(model.geom_size[idx(geom, "right_leg"), 1]),
            ankle_to_foot=-float(model.jnt_pos[idx(joint, "right_ankle"), 0]),
            foot_radius=float(model.geom_size[idx(geom, "right_foot"), 0]),
            foot_half=float(model.geom_size[idx(geom, "right_foot"), 1]),
            thigh_radius=float(model.geom_size[idx(geom, "right_thigh"), 0]),
            torso_radius=float(model.geom_size[idx(geom, "torso"), 0]),
            torso_half=float(model.geom_size[idx(geom, "torso"), 1]),
            joint_low=tuple(float(model.jnt_range[j, 0]) for j in legs),
            joint_high=tuple(float(model.jnt_range[j, 1]) for j in legs),
            gear=tuple(float(model.actuator_gear[m, 0]) for m in motors),
        )

    @property
    def ground_ankle_z(self) -> float:
        """Ankle height of a flat foot on the floor."""
        return self.foot_radius

    def leg_ik(self, dx: float, dz: float) -> tuple[float, float]:
        """Absolute thigh and shank angles (rad, from the downward vertical, + = forward) that
        put the ankle at (dx, dz) from the hip, knee bending forward."""
        thigh, shank = self.thigh, self.shank
        d2 = dx * dx + dz * dz
        dmax = thigh + shank - 1e-4
        if d2 > dmax * dmax:
            scale = dmax / math.sqrt(d2)
            dx, dz, d2 = dx * scale, dz * scale, dmax * dmax
        c = (d2 - thigh * thigh - shank * shank) / (2.0 * thigh * shank)
        c = 1.0 if c > 1.0 else (-1.0 if c < -1.0 else c)
        bend = math.acos(c)  # = -knee angle
        psi = math.atan2(dx, -dz)
        alpha = psi + math.atan2(shank * math.sin(bend), thigh + shank * c)
        return alpha, alpha - bend

    def leg_rates(self, alpha: float, beta: float, vx: float, vz: float) -> tuple[float, float]:
        """Absolute thigh/shank angular rates that move the ankle at (vx, vz) relative to the hip."""
        thigh, shank = self.thigh, self.shank
        ca, sa, cb, sb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
        det = thigh * shank * (ca * sb - sa * cb)
        if abs(det) < 0.02:  # near-straight knee: avoid the singularity
            det = 0.02 if det >= 0 else -0.02
        # J = [[L1 ca, L2 cb], [L1 sa, L2 sb]]
        da = (shank * sb * vx - shank * cb * vz) / det
        db = (-thigh * sa * vx + thigh * ca * vz) / det
        return da, db

    def kinematics(self, rootz: float, rootx: float, pitch: float, joints: list[float]) -> tuple[float, ...]:
        """Planar forward kinematics: hip x, z, then per foot (right, left) ankle x, z, foot-centre
        x, z and clearance (lowest point of the capsule above the floor). ``joints`` as LEG_JOINTS."""
        to_hip, thigh, shank, to_foot = self.torso_to_hip, self.thigh, self.shank, self.ankle_to_foot
        sin, cos = math.sin, math.cos
        th = pitch
        hx = rootx - to_hip * sin(th)
        hz = self.torso_z0 + rootz - to_hip * cos(th)
        out = [hx, hz]
        for j in (0, 3):
            a = joints[j] - th
            b = a + joints[j + 1]
            g = b + joints[j + 2]
            ax = hx + thigh * sin(a) + shank * sin(b)
            az = hz - thigh * cos(a) - shank * cos(b)
            sg = sin(g)
            fx = ax + to_foot * cos(g)
            fz = az + to_foot * sg
            out += [ax, az, fx, fz, fz - self.foot_radius - self.foot_half * abs(sg)]
        return tuple(out)


class WalkerPhysics:
    """The walker's MuJoCo model and data with named getters, in the style of dm_control's suite.

    ``observe()`` reads the state once per physics step (qpos/qvel as Python floats, the planar
    kinematics, finite-difference foot velocities); the getters answer from that reading, so the
    controller and the recorder see the same numbers.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, keep_alive: object = None) -> None:
        self.model, self.data = model, data
        self._keep_alive = keep_alive  # the dm_control Physics that owns model and data
        self.geometry = WalkerGeometry.from_model(model)
        joint = mujoco.mjtObj.mjOBJ_JOINT
        adr = [int(model.jnt_qposadr[mujoco.mj_name2id(model, joint, j)]) for j in ("rootz", "rootx", "rooty")]
        self._root: tuple[int, int, int] = (adr[0], adr[1], adr[2])
        self._legs = int(model.jnt_qposadr[mujoco.mj_name2id(model, joint, LEG_JOINTS[0])])
        legs = [int(model.jnt_qposadr[mujoco.mj_name2id(model, joint, j)]) for j in LEG_JOINTS]
        assert legs == list(range(self._legs, self._legs + 6)) and model.nq == model.nv, "walker joint layout"
        motors = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(model.nu)]
        assert tuple(motors) == LEG_JOINTS, "walker motors: one per leg joint, in LEG_JOINTS order"
        self._torso_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "torso")
        self._dt = float(model.opt.timestep)
        # views into data, made once: each `data.qpos` makes a new array object (costly every step)
        self._qpos, self._qvel, self._ctrl = data.qpos, data.qvel, data.ctrl
        self._applied, self._bias = data.qfrc_applied, data.qfrc_bias
        self._q: list[float] = []
        self._v: list[float] = []
        self._joints: list[float] = []
        self._joint_vel: list[float] = []
        self._torso = self._torso_vel = (0.0, 0.0, 0.0)  # height, x, pitch and their rates
        self._hip = (0.0, 0.0)
        self._ankles = self._feet = ((0.0, 0.0), (0.0, 0.0))
        self._clearances = (0.0, 0.0)
        self._prev_feet: tuple[float, float, float, float] | None = None
        self._foot_vel = (0.0, 0.0, 0.0, 0.0)
        self._speeds = (0.0, 0.0)

    @classmethod
    def from_suite(cls) -> WalkerPhysics:
        from dm_control.suite import walker as suite_walker

        physics = suite_walker.Physics.from_xml_string(*suite_walker.get_model_and_assets())
        return cls(physics.model.ptr, physics.data.ptr, keep_alive=physics)

    # ---------------------------------------------------------------- stepping
    def reset(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """Start from ``qpos``/``qvel``, lowered so that the lower foot just touches the floor."""
        model, data = self.model, self.data
        mujoco.mj_resetData(model, data)
        data.qpos[:] = qpos
        data.qvel[:] = qvel
        mujoco.mj_forward(model, data)
        (iz, ix, iy), legs, q = self._root, self._legs, data.qpos.tolist()
        k0 = self.geometry.kinematics(q[iz], q[ix], q[iy], q[legs:legs + 6])
        data.qpos[self._root[0]] -= min(k0[6], k0[11]) + 1e-4
        mujoco.mj_forward(model, data)
        self._prev_feet, self._foot_vel = None, (0.0, 0.0, 0.0, 0.0)

    def observe(self) -> None:
        """Read this step's state; foot velocities are differences to the previous reading."""
        q, v = self._qpos.tolist(), self._qvel.tolist()
        self._q, self._v = q, v
        (iz, ix, iy), legs = self._root, self._legs
        self._joints, self._joint_vel = q[legs:legs + 6], v[legs:legs + 6]
        kin = self.geometry.kinematics(q[iz], q[ix], q[iy], self._joints)
        self._torso = (self.geometry.torso_z0 + q[iz], q[ix], q[iy])
        self._torso_vel = (v[iz], v[ix], v[iy])
        self._hip = (kin[0], kin[1])
        self._ankles = ((kin[2], kin[3]), (kin[7], kin[8]))
        self._feet = ((kin[4], kin[5]), (kin[9], kin[10]))
        self._clearances = (kin[6], kin[11])
        feet = (kin[4], kin[5], kin[9], kin[10])
        if self._prev_feet is not None:
            dt = self._dt
            prx, prz, plx, plz = self._prev_feet
            self._foot_vel = ((feet[0] - prx) / dt, (feet[1] - prz) / dt, (feet[2] - plx) / dt, (feet[3] - plz) / dt)
        self._prev_feet = feet
        vfr = self._foot_vel
        self._speeds = (math.hypot(vfr[0], vfr[1]), math.hypot(vfr[2], vfr[3]))

    def act(self, ctrl: tuple[float, ...], assist: tuple[float, float, float]) -> None:
        """Set the motor commands and the torso assist (rootz, rootx, rooty forces), then step."""
        ctrl_arr, applied = self._ctrl, self._applied
        ctrl_arr[0], ctrl_arr[1], ctrl_arr[2], ctrl_arr[3], ctrl_arr[4], ctrl_arr[5] = ctrl
        applied[self._root[0]], applied[self._root[1]], applied[self._root[2]] = assist
        mujoco.mj_step(self.model, self.data)

    def bias_at(self, q: list[float], v: list[float]) -> list[float]:
        """MuJoCo's bias forces on the leg joints at root z, x, pitch + leg angles ``q`` and their rates ``v``.

        Overwrites this physics' state: for a copy of the model that only answers this (a policy's own).
        """
        qpos, qvel, (iz, ix, iy), legs = self._qpos, self._qvel, self._root, self._legs
        qpos[iz], qpos[ix], qpos[iy] = q[:3]
        qvel[iz], qvel[ix], qvel[iy] = v[:3]
        qpos[legs:legs + 6], qvel[legs:legs + 6] = q[3:], v[3:]
        mujoco.mj_forward(self.model, self.data)
        return self._bias[legs:legs + 6].tolist()

    # ---------------------------------------------------------------- named quantities (of the last observe)
    def timestep(self) -> float:
        return self._dt

    def body_weight(self) -> float:
        """Weight of the whole walker (N)."""
        return float(self.model.body_subtreemass[self._torso_body]) * -float(self.model.opt.gravity[2])

    def qpos(self) -> list[float]:
        return self._q

    def qvel(self) -> list[float]:
        return self._v

    def joint_angles(self) -> list[float]:
        """Right hip, knee, ankle, left hip, knee, ankle (rad)."""
        return self._joints

    def joint_velocities(self) -> list[float]:
        return self._joint_vel

    def bias_forces(self) -> list[float]:
        """MuJoCo's bias forces (gravity, Coriolis) on the leg joints, in joint_angles' order."""
        return self._bias[self._legs:self._legs + 6].tolist()

    def torso_height(self) -> float:
        """Height of the torso centre (m)."""
        return self._torso[0]

    def torso_x(self) -> float:
        return self._torso[1]

    def torso_pitch(self) -> float:
        """Torso pitch (rad, + = forward)."""
        return self._torso[2]

    def torso_velocity(self) -> tuple[float, float, float]:
        """Torso vertical and horizontal speed (m/s) and pitch rate (rad/s)."""
        return self._torso_vel

    def hip_position(self) -> tuple[float, float]:
        """World (x, z) of the hip joints (m)."""
        return self._hip

    def ankle_positions(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """World (x, z) of the right and left ankle joints (m)."""
        return self._ankles

    def foot_positions(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """World (x, z) of the right and left foot geom centres (m)."""
        return self._feet

    def foot_clearances(self) -> tuple[float, float]:
        """Lowest point of each foot capsule above the floor (m)."""
        return self._clearances

    def foot_velocities(self) -> tuple[float, float, float, float]:
        """Right vx, vz, left vx, vz of the foot centres (m/s), by finite difference of physics steps."""
        return self._foot_vel

    def foot_speeds(self) -> tuple[float, float]:
        return self._speeds

    def thigh_lowest_point(self) -> float:
        """Lowest point of the thigh capsules above the floor (m): the hips or a knee."""
        geo, joints, th, hz = self.geometry, self._joints, self._torso[2], self._hip[1]
        knee_r = hz - geo.thigh * math.cos(joints[0] - th)
        knee_l = hz - geo.thigh * math.cos(joints[3] - th)
        return min(hz, knee_r, knee_l) - geo.thigh_radius

    def torso_lowest_point(self) -> float:
        """Lowest point of the torso capsule above the floor (m)."""
        geo = self.geometry
        return self._torso[0] - geo.torso_half * abs(math.cos(self._torso[2])) - geo.torso_radius


# ---------------------------------------------------------------- the gait
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

    def __init__(self, plan: GaitPlan, physics: WalkerPhysics) -> None:
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

    def control(self, t: float, physics: WalkerPhysics) -> Command:
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

    def _advance(self, t: float, physics: WalkerPhysics) -> None:
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

    def _start_swing(self, t: float, physics: WalkerPhysics) -> None:
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

    def _touch_down(self, t: float, physics: WalkerPhysics, forced: bool) -> None:
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

    def _right_share(self, t: float, physics: WalkerPhysics, in_swing: bool) -> float:
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
    def _leg(self, leg: int, physics: WalkerPhysics, target: tuple[float, float, float, float] | None,
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

    def _assist(self, physics: WalkerPhysics) -> tuple[float, float, float]:
        """Spring-dampers pulling the torso toward the planned path (height, x, pitch)."""
        plan, to_hip = self.plan, self._geo.torso_to_hip
        vz, vx, vpitch = physics.torso_velocity()
        tz_d = plan.hip_height + to_hip * self._cos_lean
        tx_d = self._hip_xd + to_hip * self._sin_lean
        fz = ASSIST_KZ * (tz_d - physics.torso_height()) - ASSIST_DZ * vz
        fx = ASSIST_KX * (tx_d - physics.torso_x()) + ASSIST_DX * (self._hip_vd - vx)
        tp = ASSIST_KP * (plan.lean - physics.torso_pitch()) - ASSIST_DP * vpitch
        return fz, fx, tp


# ---------------------------------------------------------------- recording and measuring
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


def touchdown_proxies(touchdowns: list[Touchdown]) -> dict[str, float]:
    """The attributes' proxies: feet distance and minus the landing speed, means over the later two touchdowns."""
    later = touchdowns[1:] if len(touchdowns) > 1 else touchdowns
    if not later:
        return {"step_size": 0.0, "softness": -0.0}
    return {"step_size": float(np.mean([td.feet_distance for td in later])),
            "softness": -float(np.mean([td.landing_speed for td in later]))}


# free-text feedback's anchors (rba.interpret): both sides written with the same nouns
FEEDBACK_PHRASES = MappingProxyType({
    "step_size": FeedbackPhrases(
        more=("longer steps", "big strides", "take long strides", "lengthen the stride", "stretch the legs out far",
              "wide steps", "large steps", "cover ground with each step"),
        less=("shorter steps", "small strides", "take short strides", "shorten the stride", "tiny steps",
              "little steps", "keep the legs close together", "shuffle"),
        names=("stride length", "step length")),
    "softness": FeedbackPhrases(
        more=("soft landings", "land gently", "gentle steps", "light footsteps", "tread lightly", "quiet feet",
              "tiptoe", "land softly", "cushion the landing", "delicate steps", "careful footfalls"),
        less=("stomp", "stomping", "hard landings", "land heavily", "heavy steps", "loud footsteps",
              "slam the feet down", "pound the ground", "thud", "forceful landings", "harsh impact"),
        names=("landing softness",)),
})


# ---------------------------------------------------------------- the domain
class Walker(Domain):
    """dm_control walker taking three scripted, assisted steps (see the module docstring)."""

    name = "walker"
    attributes = (
        AttributeSpec(
            name="step_size",
            description="How long the walker's steps are: the distance between its feet when a foot lands.",
            unit="m",
        ),
        AttributeSpec(
            name="softness",
            description="How softly the walker puts its feet down: gentle, slow landings are soft, stomping is not.",
            unit="m/s",
            reading=Reading("landing speed", -1, "lower is softer"),
        ),
    )
    state_dim = len(STATE_FEATURES)
    param_names = tuple(PARAM_RANGES)
    frame_rate = FRAME_RATE
    feedback_phrases = FEEDBACK_PHRASES
    zeta_surface = 96  # the generating agent reads clips on ζσ over the parameters (generation_surface_val.md)
    export_refit = False  # reward-only on 60 val profiles: trained weights 60, re-fitted 54 (reward_refit_val.md)
    generate_spread = 0.5  # with the surface: val AF lower, searches still rare at normal precision (same report)
    zeta_noise = 0.04  # its soft step, chosen with the surface: val AF lowest with SR held (same report)

    def __init__(self) -> None:
        self._physics: WalkerPhysics | None = None
        # the camera only slides along x, and three quarters of each frame are sky: drawn once a clip
        self._renderers = ThreadRenderers(sky=Sky.ONCE)

    def physics(self) -> WalkerPhysics:
        """The walker's physics, made on first use."""
        if self._physics is None:
            self._physics = WalkerPhysics.from_suite()
        return self._physics

    # ------------------------------------------------------------------ skill
    def sample_params(self, rng: np.random.Generator) -> dict[str, float]:
        return {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in PARAM_RANGES.items()}

    def param_space(self) -> ParamSpace:
        return ParamSpace.box(PARAM_RANGES)

    def rollout(self, params: dict[str, float], seed: int) -> Rollout:
        physics = self.physics()
        sim, policy = WalkerSim(physics), GaitPolicy(GaitPlan.from_params(params, physics.geometry), physics)
        states = run_skill(sim, policy, params, seed)
        recording = sim.recording
        m = measure(recording, policy.controller.touchdowns, policy.plan, physics.body_weight(), physics.timestep())
        states = (stack_samples(recording.raw, STATE_EVERY // RAW_EVERY) if self.raw_states
                  else np.asarray(states, dtype=np.float32))
        return Rollout(id="", domain=self.name, params={k: float(params[k]) for k in self.param_names},
                       seed=int(seed), states=states,
                       replay=np.asarray(recording.frames, dtype=np.float64), proxies=m.proxies,
                       success=m.success, info=m.info)

    # ------------------------------------------------------------------ rendering
    def render(self, rollout: Rollout, width: int, height: int, frames: slice = ALL_FRAMES) -> Iterator[np.ndarray]:
        camera = Camera(CAMERA_DISTANCE, CAMERA_ELEVATION,  # follows the torso along x
                        aim=lambda data: (float(data.xpos[1, 0]), 0.0, CAMERA_LOOKAT_Z))
        return self._renderers.replay(self.physics().model, rollout.replay[frames], width, height, camera)

    # ------------------------------------------------------------------ stepping (rba.gym)
    def simulator(self) -> SkillSim:
        return WalkerSim(WalkerPhysics.from_suite())

    def skill_policy(self, params: dict[str, float], seed: int) -> SkillPolicy:
        return WalkerSkillPolicy(params)


def start(physics: WalkerPhysics, params: dict[str, float], seed: int) -> GaitPlan:
    """Reset ``physics`` to the skill's start (standing for the gait ``params`` plan, perturbed by ``seed``)."""
    plan = GaitPlan.from_params(params, physics.geometry)
    rng = np.random.default_rng(seed)  # a small seed-dependent perturbation of the start
    pose = np.array(plan.start_pose(physics.geometry)) + np.concatenate([[0.0] * 3,
                                                                          rng.normal(0.0, INIT_JOINT_NOISE, 6)])
    physics.reset(pose, np.concatenate([[0.0] * 3, rng.normal(0.0, INIT_VEL_NOISE, 6)]))
    return plan


class WalkerRaw(Walker):
    """The walker's raw view (``--states raw``): each 10 Hz state is the MuJoCo ``qpos`` and ``qvel`` (9 + 9: root
    z, x, pitch and the six leg joints) at four 40 Hz samples, nothing computed from them.

    ``softness`` is the harder attribute here: it is the foot's peak speed in the 50 ms before touchdown, and a
    40 Hz sample falls in that window once or twice per landing, where the foot's speed is a function of the
    whole leg's angles and rates (its Jacobian) for the models to learn; the feature view hands it over as
    the peak foot speed. ``step_size`` is in the positions (root x and the leg angles at touchdown).
    """

    name = "walker_raw"
    raw_states = True
    state_dim = (STATE_EVERY // RAW_EVERY) * 2 * 9
    # no rba.gym env: the gait's policy reads the feature view's observations (foot positions and speeds)
    simulator, skill_policy = Domain.simulator, Domain.skill_policy


CAMERA_DISTANCE = 3.3  # m from the torso, side view
CAMERA_ELEVATION = -8.0  # degrees
CAMERA_LOOKAT_Z = 0.75  # m


# ---------------------------------------------------------------- stepping for rba.gym
# The walker stepped one physics step (2.5 ms) at a time, and its scripted gait as a policy on observations.
#
# The step interface is the rollout's own loop (``run_skill``) cut at ``physics.act``: an action is
# one physics step's :class:`Command`, the six motor commands in [-1, 1] and the torso
# assist (rootz force, rootx force, pitch torque), which is part of the scripted skill. An observation is the
# state vector (``STATE_FEATURES``, float64) of that step; every ``STATE_EVERY``-th is one the rollout
# records (foot peak speeds run over the steps since the last recorded one).
#
# The rollout's policy is :class:`GaitPolicy` on the sim's own physics; ``rba.gym``'s is the same
# :class:`GaitController`, fed an :class:`ObservedWalker` that
# answers its questions from the observation alone: joint and torso quantities are in it, positions follow by
# the planar kinematics, the torso's absolute x from the start pose the gait plans, and the feed-forward's bias
# forces from the policy's own copy of the MuJoCo model at the previous observation (MuJoCo's ``mj_step``
# leaves those of the state it stepped from). Its clock is its call count: one call per step.

ASSIST_LIMITS = (5000.0, 5000.0, 2000.0)  # N, N, N·m: action bounds, > 10x what the gait's assist asks (~120 N)
_F = {name: i for i, name in enumerate(STATE_FEATURES)}


class WalkerSim:
    """The walker's physics under per-step actions (``rba.domains.base.SkillSim``), recording as it goes."""

    action_low = np.array([-1.0] * 6 + [-a for a in ASSIST_LIMITS])
    action_high = np.array([1.0] * 6 + list(ASSIST_LIMITS))

    def __init__(self, physics: WalkerPhysics) -> None:
        self.physics = physics
        self.max_steps = int(MAX_DURATION / physics.timestep())
        self._k = 0

    def reset(self, params: dict[str, float], seed: int) -> tuple[np.ndarray, bool]:
        start(self.physics, params, seed)
        self.physics.observe()
        self.recording = Recording(x_start=self.physics.torso_x())
        self._k = 0
        return self._observe()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, bool]:
        a = np.asarray(action, dtype=np.float64).tolist()
        self.recording.check_fall(self.physics)  # the state stepped from
        self.recording.count(a[6])
        self.physics.act(tuple(a[:6]), (a[6], a[7], a[8]))
        self.physics.observe()
        self._k += 1
        return self._observe()

    def _observe(self) -> tuple[np.ndarray, bool]:
        kept = self._k < self.max_steps  # the step the episode is cut at is not the rollout's
        obs = np.array(self.recording.record(self._k, self.physics, kept))
        return obs, kept and self._k % STATE_EVERY == 0


class ObservedWalker:
    """What ``GaitController`` asks of ``WalkerPhysics``, answered from one observation (see the module)."""

    def __init__(self, mirror: WalkerPhysics, x_start: float) -> None:
        self._mirror, self._x_start = mirror, x_start
        self.geometry: WalkerGeometry = mirror.geometry
        self._prev: tuple[list[float], list[float]] | None = None
        self._obs: list[float] = []
        self._kin: tuple[float, ...] = ()
        self._bias: list[float] = []

    def read(self, obs: np.ndarray) -> None:
        o = np.asarray(obs, dtype=np.float64).tolist()
        rootz, rootx, pitch = o[_F["torso_height"]] - self.geometry.torso_z0, o[_F["torso_x_from_start"]] + \
            self._x_start, o[_F["torso_pitch"]]
        joints = o[_F["right_hip"]:_F["right_hip"] + 6]
        q = [rootz, rootx, pitch, *joints]
        v = [o[_F["torso_vz"]], o[_F["torso_vx"]], o[_F["torso_pitch_rate"]], *o[_F["right_hip_vel"]:
                                                                                 _F["right_hip_vel"] + 6]]
        self._bias = self._mirror.bias_at(*(self._prev or (q, v)))
        self._prev, self._obs = (q, v), o
        self._kin = self.geometry.kinematics(rootz, rootx, pitch, joints)

    def timestep(self) -> float:
        return self._mirror.timestep()

    def body_weight(self) -> float:
        return self._mirror.body_weight()

    def bias_forces(self) -> list[float]:
        return self._bias

    def joint_angles(self) -> list[float]:
        return self._obs[_F["right_hip"]:_F["right_hip"] + 6]

    def joint_velocities(self) -> list[float]:
        return self._obs[_F["right_hip_vel"]:_F["right_hip_vel"] + 6]

    def torso_height(self) -> float:
        return self._obs[_F["torso_height"]]

    def torso_x(self) -> float:
        return self._obs[_F["torso_x_from_start"]] + self._x_start

    def torso_pitch(self) -> float:
        return self._obs[_F["torso_pitch"]]

    def torso_velocity(self) -> tuple[float, float, float]:
        o = self._obs
        return o[_F["torso_vz"]], o[_F["torso_vx"]], o[_F["torso_pitch_rate"]]

    def hip_position(self) -> tuple[float, float]:
        return self._kin[0], self._kin[1]

    def ankle_positions(self) -> tuple[tuple[float, float], tuple[float, float]]:
        k = self._kin
        return (k[2], k[3]), (k[7], k[8])

    def foot_positions(self) -> tuple[tuple[float, float], tuple[float, float]]:
        k = self._kin
        return (k[4], k[5]), (k[9], k[10])

    def foot_clearances(self) -> tuple[float, float]:
        return self._obs[_F["right_foot_clearance"]], self._obs[_F["left_foot_clearance"]]

    def foot_speeds(self) -> tuple[float, float]:
        o, i = self._obs, _F["right_foot_vx"]
        return math.hypot(o[i], o[i + 1]), math.hypot(o[i + 2], o[i + 3])


class GaitPolicy:
    """The scripted gait with fixed parameters as ``policy(obs) -> action``, reading ``view`` (what the
    :class:`GaitController` asks): on the simulator's own physics it is the rollout's skill."""

    def __init__(self, plan: GaitPlan, view: WalkerPhysics | ObservedWalker) -> None:
        self.plan, self._view = plan, view
        self.controller = GaitController(plan, view)
        self._k = 0
        self.done = False

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        t = self._k * self._view.timestep()
        if self.controller.finished(t):
            self.done = True
            return np.zeros(9)
        command = self.controller.control(t, self._view)
        self._k += 1
        return np.array(command.ctrl + command.assist)

    def measured(self) -> dict[str, float]:
        return touchdown_proxies(self.controller.touchdowns)


class WalkerSkillPolicy(GaitPolicy):
    """The gait reading observations alone (``rba.domains.base.SkillPolicy``), through an :class:`ObservedWalker`."""

    def __init__(self, params: dict[str, float]) -> None:
        mirror = WalkerPhysics.from_suite()  # the policy's own model: the feed-forward's bias forces
        plan = GaitPlan.from_params(params, mirror.geometry)
        self._observed = ObservedWalker(mirror, plan.start_pose(mirror.geometry)[1])
        super().__init__(plan, self._observed)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        self._observed.read(obs)
        return super().__call__(obs)
