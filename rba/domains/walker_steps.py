"""The walker stepped one physics step (2.5 ms) at a time, and its scripted gait as a policy on observations.

The step interface is the rollout loop's (``rba.domains.walker.run``) cut at ``physics.act``: an action is
one physics step's :class:`~rba.domains.walker.Command`, the six motor commands in [-1, 1] and the torso
assist (rootz force, rootx force, pitch torque), which is part of the scripted skill. An observation is the
state vector (``STATE_FEATURES``, float64) of that step; every ``STATE_EVERY``-th is one the rollout
records (foot peak speeds run over the steps since the last recorded one, as in the rollout).

The policy is the same :class:`~rba.domains.walker.GaitController`, fed an :class:`ObservedWalker` that
answers its questions from the observation alone: joint and torso quantities are in it, positions follow by
the planar kinematics, the torso's absolute x from the start pose the gait plans, and the feed-forward's bias
forces from the policy's own copy of the MuJoCo model at the previous observation (MuJoCo's ``mj_step``
leaves those of the state it stepped from). Its clock is its call count: one call per step.
"""

from __future__ import annotations

import math

import numpy as np

from rba.domains.walker import (
    MAX_DURATION,
    STATE_EVERY,
    STATE_FEATURES,
    GaitController,
    GaitPlan,
    WalkerGeometry,
    WalkerPhysics,
    start,
    state_features,
    touchdown_proxies,
)

ASSIST_LIMITS = (5000.0, 5000.0, 2000.0)  # N, N, N·m: action bounds, > 10x what the gait's assist asks (~120 N)
_F = {name: i for i, name in enumerate(STATE_FEATURES)}


class WalkerSim:
    """The walker's physics under per-step actions (``rba.domains.base.SkillSim``)."""

    action_low = np.array([-1.0] * 6 + [-a for a in ASSIST_LIMITS])
    action_high = np.array([1.0] * 6 + list(ASSIST_LIMITS))

    def __init__(self) -> None:
        self.physics = WalkerPhysics.from_suite()
        self.max_steps = int(MAX_DURATION / self.physics.timestep())
        self._k, self._x_start, self._peaks = 0, 0.0, [0.0, 0.0]

    def reset(self, params: dict[str, float], seed: int) -> tuple[np.ndarray, bool]:
        start(self.physics, params, seed)
        self.physics.observe()
        self._k, self._x_start = 0, self.physics.torso_x()
        return self._observe()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, bool]:
        a = np.asarray(action, dtype=np.float64).tolist()
        self.physics.act(tuple(a[:6]), (a[6], a[7], a[8]))
        self.physics.observe()
        self._k += 1
        return self._observe()

    def _observe(self) -> tuple[np.ndarray, bool]:
        peaks, speeds = self._peaks, self.physics.foot_speeds()
        peaks[:] = [max(peaks[0], speeds[0]), max(peaks[1], speeds[1])]
        obs = np.array(state_features(self.physics, peaks[0], peaks[1], self._x_start))
        recorded = self._k % STATE_EVERY == 0 and self._k < self.max_steps
        if self._k % STATE_EVERY == 0:
            peaks[:] = [0.0, 0.0]
        return obs, recorded


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


class WalkerSkillPolicy:
    """The scripted gait with fixed parameters as ``policy(obs) -> action`` (``rba.domains.base.SkillPolicy``)."""

    def __init__(self, params: dict[str, float]) -> None:
        mirror = WalkerPhysics.from_suite()  # the policy's own model: the feed-forward's bias forces
        self.plan = GaitPlan.from_params(params, mirror.geometry)
        self._view = ObservedWalker(mirror, self.plan.start_pose(mirror.geometry)[1])
        self._controller: GaitController | None = None
        self._k = 0
        self.done = False

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        self._view.read(obs)
        if self._controller is None:
            self._controller = GaitController(self.plan, self._view)
        t = self._k * self._view.timestep()
        if self._controller.finished(t):
            self.done = True
            return np.zeros(9)
        command = self._controller.control(t, self._view)
        self._k += 1
        return np.array(command.ctrl + command.assist)

    def measured(self) -> dict[str, float]:
        return touchdown_proxies(self._controller.touchdowns if self._controller else [])
