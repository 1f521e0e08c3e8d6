"""The walker stepped one physics step (2.5 ms) at a time, and its scripted gait as a policy on observations.

The step interface is the rollout's own loop (``run_skill``) cut at ``physics.act``: an action is
one physics step's :class:`~rba.domains.walker.gait.Command`, the six motor commands in [-1, 1] and the torso
assist (rootz force, rootx force, pitch torque), which is part of the scripted skill. An observation is the
state vector (``STATE_FEATURES``, float64) of that step; every ``STATE_EVERY``-th is one the rollout
records (foot peak speeds run over the steps since the last recorded one).

The rollout's policy is :class:`GaitPolicy` on the sim's own physics; ``rba.gym``'s is the same
:class:`~rba.domains.walker.gait.GaitController`, fed an :class:`ObservedWalker` that
answers its questions from the observation alone: joint and torso quantities are in it, positions follow by
the planar kinematics, the torso's absolute x from the start pose the gait plans, and the feed-forward's bias
forces from the policy's own copy of the MuJoCo model at the previous observation (MuJoCo's ``mj_step``
leaves those of the state it stepped from). Its clock is its call count: one call per step.
"""

from __future__ import annotations

import numpy as np

from rba.domains.walker.gait import GaitController, GaitPlan, start
from rba.domains.walker.measure import STATE_EVERY, STATE_FEATURES, Recording, touchdown_proxies
from rba.domains.walker.physics import WalkerPhysics, WalkerReading

MAX_DURATION = 40.0  # s: a clip ends here even if the gait never finishes
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


class ObservedWalker(WalkerReading):
    """The walker's getters answered from one observation alone (see the module), for ``GaitController``."""

    def __init__(self, mirror: WalkerPhysics, x_start: float) -> None:
        super().__init__(mirror.geometry, mirror.timestep(), mirror.body_weight())
        self._mirror, self._x_start = mirror, x_start
        self._prev: tuple[list[float], list[float]] | None = None

    def read(self, obs: np.ndarray) -> None:
        """Take the reading from ``obs`` (``STATE_FEATURES``); the bias forces are the mirror's at the previous one."""
        o = np.asarray(obs, dtype=np.float64).tolist()
        torso = (o[_F["torso_height"]], o[_F["torso_x_from_start"]] + self._x_start, o[_F["torso_pitch"]])
        torso_vel = (o[_F["torso_vz"]], o[_F["torso_vx"]], o[_F["torso_pitch_rate"]])
        joints = o[_F["right_hip"]:_F["right_hip"] + 6]
        joint_vel = o[_F["right_hip_vel"]:_F["right_hip_vel"] + 6]
        rootz = torso[0] - self.geometry.torso_z0  # may differ from the physics' rootz in the last bit
        q, v = [rootz, torso[1], torso[2], *joints], [*torso_vel, *joint_vel]
        bias = self._mirror.bias_at(*(self._prev or (q, v)))
        self._prev = (q, v)
        fv = _F["right_foot_vx"]
        self._read(torso, torso_vel, joints, joint_vel, self.geometry.kinematics(rootz, torso[1], torso[2], joints),
                   (o[_F["right_foot_clearance"]], o[_F["left_foot_clearance"]]),
                   (o[fv], o[fv + 1], o[fv + 2], o[fv + 3]), bias)


class GaitPolicy:
    """The scripted gait with fixed parameters as ``policy(obs) -> action``, reading ``view`` (what the
    :class:`GaitController` asks): on the simulator's own physics it is the rollout's skill."""

    def __init__(self, plan: GaitPlan, view: WalkerReading) -> None:
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
