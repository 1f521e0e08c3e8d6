"""A domain from a Gymnasium MuJoCo environment, a parameterised skill and attribute measurements.

A subclass names the env (``env_id``, ``env_kwargs``: e.g. ``"HalfCheetah-v5"`` from ``gymnasium[mujoco]``), the
skill (``param_ranges``, the parameter box, and ``skill(params, seed)``, the policy ``action = act(obs, step)``),
and the measurements (``observed_proxies(observations)``: every attribute's proxy from the episode's
observations). The
adapter runs the env for ``episode_steps`` steps, whatever its own reward and termination say (the skill has no
task): the states are the env's observations (one per step, the reset's included), the replay is MuJoCo's
``qpos`` at each of them, and rendering poses the env's model at those rows (``rba.domains.mujoco_render``).

The rollout is ``run_skill`` over :class:`GymMujocoSim` and :class:`MeasuredSkill`, the same pair ``rba.gym``
steps, so a plugin domain gets its ``rba/<Name>-v0`` env too. Measurements read observations only, so the
policy's ``measured()`` equals the rollout's proxies.

MuJoCo prints a model's compile warnings (a deprecated XML attribute of the env's own file) and writes them to
``MUJOCO_LOG.TXT`` in the working folder; each env is made once per simulator, so they go to the log instead.
"""

from __future__ import annotations

import contextlib
import logging
from abc import abstractmethod
from collections.abc import Callable, Iterator, Mapping
from types import MappingProxyType

import mujoco
import numpy as np

from rba.domains.base import ALL_FRAMES, Domain, Rollout, run_skill
from rba.domains.mujoco_render import Camera, MujocoView, Sky, ThreadRenderers

log = logging.getLogger(__name__)

Act = Callable[[np.ndarray, int], np.ndarray]  # the skill with its parameters: (observation, step) -> action


@contextlib.contextmanager
def _mujoco_warnings_logged() -> Iterator[None]:
    """MuJoCo's warnings go to this module's log (debug) while the block runs, not to stdout and a log file."""
    before = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda msg: log.debug("MuJoCo: %s", msg))
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(before)


def make_env(env_id: str, kwargs: Mapping[str, object]):
    """The bare Gymnasium env (no wrappers: the adapter keeps its own time limit and never renders through it)."""
    import gymnasium as gym

    with _mujoco_warnings_logged():
        return gym.make(env_id, disable_env_checker=True, **dict(kwargs)).unwrapped


class GymMujocoSim:
    """The env stepped by the skill's actions (``SkillSim``); every observation is recorded, its ``qpos`` kept."""

    def __init__(self, env, max_steps: int) -> None:
        self.env, self.max_steps = env, max_steps
        self.action_low = np.asarray(env.action_space.low, dtype=np.float64)
        self.action_high = np.asarray(env.action_space.high, dtype=np.float64)
        self.replay: list[np.ndarray] = []

    def reset(self, params: dict[str, float], seed: int) -> tuple[np.ndarray, bool]:
        obs, _ = self.env.reset(seed=int(seed))
        self.replay = [self.env.unwrapped.data.qpos.copy()]
        return np.asarray(obs, dtype=np.float64), True

    def step(self, action: np.ndarray) -> tuple[np.ndarray, bool]:
        obs, *_ = self.env.step(np.clip(np.asarray(action, dtype=np.float64), self.action_low, self.action_high))
        self.replay.append(self.env.unwrapped.data.qpos.copy())
        return np.asarray(obs, dtype=np.float64), True


class MeasuredSkill:
    """The skill as a ``SkillPolicy``: ``act`` for ``steps`` steps, then done; ``measured()`` from what it saw."""

    def __init__(self, act: Act, measure: Callable[[np.ndarray], dict[str, float]], steps: int) -> None:
        self._act, self._measure, self._steps = act, measure, steps
        self._seen: list[np.ndarray] = []
        self.done = False

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        self._seen.append(np.asarray(obs, dtype=np.float64))
        step = len(self._seen) - 1
        self.done = step >= self._steps
        return np.asarray(self._act(self._seen[-1], step), dtype=np.float64)

    def measured(self) -> dict[str, float]:
        return {k: float(v) for k, v in self._measure(np.array(self._seen)).items()}


class GymMujocoDomain(Domain):
    """Subclass with the class attributes and the three methods below (the module docstring says what each is)."""

    env_id: str
    env_kwargs: Mapping[str, object] = MappingProxyType({})
    episode_steps: int  # env steps per rollout: the rollout has episode_steps + 1 states
    camera: Camera  # a side view whose ``aim`` follows the body: the camera only slides, so the sky is drawn once

    def __init__(self) -> None:
        self._model: mujoco.MjModel | None = None
        self._renderers = ThreadRenderers(sky=Sky.ONCE)

    @abstractmethod
    def skill(self, params: dict[str, float], seed: int) -> Act:
        """The skill with ``params``: ``act(obs, step) -> action`` (``seed``: the episode's, for its own noise)."""

    @abstractmethod
    def observed_proxies(self, observations: np.ndarray) -> dict[str, float]:
        """Every attribute's proxy from an episode's observations, float64[N, obs_dim] (the reset's first): the
        skill's, or any policy's in ``simulator()``."""

    def succeeded(self, observations: np.ndarray) -> bool:
        """Whether the episode is one to keep (libraries keep successes only): by default, finite observations."""
        return bool(np.isfinite(observations).all())

    def simulator(self) -> GymMujocoSim:
        env = make_env(self.env_id, self.env_kwargs)
        if env.observation_space.shape != (self.state_dim,) or abs(env.dt * self.frame_rate - 1.0) > 1e-9:
            raise ValueError(f"domain {self.name!r} declares state_dim {self.state_dim} and frame_rate "
                             f"{self.frame_rate:g}; {self.env_id} has observations of shape "
                             f"{env.observation_space.shape} and {1 / env.dt:g} steps per second")
        return GymMujocoSim(env, self.episode_steps)

    def skill_policy(self, params: dict[str, float], seed: int) -> MeasuredSkill:
        return MeasuredSkill(self.skill(params, seed), self.observed_proxies, self.episode_steps)

    def rollout(self, params: dict[str, float], seed: int) -> Rollout:
        sim = self.simulator()
        observations = np.array(run_skill(sim, self.skill_policy(params, seed), params, seed))
        proxies = {k: float(v) for k, v in self.observed_proxies(observations).items()}
        return Rollout("", self.name, dict(params), seed, observations.astype(np.float32), np.array(sim.replay),
                       proxies, self.succeeded(observations))

    def clip_view(self, rollout: Rollout | None = None) -> MujocoView:
        if self._model is None:
            self._model = make_env(self.env_id, self.env_kwargs).model
        return MujocoView(self._model, self.camera, self._renderers)

    def render(self, rollout: Rollout, width: int, height: int, frames: slice = ALL_FRAMES) -> Iterator[np.ndarray]:
        return self.clip_view(rollout).replay(rollout.replay[frames], width, height)
