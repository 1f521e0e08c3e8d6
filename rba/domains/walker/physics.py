"""The walker's MuJoCo model and its named quantities, in the style of dm_control's suite.

:class:`WalkerGeometry` holds the dimensions read from the model; :class:`WalkerReading` is the named getters
(``torso_height()``, ``hip_position()``, ``foot_positions()``...) over one reading of the state, which is what
the gait controller asks; :class:`WalkerPhysics` takes that reading from MuJoCo's data every physics step (and
steps the model). ``rba.domains.walker.sim.ObservedWalker`` takes it from an observation vector instead: one set
of getters, two readers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

LEG_JOINTS = ("right_hip", "right_knee", "right_ankle", "left_hip", "left_knee", "left_ankle")


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


class WalkerReading:
    """The walker's named getters, answered from its last reading (see the module).

    The readers fill it through ``_read``; the getters never compute from MuJoCo themselves, so the gait
    controller gets the same answers from whichever reader it is given.
    """

    def __init__(self, geometry: WalkerGeometry, timestep: float, body_weight: float) -> None:
        self.geometry = geometry
        self._dt, self._weight = timestep, body_weight
        self._joints: list[float] = []
        self._joint_vel: list[float] = []
        self._bias_legs: list[float] = []
        self._torso = self._torso_vel = (0.0, 0.0, 0.0)  # height, x, pitch and their rates
        self._hip = (0.0, 0.0)
        self._ankles = self._feet = ((0.0, 0.0), (0.0, 0.0))
        self._clearances = (0.0, 0.0)
        self._foot_vel = (0.0, 0.0, 0.0, 0.0)
        self._speeds = (0.0, 0.0)

    def _read(self, torso: tuple[float, float, float], torso_vel: tuple[float, float, float], joints: list[float],
              joint_vel: list[float], kin: tuple[float, ...], clearances: tuple[float, float],
              foot_vel: tuple[float, float, float, float], bias_legs: list[float]) -> None:
        """Take one reading: the torso's height, x, pitch and their rates, the leg joints' angles and rates,
        ``kin`` (``WalkerGeometry.kinematics`` of them), the feet's clearances and velocities, the bias forces."""
        self._torso, self._torso_vel = torso, torso_vel
        self._joints, self._joint_vel = joints, joint_vel
        self._hip = (kin[0], kin[1])
        self._ankles = ((kin[2], kin[3]), (kin[7], kin[8]))
        self._feet = ((kin[4], kin[5]), (kin[9], kin[10]))
        self._clearances = clearances
        self._foot_vel = foot_vel
        self._speeds = (math.hypot(foot_vel[0], foot_vel[1]), math.hypot(foot_vel[2], foot_vel[3]))
        self._bias_legs = bias_legs

    # ---------------------------------------------------------------- named quantities (of the last reading)
    def timestep(self) -> float:
        return self._dt

    def body_weight(self) -> float:
        """Weight of the whole walker (N)."""
        return self._weight

    def joint_angles(self) -> list[float]:
        """Right hip, knee, ankle, left hip, knee, ankle (rad)."""
        return self._joints

    def joint_velocities(self) -> list[float]:
        return self._joint_vel

    def bias_forces(self) -> list[float]:
        """MuJoCo's bias forces (gravity, Coriolis) on the leg joints, in joint_angles' order."""
        return self._bias_legs

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


class WalkerPhysics(WalkerReading):
    """The walker's MuJoCo model and data, read with :class:`WalkerReading`'s getters.

    ``observe()`` reads the state once per physics step (qpos/qvel as Python floats, the planar
    kinematics, finite-difference foot velocities); the getters answer from that reading, so the
    controller and the recorder see the same numbers.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, keep_alive: object = None) -> None:
        self.model, self.data = model, data
        self._keep_alive = keep_alive  # the dm_control Physics that owns model and data
        joint = mujoco.mjtObj.mjOBJ_JOINT
        adr = [int(model.jnt_qposadr[mujoco.mj_name2id(model, joint, j)]) for j in ("rootz", "rootx", "rooty")]
        self._root: tuple[int, int, int] = (adr[0], adr[1], adr[2])
        self._legs = int(model.jnt_qposadr[mujoco.mj_name2id(model, joint, LEG_JOINTS[0])])
        legs = [int(model.jnt_qposadr[mujoco.mj_name2id(model, joint, j)]) for j in LEG_JOINTS]
        assert legs == list(range(self._legs, self._legs + 6)) and model.nq == model.nv, "walker joint layout"
        motors = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(model.nu)]
        assert tuple(motors) == LEG_JOINTS, "walker motors: one per leg joint, in LEG_JOINTS order"
        torso = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "torso")
        weight = float(model.body_subtreemass[torso]) * -float(model.opt.gravity[2])
        super().__init__(WalkerGeometry.from_model(model), float(model.opt.timestep), weight)
        # views into data, made once: each `data.qpos` makes a new array object (costly every step)
        self._qpos, self._qvel, self._ctrl = data.qpos, data.qvel, data.ctrl
        self._applied, self._bias = data.qfrc_applied, data.qfrc_bias
        self._q: list[float] = []
        self._v: list[float] = []
        self._prev_feet: tuple[float, float, float, float] | None = None

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
        joints = q[legs:legs + 6]
        kin = self.geometry.kinematics(q[iz], q[ix], q[iy], joints)
        feet, foot_vel = (kin[4], kin[5], kin[9], kin[10]), self._foot_vel
        if self._prev_feet is not None:
            dt = self._dt
            prx, prz, plx, plz = self._prev_feet
            foot_vel = ((feet[0] - prx) / dt, (feet[1] - prz) / dt, (feet[2] - plx) / dt, (feet[3] - plz) / dt)
        self._prev_feet = feet
        self._read((self.geometry.torso_z0 + q[iz], q[ix], q[iy]), (v[iz], v[ix], v[iy]), joints, v[legs:legs + 6],
                   kin, (kin[6], kin[11]), foot_vel, self._bias[legs:legs + 6].tolist())

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

    # ---------------------------------------------------------------- the raw state (of the last observe)
    def qpos(self) -> list[float]:
        return self._q

    def qvel(self) -> list[float]:
        return self._v
