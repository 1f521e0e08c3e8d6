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

Stepping (``rba.gym``): :class:`ManipulatorSim` is the arm under per-control-step joint targets (the action);
its servo (PD with gravity compensation through the arm's motors) is part of the robot, the lift is
:class:`LiftPolicy`: open loop, the minimum-jerk path plus the tremor drawn from the episode's seed, reading
the hand's path from the observations for ``measured()``. The observation at each control step is the state
vector of the last 5 raw samples; every 5th sample completes one the rollout records. ``rollout`` is
``run_skill`` of the two, so the rollout and the step interface are one code path. The raw view gets no env:
its samples have no hand position (the hand's, read after MuJoCo's step, lags ``qpos`` by a physics step),
so a policy on them could not measure the proxies.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import mujoco
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
from rba.domains.mujoco_render import Camera, MujocoView, ThreadRenderers

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
CONTROL_DT = TIMESTEP * CONTROL_EVERY  # s per control step
FRAME_EVERY = 3  # control steps per rendered frame
FRAME_RATE = 1.0 / (FRAME_EVERY * CONTROL_EVERY * TIMESTEP)  # 33.3 frames per second
MIN_RISE = 0.4  # m the ball must rise for a successful lift

PARAM_RANGES = {
    "duration": (0.5, 2.5),  # s of the lift
    "tremor": (0.0, 0.04),  # rad, std of the noise on joint targets
}
RAW_FEATURES = ("hand_x", "hand_z", "hand_angle", "ball_x", "ball_z", "shoulder", "elbow", "wrist")
N_QPOS = 11  # the suite model's qpos and qvel: 4 arm joints, 4 finger joints, the ball's x, z and rotation
NEWEST = slice((STACK - 1) * len(RAW_FEATURES), STACK * len(RAW_FEATURES))  # a state's newest raw sample
HAND = slice(0, 2)  # hand x, z in a raw sample


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


def control_steps(duration: float) -> int:
    """Control steps of a lift taking ``duration`` s, the holds before and after included."""
    return round((HOLD_BEFORE + duration + HOLD_AFTER) / CONTROL_DT)


def _servo(model: mujoco.MjModel, data: mujoco.MjData, target: np.ndarray) -> None:
    """The arm's motor commands toward joint ``target``: PD with gravity compensation, clipped to the motors."""
    tau = KP * (target - data.qpos[:4]) - KD * data.qvel[:4] + data.qfrc_bias[:4]
    data.ctrl[:4] = np.clip(tau / model.actuator_gear[:4, 0], -1.0, 1.0)


def _grasp(model: mujoco.MjModel, data: mujoco.MjData, pinch: int) -> None:
    """Start with the arm down and close the gripper on the ball, held in place meanwhile."""
    data.qpos[:4] = Q_DOWN
    mujoco.mj_kinematics(model, data)
    # the ball's slide joints have ref = its default place, so their qpos are its x and z
    hold = data.site_xpos[pinch][[0, 2]] + np.array([0.0, BALL_IN_HAND])
    data.ctrl[4] = GRASP
    for _ in range(SETTLE_STEPS):
        data.qpos[8:10], data.qvel[8:11] = hold, 0.0
        _servo(model, data, Q_DOWN)
        mujoco.mj_step(model, data)
    data.qpos[8:10], data.qvel[8:11] = hold, 0.0
    mujoco.mj_forward(model, data)


class LiftPolicy:
    """The lift as ``policy(obs) -> action`` (``SkillPolicy``): open loop, joint targets on a minimum-jerk path
    plus the tremor, a new sample every TREMOR_HOLD control steps; the hand's path is read off the observations."""

    def __init__(self, params: dict[str, float], seed: int) -> None:
        self.duration, self.tremor = float(params["duration"]), float(params["tremor"])
        self._rng = np.random.default_rng(seed)
        self._noise = np.zeros(4)
        self._n = control_steps(self.duration)
        self._k = 0
        self._hand: list[np.ndarray] = []  # hand x, z per raw sample, as observed
        self.done = False

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        k = self._k
        if k and (k - 1) % RAW_EVERY == 0:  # the step just taken sampled the arm
            self._hand.append(np.asarray(obs, dtype=np.float64)[NEWEST][HAND])
        if k == self._n:
            self.done = True
            return np.zeros(4)
        t = k * CONTROL_DT
        q_ref = Q_DOWN + (Q_UP - Q_DOWN) * min_jerk(np.array((t - HOLD_BEFORE) / self.duration))
        if self.tremor and k % TREMOR_HOLD == 0 and HOLD_BEFORE <= t < HOLD_BEFORE + self.duration + 0.3:
            self._noise = self.tremor * self._rng.standard_normal(4)
        elif k % TREMOR_HOLD == 0:
            self._noise = np.zeros(4)
        self._k += 1
        return q_ref + self._noise

    def measured(self) -> dict[str, float]:
        return lift_proxies(np.array(self._hand).reshape(-1, 2))


@dataclass
class LiftRecording:
    """What a rollout keeps besides its states: raw samples (50 Hz), qpos + qvel at them, replay frames."""

    raw: list[np.ndarray] = field(default_factory=list)  # RAW_FEATURES per raw sample
    sim: list[np.ndarray] = field(default_factory=list)  # qpos + qvel per raw sample: the raw view
    replay: list[np.ndarray] = field(default_factory=list)  # qpos per rendered frame


class ManipulatorSim:
    """The arm under per-control-step joint targets (``SkillSim``), the ball grasped at reset."""

    action_low, action_high = np.full(4, -np.pi), np.full(4, np.pi)  # rad: any joint angle
    max_steps = control_steps(PARAM_RANGES["duration"][1])  # the longest lift

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self._pinch = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "pinch")
        self._ball = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "ball")

    def reset(self, params: dict[str, float], seed: int) -> tuple[np.ndarray, bool]:
        self.data = mujoco.MjData(self.model)
        _grasp(self.model, self.data, self._pinch)
        self.recording = LiftRecording()
        self._window = deque([self._sample()] * STACK, maxlen=STACK)  # the arm at rest fills the first state
        self._k = 0
        return self._observe(), False

    def step(self, action: np.ndarray) -> tuple[np.ndarray, bool]:
        data, rec = self.data, self.recording
        _servo(self.model, data, np.asarray(action, dtype=np.float64))
        mujoco.mj_step(self.model, data, nstep=CONTROL_EVERY)
        k, self._k = self._k, self._k + 1
        sampled = k % RAW_EVERY == 0
        if sampled:
            rec.raw.append(self._sample())
            rec.sim.append(np.concatenate([data.qpos, data.qvel]))
            self._window.append(rec.raw[-1])
        if k % FRAME_EVERY == 0:
            rec.replay.append(data.qpos.copy())
        return self._observe(), sampled and len(rec.raw) % STACK == 0

    def _sample(self) -> np.ndarray:
        """RAW_FEATURES now."""
        data, pinch = self.data, self._pinch
        r = data.site_xmat[pinch].reshape(3, 3)
        return np.array([data.site_xpos[pinch][0], data.site_xpos[pinch][2], np.arctan2(r[2, 2], r[0, 2]),
                         data.xpos[self._ball][0], data.xpos[self._ball][2], *data.qpos[1:4]])

    def _observe(self) -> np.ndarray:
        """The state of the last STACK raw samples: the samples and the hand's third differences (mm)."""
        window = np.array(self._window)
        jitter = 1000.0 * np.diff(window[:, HAND], n=3, axis=0).reshape(-1)
        return np.concatenate([window.reshape(-1), jitter])


def _climb(z: np.ndarray) -> tuple[float, float]:
    """The hand's height at rest before the lift and how far it climbs, from its heights at 50 Hz."""
    z0, z1 = z[: int(HOLD_BEFORE * 50)].mean(), z[-int(0.3 * 50):].mean()
    return z0, z1 - z0


def lift_proxies(hand: np.ndarray) -> dict[str, float]:
    """The attributes' proxies from the hand's path at 50 Hz [T, (x, z)]: 10-90 % rise speed, jitter (mm)."""
    z = hand[:, 1]
    z0, climb = _climb(z)
    t = np.arange(len(z)) / 50.0
    t10 = t[np.argmax(z >= z0 + 0.1 * climb)]
    t90 = t[np.argmax(z >= z0 + 0.9 * climb)]
    speed = 0.8 * climb / max(t90 - t10, 1e-3)
    return {"speed": float(speed), "instability": 1000.0 * quadratic_residual(hand)}  # mm


def lift_overlays(hand: np.ndarray, proxies: dict[str, float], frame_rate: float) -> list[Overlay]:
    """The page's overlays from the hand geom's centre per frame, float[F, 3]: the hand's path with where the
    10-90 % rise starts and ends (the speed measured over it), and the path again with the jitter it measures."""
    z = hand[:, 2]
    z0, z1 = z[: max(1, int(HOLD_BEFORE * frame_rate))].mean(), z[-max(1, int(0.3 * frame_rate)):].mean()
    k10, k90 = int(np.argmax(z >= z0 + 0.1 * (z1 - z0))), int(np.argmax(z >= z0 + 0.9 * (z1 - z0)))
    path = tuple(tuple(map(float, p)) for p in hand)
    rise = (Marker(k10, path[k10], "10 % of the climb"),
            Marker(k90, path[k90], f"90 %: {(k90 - k10) / frame_rate:.2f} s, {proxies['speed']:.2f} m/s"))
    return [Overlay("speed", "The hand's path and the middle 80 % of its climb", rise, path),
            Overlay("instability", "The hand's path: jitter shows as wiggles",
                    (Marker(len(path) - 1, path[-1], f"jitter {proxies['instability']:.2f} mm"),), path)]


def measure(raw: np.ndarray, states: np.ndarray) -> tuple[dict[str, float], bool, dict[str, float]]:
    """Proxies, success and diagnostics from the raw 50 Hz samples [T, RAW_FEATURES] and the states."""
    _, climb = _climb(raw[:, 1])
    ball_rise = raw[-1, 4] - raw[0, 4]
    held = np.linalg.norm(raw[-1, 3:5] - raw[-1, :2]) < 0.08
    success = bool(held and ball_rise > MIN_RISE and np.isfinite(states).all())
    return lift_proxies(raw[:, HAND]), success, {"ball_rise_m": float(ball_rise), "climb_m": float(climb)}


# free-text feedback's anchors (rba.interact.free_text): both sides written with the same nouns
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
    description = "A robot arm lifts a ball it holds; tune how fast and how steadily."
    attributes = (
        AttributeSpec("speed", "How fast the arm lifts the ball.", "m/s"),
        AttributeSpec("instability", "How shaky and jittery the arm's motion is.", "mm"),
    )
    state_dim = STACK * len(RAW_FEATURES) + 2 * (STACK - 3)
    param_names = tuple(PARAM_RANGES)
    param_ranges = PARAM_RANGES
    frame_rate = FRAME_RATE
    feedback_phrases = FEEDBACK_PHRASES
    zeta_noise = 0.06  # decisions 0006 and 0003
    generate_spread = 0.5  # decision 0003
    belief_prior = 0.05  # decision 0010
    noisy_skill = True  # the tremor is drawn from the seed (zeta_residual.md); decision 0007
    generate_seconds = 1.0  # decision 0005

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
            assert self._model.opt.timestep == TIMESTEP  # the policy's clock counts TIMESTEP's
            target = mujoco.mj_name2id(self._model, mujoco.mjtObj.mjOBJ_GEOM, "target_ball")
            if target >= 0:
                self._model.geom_rgba[target, 3] = 0.0  # the bring_ball target is not part of this task
        return self._model

    def rollout(self, params: dict[str, float], seed: int) -> Rollout:
        sim = ManipulatorSim(self._physics())
        states = np.asarray(run_skill(sim, LiftPolicy(params, seed), params, seed), dtype=np.float32)
        rec = sim.recording
        proxies, success, info = measure(np.asarray(rec.raw, dtype=np.float64), states)
        if self.raw_states:
            states = stack_samples(rec.sim, STACK)
        return Rollout("", self.name, dict(params), seed, states, np.asarray(rec.replay), proxies, success, info)

    def clip_view(self, rollout: Rollout | None = None) -> MujocoView:
        return MujocoView(self._physics(), Camera(CAMERA_DISTANCE, CAMERA_ELEVATION, CAMERA_LOOKAT), self._renderers)

    def render(self, rollout: Rollout, width: int, height: int, frames: slice = ALL_FRAMES) -> Iterator[np.ndarray]:
        return self.clip_view(rollout).replay(rollout.replay[frames], width, height)

    def clip_overlays(self, rollout: Rollout, track: Mapping[str, np.ndarray]) -> list[Overlay]:
        return lift_overlays(track["hand"], rollout.proxies, self.frame_rate)

    def simulator(self) -> SkillSim:
        return ManipulatorSim(self._physics())

    def skill_policy(self, params: dict[str, float], seed: int) -> SkillPolicy:
        return LiftPolicy(params, seed)


class ManipulatorRaw(Manipulator):
    """The manipulator's raw view (``--states raw``): each 10 Hz state is MuJoCo's ``qpos`` and ``qvel`` (11 + 11)
    at five 50 Hz samples (the feature view's own stack), without the hand's path or its third differences.

    ``instability`` is the hand's jitter within 0.1 s; here the models must find it in the joint rates
    themselves (the tremor is on joint targets, so it shows in ``qvel``), not in a ready-made jitter feature.
    """

    name = "manipulator_raw"
    raw_states = True
    state_dim = STACK * 2 * N_QPOS
    generate_seconds = Domain.generate_seconds  # decision 0005 measured the feature view; this one keeps the default
    simulator, skill_policy = Domain.simulator, Domain.skill_policy  # no env: see the module docstring


CAMERA_LOOKAT = (0.15, 0.0, 0.42)  # m: between the low and the raised hand
CAMERA_DISTANCE = 1.05  # m
CAMERA_ELEVATION = -8.0  # degrees
