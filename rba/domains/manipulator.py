"""Manipulator on dm_control's planar ``manipulator``: lift a held ball, at a chosen speed and tremor.

The ball starts in the closed gripper, the hand pointing down at (0.35, 0.10) m; a minimum-jerk
path in joint space takes the arm over ``duration`` seconds to a raised pose at (0.20, 0.65) m,
then it holds. Control at 100 Hz: PD on joint targets with gravity compensation through the
arm's own actuators (torques clipped to their limits). Tremor is Gaussian noise with std
``tremor`` (rad) on the joint *targets*, held for 4 control steps (noise on torques would be
filtered away by the arm's inertia and stay invisible).

Attributes: ``speed`` = 10-90 % rise speed of the hand (m/s, from the time the hand takes to
cover the middle 80 % of its climb: peak speeds would count tremor as speed); ``instability``
= mean residual (mm) of a quadratic fit to each window of 5 consecutive hand positions at
50 Hz: zero for a smooth path, growing with jitter.

States (10 Hz) stack the last 5 raw 50 Hz samples (hand x, z, pointing angle; ball x, z;
shoulder, elbow, wrist angles), so jitter within 0.1 s is visible to the models, plus the third
differences of the hand's x and z over those 5 samples (mm): zero for any path up to a
quadratic, so they show the jitter itself rather than the smooth lift (which is 1000x larger).
"""

from __future__ import annotations

from collections.abc import Iterator
from types import MappingProxyType

import mujoco
import numpy as np

from rba.domains.base import AttributeSpec, Domain, FeedbackPhrases, ParamSpace, Rollout, stack_samples
from rba.domains.mujoco_render import Camera, ThreadRenderers

CONTROL_EVERY = 10  # physics steps (1 ms) per control step: 100 Hz
RAW_EVERY = 2  # control steps per raw sample: 50 Hz
STACK = 5  # raw samples per model state: 10 Hz states
HOLD_BEFORE, HOLD_AFTER = 0.4, 0.8  # s at the start and end poses
Q_DOWN = np.array([-1.613, -1.012, 0.412, -0.928])  # rad: pinch at (0.35, 0.10) m, hand pointing down
Q_UP = np.array([-0.062, -0.443, -0.822, -1.815])  # rad: pinch at (0.20, 0.65) m, hand pointing down
KP = np.array([60.0, 40.0, 15.0, 4.0])  # N·m/rad (root, shoulder, elbow, wrist)
KD = np.array([3.0, 2.0, 0.6, 0.15])  # N·m·s/rad
GRASP = 1.0  # grasp actuator command: closed
BALL_IN_HAND = 0.02  # m above the pinch point (towards the palm): where the closed fingers hold the ball
SETTLE_STEPS = 300  # physics steps (0.3 s) to close the gripper before the clip starts
TREMOR_HOLD = 4  # control steps each tremor sample is held
TIMESTEP = 0.001  # s, the suite model's physics step
FRAME_EVERY = 3  # control steps per rendered frame
FRAME_RATE = 1.0 / (FRAME_EVERY * CONTROL_EVERY * TIMESTEP)  # 33.3 frames per second
MIN_RISE = 0.4  # m the ball must rise for a successful lift

PARAM_RANGES = {
    "duration": (0.5, 2.5),  # s of the lift
    "tremor": (0.0, 0.04),  # rad, std of the noise on joint targets
}
RAW_FEATURES = ("hand_x", "hand_z", "hand_angle", "ball_x", "ball_z", "shoulder", "elbow", "wrist")
N_QPOS = 11  # the suite model's qpos and qvel: 4 arm joints, 4 finger joints, the ball's x, z and rotation


def min_jerk(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk progress 10s³ − 15s⁴ + 6s⁵ for s in [0, 1]."""
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s**2)


def quadratic_residual(points: np.ndarray, window: int = 5) -> float:
    """Mean RMS residual (same unit as ``points`` [T, d]) of a quadratic fit over each window."""
    t = np.arange(window, dtype=np.float64)
    basis = np.stack([np.ones(window), t, t * t], 1)
    proj = np.eye(window) - basis @ np.linalg.pinv(basis)  # residual maker
    wins = np.lib.stride_tricks.sliding_window_view(points, window, axis=0)  # [n, d, window]
    res = np.einsum("ij,ndj->ndi", proj, wins)
    return float(np.sqrt((res**2).sum(1).mean(1)).mean())


def _grasp(model: mujoco.MjModel, data: mujoco.MjData, pinch: int) -> None:
    """Start with the arm down and close the gripper on the ball, held in place meanwhile."""
    data.qpos[:4] = Q_DOWN
    mujoco.mj_kinematics(model, data)
    # the ball's slide joints have ref = its default place, so their qpos are its x and z
    hold = data.site_xpos[pinch][[0, 2]] + np.array([0.0, BALL_IN_HAND])
    data.ctrl[4] = GRASP
    for _ in range(SETTLE_STEPS):
        data.qpos[8:10], data.qvel[8:11] = hold, 0.0
        tau = KP * (Q_DOWN - data.qpos[:4]) - KD * data.qvel[:4] + data.qfrc_bias[:4]
        data.ctrl[:4] = np.clip(tau / model.actuator_gear[:4, 0], -1.0, 1.0)
        mujoco.mj_step(model, data)
    data.qpos[8:10], data.qvel[8:11] = hold, 0.0
    mujoco.mj_forward(model, data)


class LiftController:
    """The lift: PD with gravity compensation toward a minimum-jerk joint path, plus the held tremor."""

    def __init__(self, duration: float, tremor: float, rng: np.random.Generator, gear: np.ndarray) -> None:
        self.duration, self.tremor = duration, tremor
        self._rng, self._gear = rng, gear
        self._noise = np.zeros(4)

    def control(self, t: float, k: int, data: mujoco.MjData) -> np.ndarray:
        """Arm motor commands at control step ``k`` (time ``t``): a new tremor sample every TREMOR_HOLD steps."""
        q_ref = Q_DOWN + (Q_UP - Q_DOWN) * min_jerk(np.array((t - HOLD_BEFORE) / self.duration))
        if self.tremor and k % TREMOR_HOLD == 0 and HOLD_BEFORE <= t < HOLD_BEFORE + self.duration + 0.3:
            self._noise = self.tremor * self._rng.standard_normal(4)
        elif k % TREMOR_HOLD == 0:
            self._noise = np.zeros(4)
        tau = KP * (q_ref + self._noise - data.qpos[:4]) - KD * data.qvel[:4] + data.qfrc_bias[:4]
        return np.clip(tau / self._gear, -1.0, 1.0)


def measure(raw: np.ndarray) -> tuple[np.ndarray, dict[str, float], bool, dict[str, float]]:
    """States, proxies, success and diagnostics from the raw 50 Hz samples [T, RAW_FEATURES]."""
    n_states = len(raw) // STACK
    windows = raw[: n_states * STACK].reshape(n_states, STACK, len(RAW_FEATURES))
    jitter = 1000.0 * np.diff(windows[:, :, :2], n=3, axis=1).reshape(n_states, -1)  # mm, [n, 2 x 2]
    states = np.concatenate([windows.reshape(n_states, -1), jitter], 1).astype(np.float32)
    hand = raw[:, :2]
    z = hand[:, 1]
    z0, z1 = z[: int(HOLD_BEFORE * 50)].mean(), z[-int(0.3 * 50):].mean()
    climb = z1 - z0
    t = np.arange(len(z)) / 50.0
    t10 = t[np.argmax(z >= z0 + 0.1 * climb)]
    t90 = t[np.argmax(z >= z0 + 0.9 * climb)]
    speed = 0.8 * climb / max(t90 - t10, 1e-3)
    instability = 1000.0 * quadratic_residual(hand)  # mm
    ball_rise = raw[-1, 4] - raw[0, 4]
    held = np.linalg.norm(raw[-1, 3:5] - raw[-1, :2]) < 0.08
    success = bool(held and ball_rise > MIN_RISE and np.isfinite(states).all())
    return (states, {"speed": float(speed), "instability": instability}, success,
            {"ball_rise_m": float(ball_rise), "climb_m": float(climb)})


# free-text feedback's anchors (rba.interpret): both sides written with the same nouns
FEEDBACK_PHRASES = MappingProxyType({
    "speed": FeedbackPhrases(
        more=("fast lift", "lift quickly", "hurry", "rapid motion", "quick arm", "swift lift", "speedy", "brisk"),
        less=("slow lift", "lift slowly", "take your time", "leisurely motion", "sluggish arm", "gradual lift",
              "unhurried", "gently paced"),
        names=("lifting speed", "pace")),
    "instability": FeedbackPhrases(
        more=("shaky motion", "jittery", "wobbly arm", "trembling", "jerky lift", "unsteady", "vibrating",
              "shaking"),
        less=("steady motion", "smooth", "stable arm", "calm lift", "fluid movement", "precise", "still",
              "controlled"),
        names=("shakiness", "jitter")),
})


class Manipulator(Domain):
    name = "manipulator"
    attributes = (
        AttributeSpec("speed", "How fast the arm lifts the ball.", "m/s"),
        AttributeSpec("instability", "How shaky and jittery the arm's motion is.", "mm"),
    )
    state_dim = STACK * len(RAW_FEATURES) + 2 * (STACK - 3)
    param_names = tuple(PARAM_RANGES)
    frame_rate = FRAME_RATE
    feedback_phrases = FEEDBACK_PHRASES

    def __init__(self) -> None:
        self._model: mujoco.MjModel | None = None
        self._renderers = ThreadRenderers()

    def _physics(self) -> mujoco.MjModel:
        if self._model is None:
            from dm_control.suite import manipulator as suite_manipulator

            xml, assets = suite_manipulator.make_model(use_peg=False, insert=False)
            physics = suite_manipulator.Physics.from_xml_string(xml, assets)
            self._physics_ref = physics  # keeps the model alive
            self._model = physics.model.ptr
            assert abs(self._model.opt.timestep - TIMESTEP) < 1e-12
            target = mujoco.mj_name2id(self._model, mujoco.mjtObj.mjOBJ_GEOM, "target_ball")
            if target >= 0:
                self._model.geom_rgba[target, 3] = 0.0  # the bring_ball target is not part of this task
        return self._model

    def sample_params(self, rng: np.random.Generator) -> dict[str, float]:
        return {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in PARAM_RANGES.items()}

    def param_space(self) -> ParamSpace:
        return ParamSpace.box(PARAM_RANGES)

    def _ids(self, model):
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "pinch")
        ball = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "ball")
        return site, ball

    def rollout(self, params: dict[str, float], seed: int) -> Rollout:
        model = self._physics()
        data = mujoco.MjData(model)
        pinch, ball = self._ids(model)
        _grasp(model, data, pinch)
        controller = LiftController(float(params["duration"]), float(params["tremor"]), np.random.default_rng(seed),
                                    model.actuator_gear[:4, 0])
        dt_control = model.opt.timestep * CONTROL_EVERY
        n_control = round((HOLD_BEFORE + controller.duration + HOLD_AFTER) / dt_control)
        raw, sim, replay = [], [], []
        for k in range(n_control):
            data.ctrl[:4] = controller.control(k * dt_control, k, data)
            mujoco.mj_step(model, data, nstep=CONTROL_EVERY)
            if k % RAW_EVERY == 0:
                r = data.site_xmat[pinch].reshape(3, 3)
                raw.append([data.site_xpos[pinch][0], data.site_xpos[pinch][2], np.arctan2(r[2, 2], r[0, 2]),
                            data.xpos[ball][0], data.xpos[ball][2], *data.qpos[1:4]])
                sim.append(np.concatenate([data.qpos, data.qvel]))
            if k % FRAME_EVERY == 0:
                replay.append(data.qpos.copy())
        states, proxies, success, info = measure(np.asarray(raw, dtype=np.float64))
        if self.raw_states:
            states = stack_samples(sim, STACK)
        return Rollout("", self.name, dict(params), seed, states, np.asarray(replay), proxies, success, info)

    def render(self, rollout: Rollout, width: int, height: int) -> Iterator[np.ndarray]:
        camera = Camera(CAMERA_DISTANCE, CAMERA_ELEVATION, CAMERA_LOOKAT)
        return self._renderers.replay(self._physics(), rollout.replay, width, height, camera)


class ManipulatorRaw(Manipulator):
    """The manipulator's raw view (``--states raw``): each 10 Hz state is MuJoCo's ``qpos`` and ``qvel`` (11 + 11)
    at five 50 Hz samples (the feature view's own stack), without the hand's path or its third differences.

    ``instability`` is the hand's jitter within 0.1 s; here the models must find it in the joint rates
    themselves (the tremor is on joint targets, so it shows in ``qvel``), not in a ready-made jitter feature.
    """

    name = "manipulator_raw"
    raw_states = True
    state_dim = STACK * 2 * N_QPOS


CAMERA_LOOKAT = (0.15, 0.0, 0.42)  # m: between the low and the raised hand
CAMERA_DISTANCE = 1.05  # m
CAMERA_ELEVATION = -8.0  # degrees
