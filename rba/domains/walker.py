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
"""

from __future__ import annotations

import math
import os

os.environ.setdefault("MUJOCO_GL", "egl")

from collections.abc import Iterator

import mujoco
import numpy as np

from rba.domains.base import AttributeSpec, Domain, Rollout
from rba.domains.mujoco_render import Camera, ThreadRenderers

# ---------------------------------------------------------------- model geometry (m, kg)
DT = 0.0025  # physics timestep of the walker model (s)
TORSO_Z0 = 1.3  # torso body height when rootz = 0 (m)
TORSO_TO_HIP = 0.3  # torso centre to hip joints (m)
THIGH = 0.45  # hip to knee (m)
SHANK = 0.5  # knee to ankle (m)
ANKLE_TO_FOOT = 0.06  # ankle joint to foot geom centre, along the foot (m)
FOOT_RADIUS = 0.05  # foot capsule radius (m)
FOOT_HALF = 0.1  # foot capsule half-length (m)
THIGH_RADIUS = 0.05  # thigh capsule radius (m)
TORSO_RADIUS = 0.07  # torso capsule radius (m)
TORSO_HALF = 0.3  # torso capsule half-length (m)
GROUND_ANKLE_Z = FOOT_RADIUS  # ankle height of a flat foot on the floor (m)
GRAVITY = 9.81  # m/s^2

# qpos / qvel indices (the walker's joint order)
ROOTZ, ROOTX, ROOTY = 0, 1, 2
R_HIP, R_KNEE, R_ANKLE, L_HIP, L_KNEE, L_ANKLE = 3, 4, 5, 6, 7, 8
JOINT_LOW = (math.radians(-20), math.radians(-150), math.radians(-45))  # hip, knee, ankle (rad)
JOINT_HIGH = (math.radians(100), 0.0, math.radians(45))

# ---------------------------------------------------------------- controller constants
KP = (600.0, 400.0, 100.0)  # hip, knee, ankle stiffness (N·m/rad)
KD = (30.0, 20.0, 4.0)  # hip, knee, ankle damping (N·m·s/rad)
GEAR = (100.0, 50.0, 20.0)  # motor gear = torque limit (N·m)
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
START_ANKLE_X = -ANKLE_TO_FOOT  # ankles' x at the start: foot centres under the hip at x = 0 (m)
INIT_JOINT_NOISE = 0.02  # seed-dependent initial joint perturbation, std (rad)
INIT_VEL_NOISE = 0.05  # seed-dependent initial joint velocity perturbation, std (rad/s)

# ---------------------------------------------------------------- fall / success criteria
MIN_TORSO_HEIGHT = 0.7  # torso centre height (m)
MAX_PITCH = 1.0  # |torso pitch| (rad)

# ---------------------------------------------------------------- sampling & recording
STATE_EVERY = 40  # physics steps per state sample (10 Hz: foot speed features carry the fast part)
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


def _smooth(u: float) -> tuple[float, float]:
    """Smoothstep on [0, 1] (clipped) and its derivative w.r.t. u."""
    if u <= 0.0:
        return 0.0, 0.0
    if u >= 1.0:
        return 1.0, 0.0
    return u * u * (3.0 - 2.0 * u), 6.0 * u * (1.0 - u)


def _leg_ik(dx: float, dz: float) -> tuple[float, float]:
    """Absolute thigh and shank angles (rad, from the downward vertical, + = forward) that
    put the ankle at (dx, dz) from the hip, knee bending forward."""
    d2 = dx * dx + dz * dz
    dmax = THIGH + SHANK - 1e-4
    if d2 > dmax * dmax:
        scale = dmax / math.sqrt(d2)
        dx, dz, d2 = dx * scale, dz * scale, dmax * dmax
    c = (d2 - THIGH * THIGH - SHANK * SHANK) / (2.0 * THIGH * SHANK)
    c = 1.0 if c > 1.0 else (-1.0 if c < -1.0 else c)
    bend = math.acos(c)  # = -knee angle
    psi = math.atan2(dx, -dz)
    alpha = psi + math.atan2(SHANK * math.sin(bend), THIGH + SHANK * c)
    return alpha, alpha - bend


def _leg_rates(alpha: float, beta: float, vx: float, vz: float) -> tuple[float, float]:
    """Absolute thigh/shank angular rates that move the ankle at (vx, vz) relative to the hip."""
    ca, sa, cb, sb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
    det = THIGH * SHANK * (ca * sb - sa * cb)
    if abs(det) < 0.02:  # near-straight knee: avoid the singularity
        det = 0.02 if det >= 0 else -0.02
    # J = [[L1 ca, L2 cb], [L1 sa, L2 sb]]
    da = (SHANK * sb * vx - SHANK * cb * vz) / det
    db = (-THIGH * sa * vx + THIGH * ca * vz) / det
    return da, db


def _torso_height(qpos) -> float:
    """Height of the torso centre (m)."""
    return TORSO_Z0 + qpos[ROOTZ]


def _hip_position(qpos) -> tuple[float, float]:
    """World (x, z) of the hip joints (m)."""
    th = qpos[ROOTY]
    return qpos[ROOTX] - TORSO_TO_HIP * math.sin(th), TORSO_Z0 + qpos[ROOTZ] - TORSO_TO_HIP * math.cos(th)


def _foot_positions(qpos) -> tuple[tuple[float, float], tuple[float, float]]:
    """World (x, z) of the right and left foot geom centres (m)."""
    k = _foot_kinematics(qpos)
    return (k[2], k[3]), (k[7], k[8])


def _foot_kinematics(qpos) -> tuple[float, ...]:
    """Planar forward kinematics: per foot (right then left) ankle x, z, foot-centre x, z and
    the foot's clearance (lowest point of the capsule above the floor, m)."""
    th = qpos[ROOTY]
    hx = qpos[ROOTX] - TORSO_TO_HIP * math.sin(th)
    hz = TORSO_Z0 + qpos[ROOTZ] - TORSO_TO_HIP * math.cos(th)
    out = []
    for j in (R_HIP, L_HIP):
        a = qpos[j] - th
        b = a + qpos[j + 1]
        g = b + qpos[j + 2]
        ax = hx + THIGH * math.sin(a) + SHANK * math.sin(b)
        az = hz - THIGH * math.cos(a) - SHANK * math.cos(b)
        sg = math.sin(g)
        fx = ax + ANKLE_TO_FOOT * math.cos(g)
        fz = az + ANKLE_TO_FOOT * sg
        out += [ax, az, fx, fz, fz - FOOT_RADIUS - FOOT_HALF * abs(sg)]
    return tuple(out)


class Walker(Domain):
    """dm_control walker taking three scripted, assisted steps (see the module docstring)."""

    name = "walker"
    attributes = (
        AttributeSpec(
            name="step_size",
            description="How long the walker's steps are: the distance between its feet when a foot lands.",
            unit="m",
            epsilon=0.12,  # m; measured range ≈ 0.1-1.0 m -> ~7 buckets
            high_precision_epsilon=0.02,  # m
        ),
        AttributeSpec(
            name="softness",
            description="How softly the walker puts its feet down: gentle, slow landings are soft, stomping is not.",
            unit="m/s",
            epsilon=0.2,  # m/s; measured range ≈ -1.5..-0.1 m/s -> ~7 buckets
            high_precision_epsilon=0.033,  # m/s
        ),
    )
    state_dim = len(STATE_FEATURES)
    param_names = tuple(PARAM_RANGES)
    frame_rate = FRAME_RATE

    def __init__(self) -> None:
        self._model: mujoco.MjModel | None = None
        self._data: mujoco.MjData | None = None
        self._renderers = ThreadRenderers()

    # ------------------------------------------------------------------ simulator
    def _physics(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        if self._model is None:
            from dm_control.suite import walker as suite_walker

            physics = suite_walker.Physics.from_xml_string(*suite_walker.get_model_and_assets())
            self._physics_ref = physics  # keeps the model alive
            self._model = physics.model.ptr
            self._data = physics.data.ptr
            assert abs(self._model.opt.timestep - DT) < 1e-12
        return self._model, self._data

    # ------------------------------------------------------------------ skill
    def sample_params(self, rng: np.random.Generator) -> dict[str, float]:
        return {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in PARAM_RANGES.items()}

    def rollout(self, params: dict[str, float], seed: int) -> Rollout:
        sim = self._simulate(params, seed)
        return Rollout(
            id="",
            domain=self.name,
            params={k: float(params[k]) for k in self.param_names},
            seed=int(seed),
            states=sim["states"],
            replay=sim["replay"],
            proxies=sim["proxies"],
            success=sim["success"],
            info=sim["info"],
        )

    def _simulate(self, params: dict[str, float], seed: int) -> dict:
        model, data = self._physics()
        step_len = float(params["step_length"])
        v_land = float(params["landing_speed"])
        swing_base = float(params["swing_duration"])
        swing_h = float(params["swing_height"])

        # ---- plan constants
        lean = MAX_LEAN * min(1.0, step_len / LEAN_FULL_STEP)
        half = 0.5 * step_len
        hip_h = min(HIP_HEIGHT_MAX, GROUND_ANKLE_Z + math.sqrt(max(LEG_REACH**2 - half * half, 0.25)))
        sin_lean, cos_lean = math.sin(lean), math.cos(lean)
        weight = float(model.body_subtreemass[1]) * GRAVITY  # N
        gear_h, gear_k, gear_a = GEAR
        kph, kpk, kpa = KP
        kdh, kdk, kda = KD
        lo_h, lo_k, lo_a = JOINT_LOW
        hi_h, hi_k, hi_a = JOINT_HIGH
        hover_z = GROUND_ANKLE_Z + HOVER_CLEARANCE
        floor_target = GROUND_ANKLE_Z - DESCENT_DEPTH
        peak_z = GROUND_ANKLE_Z + max(swing_h, HOVER_CLEARANCE)

        # ---- initial state: feet together under the hip, seed-dependent small perturbation
        rng = np.random.default_rng(seed)
        mujoco.mj_resetData(model, data)
        a, b = _leg_ik(START_ANKLE_X, GROUND_ANKLE_Z - hip_h)
        q0 = [hip_h + TORSO_TO_HIP * cos_lean - TORSO_Z0, TORSO_TO_HIP * sin_lean, lean]
        q0 += [a + lean, b - a, -b] * 2
        q0 = np.array(q0) + np.concatenate([[0.0, 0.0, 0.0], rng.normal(0.0, INIT_JOINT_NOISE, 6)])
        data.qpos[:] = q0
        data.qvel[:] = np.concatenate([[0.0, 0.0, 0.0], rng.normal(0.0, INIT_VEL_NOISE, 6)])
        mujoco.mj_forward(model, data)
        # shift vertically so the lower foot just touches the floor
        k0 = _foot_kinematics(data.qpos.tolist())
        data.qpos[ROOTZ] -= min(k0[4], k0[9]) + 1e-4
        mujoco.mj_forward(model, data)

        qpos_arr, qvel_arr, ctrl = data.qpos, data.qvel, data.ctrl
        qfrc_app, qfrc_bias = data.qfrc_applied, data.qfrc_bias
        step_fn = mujoco.mj_step

        x_start = float(qpos_arr[ROOTX])
        # planted ankles (x) and the planned hip path
        hip_from, hip_to = 0.0, 0.0
        swing_t0 = 0.0
        swing_dur = 1.0
        hip_xd, hip_vd = 0.0, 0.0

        # phases: 0 settle/double support, 1 swing travel, 2 hover, 3 descent, 4 final stand
        phase = 0
        phase_t0 = 0.0
        step_i = 0  # index of the next / current step
        swing = 0  # 0 right, 1 left
        sw_x0 = sw_z0 = sw_xT = 0.0
        desc_z0 = 0.0
        touchdowns: list[tuple[float, float, float, float]] = []  # (t, feet distance, peak speed, forced)
        fallen = False
        fall_reason = ""

        n_frame = 0
        next_frame_step = 0
        frames: list[list[float]] = []
        states: list[list[float]] = []
        q = qpos_arr.tolist()
        kin = _foot_kinematics(q)
        prev_feet = (kin[2], kin[3], kin[7], kin[8])
        speeds_r: list[float] = []
        speeds_l: list[float] = []
        peak_r = peak_l = 0.0
        vfr = (0.0, 0.0, 0.0, 0.0)
        assist_sq = 0.0
        n_steps_sim = 0

        t_end = None
        step = 0
        max_steps = int(40.0 / DT)
        while step < max_steps:
            t = step * DT
            q = qpos_arr.tolist()
            v = qvel_arr.tolist()
            kin = _foot_kinematics(q)
            rax, raz, rfx, rfz, rcl, lax, laz, lfx, lfz, lcl = kin
            # foot-centre velocities by finite difference of consecutive physics steps
            if step > 0:
                prx, prz, plx, plz = prev_feet
                vfr = ((rfx - prx) / DT, (rfz - prz) / DT, (lfx - plx) / DT, (lfz - plz) / DT)
            prev_feet = (rfx, rfz, lfx, lfz)
            sp_r = math.hypot(vfr[0], vfr[1])
            sp_l = math.hypot(vfr[2], vfr[3])
            if sp_r > peak_r:
                peak_r = sp_r
            if sp_l > peak_l:
                peak_l = sp_l

            # ---- record (replay frames at 30 fps, states at 10 Hz)
            if step == next_frame_step:
                frames.append(q)
                n_frame += 1
                next_frame_step = round(n_frame / FRAME_RATE / DT)
            if step % STATE_EVERY == 0:
                states.append(self._state_features(q, v, kin, vfr, peak_r, peak_l, x_start))
                peak_r = peak_l = 0.0
            if t_end is not None and t >= t_end:
                break

            th = q[ROOTY]
            torso_z = _torso_height(q)
            hx, hz = _hip_position(q)

            # ---- fall detection (torso / thigh contact, low torso, large pitch)
            if not fallen:
                knee_r = hz - THIGH * math.cos(q[R_HIP] - th)
                knee_l = hz - THIGH * math.cos(q[L_HIP] - th)
                low_torso = torso_z - TORSO_HALF * abs(math.cos(th)) - TORSO_RADIUS
                if torso_z < MIN_TORSO_HEIGHT or abs(th) >= MAX_PITCH:
                    fallen, fall_reason = True, "torso low or pitched"
                elif min(hz, knee_r, knee_l) - THIGH_RADIUS < 0.0 or low_torso < 0.0:
                    fallen, fall_reason = True, "torso/thigh floor contact"

            # ---- phase logic
            if phase == 0 and step_i < N_STEPS and t - phase_t0 >= (SETTLE_TIME if step_i == 0 else DOUBLE_SUPPORT):
                # start swing step_i
                swing = step_i % 2
                phase, phase_t0 = 1, t
                if swing == 0:
                    sw_x0, sw_z0, st_x = rax, raz, lax
                else:
                    sw_x0, sw_z0, st_x = lax, laz, rax
                sw_xT = (START_ANKLE_X if step_i == 0 else st_x) + step_len
                swing_dur = swing_base + SWING_PER_METRE * abs(sw_xT - sw_x0)
                swing_t0 = t
                hip_from, hip_to = hip_xd, 0.5 * (st_x + sw_xT) + ANKLE_TO_FOOT  # over the feet's midpoint
                if swing == 0:
                    speeds_r = []
                else:
                    speeds_l = []
            if phase in (1, 2, 3):
                (speeds_r if swing == 0 else speeds_l).append(sp_r if swing == 0 else sp_l)
            if phase == 1 and t - swing_t0 >= swing_dur:
                phase, phase_t0 = 2, t
            if phase == 2:
                sp = sp_r if swing == 0 else sp_l
                dt_h = t - phase_t0
                if (dt_h >= HOVER_MIN and sp < HOVER_SLOW) or dt_h >= HOVER_MAX:
                    phase, phase_t0 = 3, t
                    desc_z0 = hover_z
            if phase == 3:
                clear = rcl if swing == 0 else lcl
                forced = t - phase_t0 >= DESCENT_TIMEOUT
                if clear < 0.0 or forced:
                    sp_hist = speeds_r if swing == 0 else speeds_l
                    n_win = round(LANDING_WINDOW / DT)
                    peak = max(sp_hist[-n_win:]) if sp_hist else 0.0
                    touchdowns.append((t, abs(rfx - lfx), peak, float(forced)))
                    step_i += 1
                    phase, phase_t0 = (0, t) if step_i < N_STEPS else (4, t)
                    if phase == 4:
                        t_end = t + FINAL_STAND

            # ---- planned hip path
            if phase in (1, 2, 3):
                s, ds = _smooth((t - swing_t0) / swing_dur)
                hip_xd = hip_from + (hip_to - hip_from) * s
                hip_vd = (hip_to - hip_from) * ds / swing_dur
            else:
                hip_vd = 0.0
            hip_zd = hip_h

            # ---- swing foot target (ankle) and its velocity
            in_swing = phase in (1, 2, 3)
            if in_swing:
                if phase == 1:
                    u = (t - swing_t0) / swing_dur
                    sx, dsx = _smooth((u - 0.15) / 0.85)
                    tx = sw_x0 + (sw_xT - sw_x0) * sx
                    tvx = (sw_xT - sw_x0) * dsx / (0.85 * swing_dur)
                    if u < 0.3:
                        sz, dsz = _smooth(u / 0.3)
                        tz = sw_z0 + (peak_z - sw_z0) * sz
                        tvz = (peak_z - sw_z0) * dsz / (0.3 * swing_dur)
                    elif u < 0.65:
                        tz, tvz = peak_z, 0.0
                    else:
                        sz, dsz = _smooth((u - 0.65) / 0.35)
                        tz = peak_z + (hover_z - peak_z) * sz
                        tvz = (hover_z - peak_z) * dsz / (0.35 * swing_dur)
                elif phase == 2:
                    tx, tvx, tz, tvz = sw_xT, 0.0, hover_z, 0.0
                else:
                    tx, tvx = sw_xT, 0.0
                    tz = desc_z0 - v_land * (t - phase_t0)
                    tvz = -v_land
                    if tz <= floor_target:
                        tz, tvz = floor_target, 0.0

            # ---- weight shares of the stance legs
            if in_swing:
                share_r, share_l = (0.0, 1.0) if swing == 0 else (1.0, 0.0)
            else:
                span = rax - lax
                if abs(span) < 0.05:
                    share_r = 0.5
                else:
                    share_r = (hip_xd - lax) / span
                    share_r = 0.0 if share_r < 0.0 else (1.0 if share_r > 1.0 else share_r)
                if phase == 0 and step_i < N_STEPS:
                    wait = SETTLE_TIME if step_i == 0 else DOUBLE_SUPPORT
                    left_t = wait - (t - phase_t0)
                    if left_t < WEIGHT_SHIFT:  # unload the next swing foot
                        f = max(left_t, 0.0) / WEIGHT_SHIFT
                        if step_i % 2 == 0:
                            share_r *= f
                        else:
                            share_r = 1.0 - (1.0 - share_r) * f
                share_l = 1.0 - share_r

            bias = qfrc_bias.tolist()
            # ---- per-leg joint targets and torques
            for leg in (0, 1):
                j = R_HIP if leg == 0 else L_HIP
                ankx, ankz = (rax, raz) if leg == 0 else (lax, laz)
                if in_swing and leg == swing:
                    dx, dz = tx - hx, tz - hz
                    al, be = _leg_ik(dx, dz)
                    da, db = _leg_rates(al, be, tvx - hip_vd, tvz)
                    qh, qhd = al + th, da
                    ff_h, ff_k, ff_a = bias[j], bias[j + 1], bias[j + 2]
                else:
                    dx, dz = ankx - hip_xd, ankz - hip_zd
                    al, be = _leg_ik(dx, dz)
                    da, db = _leg_rates(al, be, -hip_vd, 0.0)
                    qh, qhd = al + lean, da
                    w = weight * (share_r if leg == 0 else share_l)
                    ff_h = -w * dx
                    ff_k = -w * SHANK * math.sin(be)
                    ff_a = 0.0
                qk, qkd = be - al, db - da
                qa, qad = -be, -db
                qh = lo_h if qh < lo_h else (hi_h if qh > hi_h else qh)
                qk = lo_k if qk < lo_k else (hi_k if qk > hi_k else qk)
                qa = lo_a if qa < lo_a else (hi_a if qa > hi_a else qa)
                th_h = (kph * (qh - q[j]) + kdh * (qhd - v[j]) + ff_h) / gear_h
                th_k = (kpk * (qk - q[j + 1]) + kdk * (qkd - v[j + 1]) + ff_k) / gear_k
                th_a = (kpa * (qa - q[j + 2]) + kda * (qad - v[j + 2]) + ff_a) / gear_a
                c0 = 3 * leg
                ctrl[c0] = -1.0 if th_h < -1.0 else (1.0 if th_h > 1.0 else th_h)
                ctrl[c0 + 1] = -1.0 if th_k < -1.0 else (1.0 if th_k > 1.0 else th_k)
                ctrl[c0 + 2] = -1.0 if th_a < -1.0 else (1.0 if th_a > 1.0 else th_a)

            # ---- torso assist toward the planned path
            tz_d = hip_zd + TORSO_TO_HIP * cos_lean
            tx_d = hip_xd + TORSO_TO_HIP * sin_lean
            fz = ASSIST_KZ * (tz_d - torso_z) - ASSIST_DZ * v[ROOTZ]
            fx = ASSIST_KX * (tx_d - q[ROOTX]) + ASSIST_DX * (hip_vd - v[ROOTX])
            tp = ASSIST_KP * (lean - th) - ASSIST_DP * v[ROOTY]
            qfrc_app[ROOTZ] = fz
            qfrc_app[ROOTX] = fx
            qfrc_app[ROOTY] = tp
            assist_sq += fz * fz
            n_steps_sim += 1

            step_fn(model, data)
            step += 1

        qfrc_app[:] = 0.0
        # ---- proxies
        later = touchdowns[1:] if len(touchdowns) > 1 else touchdowns
        if later:
            step_size = float(np.mean([td[1] for td in later]))
            landing = float(np.mean([td[2] for td in later]))
        else:
            step_size, landing = 0.0, 0.0
        steps_taken = len(touchdowns) == N_STEPS and not any(td[3] for td in touchdowns)
        success = steps_taken and not fallen
        info = {
            "n_touchdowns": float(len(touchdowns)),
            "fallen": float(fallen),
            "assist_rms_vertical_frac": math.sqrt(assist_sq / max(n_steps_sim, 1)) / weight,
            "duration_s": step * DT,
            "hip_height_plan_m": hip_h,
            "lean_plan_rad": lean,
        }
        for i, td in enumerate(touchdowns):
            info[f"touchdown{i}_t_s"] = td[0]
            info[f"touchdown{i}_feet_distance_m"] = td[1]
            info[f"touchdown{i}_landing_speed_mps"] = td[2]
        if fall_reason:
            info["fall_reason_" + fall_reason.replace(" ", "_").replace("/", "_")] = 1.0
        return {
            "states": np.asarray(states, dtype=np.float32),
            "replay": np.asarray(frames, dtype=np.float64),
            "proxies": {"step_size": step_size, "softness": -landing},
            "success": bool(success),
            "info": info,
        }

    @staticmethod
    def _state_features(q, v, kin, vfr, peak_r, peak_l, x_start) -> list[float]:
        torso_x = q[ROOTX]
        torso_z = TORSO_Z0 + q[ROOTZ]
        _, _, rfx, rfz, rcl, _, _, lfx, lfz, lcl = kin
        return [
            torso_z, q[ROOTY], torso_x - x_start, v[ROOTZ], v[ROOTX], v[ROOTY],
            *q[3:9], *v[3:9],
            rfx - torso_x, rfz - torso_z, lfx - torso_x, lfz - torso_z,
            *vfr,
            rcl, lcl,
            peak_r, peak_l,
        ]  # fmt: skip

    # ------------------------------------------------------------------ rendering
    def render(self, rollout: Rollout, width: int, height: int) -> Iterator[np.ndarray]:
        model, _ = self._physics()
        camera = Camera(CAMERA_DISTANCE, CAMERA_ELEVATION,  # follows the torso along x
                        aim=lambda data: (float(data.xpos[1, 0]), 0.0, CAMERA_LOOKAT_Z))
        return self._renderers.replay(model, rollout.replay, width, height, camera)


CAMERA_DISTANCE = 3.3  # m from the torso, side view
CAMERA_ELEVATION = -8.0  # degrees
CAMERA_LOOKAT_Z = 0.75  # m
