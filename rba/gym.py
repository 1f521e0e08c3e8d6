"""``import rba.gym``: a Gymnasium environment per registered domain with a step interface, the exported reward
as a wrapper, and the scripted skill with a profile's parameters as a policy.

* ``rba/<Domain>-v0``: ``rba/Walker-v0``, ``rba/Manipulator-v0``, ``rba/Snake-v0``, ``rba/LaneChange-v0`` (and
  ``rba/Toy-v0`` once the tests registered ``toy``): the domain's :class:`~rba.domains.base.SkillSim`; the
  observation is the project's state vector (float64), the action the scripted skill's (the walker: six motor
  commands and the torso assist per 2.5 ms physics step; the manipulator: four joint targets per 10 ms; the
  snake: 13 joint targets and 14 link frictions per 10 ms; the lane change: the ego's acceleration and steering
  per 1/15 s). ``reset(seed=profile.seed, options={"params": profile.params})`` starts where the rollout starts
  (without params: params sampled from the env's generator). ``info["recorded"]``: this observation is one
  of the rollout's states; ``info["step"]``: steps since reset (open-loop skills may read the time there).
  The env's own reward is 0: it has no task; the reward is the export's.
* :class:`ExportedReward`: reward = the export's rθ(s | condition) on each recorded state (0 between them:
  the models were trained on those), so an episode's return is Σ_t rθ(s_t | v*) over the rollout's states.
* :func:`skill_policy`: ``policy(obs) -> action``; :func:`run_policy` runs it and returns the recorded states.
* :func:`run_episode`: any policy's :class:`Episode`, whose ``proxies()`` are the attributes it reached, measured
  from its observations (``Domain.observed_proxies``: the walker and the lane change): how close a policy trained on
  an export's reward comes to the profile (``examples/sb3_policy/``).

Domains without a step interface (``Domain.simulator`` raises) get no environment: the raw views and
``lane_change_image``, whose states are not what the skill's policy reads (each domain module says why).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from rba.core.registry import import_object
from rba.data.export_zip import Export, ExportError, Profile, read_export
from rba.domains import Domain, domain_names, domain_target, get_domain
from rba.domains.base import SkillPolicy

NAMESPACE, VERSION = "rba", 0


def env_id(domain: str) -> str:
    """``rba/<CamelCaseDomain>-v0``: ``walker`` -> ``rba/Walker-v0``, ``lane_change`` -> ``rba/LaneChange-v0``."""
    return f"{NAMESPACE}/{''.join(part.capitalize() for part in domain.split('_'))}-v{VERSION}"


def has_simulator(domain: str) -> bool:
    """Whether the domain's class overrides ``Domain.simulator`` (checked without instantiating it)."""
    return import_object(domain_target(domain)).simulator is not Domain.simulator


class SkillEnv(gym.Env):
    """A domain's simulator stepped by the skill's actions (see the module docstring)."""

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 (Gymnasium's own class attribute)

    def __init__(self, domain: str) -> None:
        self.domain = get_domain(domain)
        self.sim = self.domain.simulator()
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (self.domain.state_dim,), np.float64)
        self.action_space = gym.spaces.Box(self.sim.action_low, self.sim.action_high, dtype=np.float64)
        self._steps = 0

    def _params(self, options: dict[str, Any] | None) -> dict[str, float]:
        params = (options or {}).get("params")
        if params is None:
            return self.domain.sample_params(self.np_random)
        if not isinstance(params, dict) or sorted(params) != sorted(self.domain.param_names):
            raise ValueError(f"options['params'] must name exactly {self.domain.name!r}'s param_names "
                             f"{list(self.domain.param_names)}")
        return {k: float(v) for k, v in params.items()}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        params = self._params(options)
        skill_seed = int(seed) if seed is not None else int(self.np_random.integers(2**31))
        obs, recorded = self.sim.reset(params, skill_seed)
        self._steps = 0
        return obs, {"step": 0, "recorded": recorded, "params": params, "seed": skill_seed}

    def step(self, action):
        a = np.clip(np.asarray(action, dtype=np.float64), self.action_space.low, self.action_space.high)
        obs, recorded = self.sim.step(a)
        self._steps += 1
        return obs, 0.0, False, self._steps >= self.sim.max_steps, {"step": self._steps, "recorded": recorded}


def _as_export(export: Export | str | Path) -> Export:
    return export if isinstance(export, Export) else read_export(Path(export))


class ExportedReward(gym.Wrapper):
    """Reward = the export's rθ(s | condition) on every recorded state: ``ExportedReward(zip)`` or ``(zip, env)``."""

    def __init__(self, export: Export | str | Path, env: gym.Env | None = None) -> None:
        self.export = _as_export(export)
        if self.export.reward is None:
            raise ExportError(f"this export has no reward model: {self.export.profile.reward_note}")
        domain = self.export.profile.domain
        super().__init__(env if env is not None else gym.make(env_id(domain)))
        given = getattr(self.env.unwrapped, "domain", None)
        if not isinstance(given, Domain) or given.name != domain:
            raise ExportError(f"this export's reward is for {domain!r} ({env_id(domain)}); the env given is "
                              f"{self.env.spec.id if self.env.spec else type(self.env.unwrapped).__name__}")
        self._pending = 0.0

    def _reward(self, obs: np.ndarray, recorded: bool) -> float:
        return self.export.reward.total(obs[None]) if recorded else 0.0

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._pending = self._reward(obs, info["recorded"])  # the first state's, paid with the first step
        return obs, info

    def step(self, action):
        obs, _, terminated, truncated, info = self.env.step(action)
        reward, self._pending = self._pending + self._reward(obs, info["recorded"]), 0.0
        return obs, reward, terminated, truncated, info


def skill_policy(profile: Profile | Export | str | Path) -> SkillPolicy:
    """The domain's scripted skill with the profile's parameters and seed, as ``policy(obs) -> action`` (one per
    episode)."""
    p = profile if isinstance(profile, Profile) else _as_export(profile).profile
    return get_domain(p.domain).skill_policy(p.params, p.seed)


@dataclass(frozen=True)
class Episode:
    """One episode of a policy in a domain's env: what it saw, and what it did to the attributes."""

    domain: Domain
    observations: np.ndarray  # float64[N, state_dim]: every step's, the reset's first
    recorded: np.ndarray  # bool[N]: which observations are states (``info["recorded"]``)
    rewards: np.ndarray  # float64[N - 1]: the env's reward per step (the export's with ``ExportedReward``)
    actions: np.ndarray  # float64[N - 1, action_dim]: each step's action as the policy gave it

    @property
    def states(self) -> np.ndarray:
        """The recorded observations, float64[T, state_dim]: what the models see (a rollout's ``states``)."""
        return self.observations[self.recorded]

    def proxies(self) -> dict[str, float]:
        """The attributes this episode reached, measured from its observations (``Domain.observed_proxies``)."""
        return self.domain.observed_proxies(self.observations)


def run_episode(env: gym.Env, policy: Callable[[np.ndarray], np.ndarray], seed: int, params: dict[str, float],
                max_steps: int | None = None) -> Episode:
    """Run ``policy`` (any ``obs -> action``; a :class:`SkillPolicy` stops when ``done``) in ``env`` from the skill's
    start until it is done, the episode ends or it took ``max_steps`` actions."""
    obs, info = env.reset(seed=seed, options={"params": params})
    observations, recorded, rewards, actions, ended = [], [], [], [], False
    while True:  # rba.domains.base.run_skill's loop, over the env: the policy sees the last observation too
        observations.append(obs)
        recorded.append(bool(info["recorded"]))
        action = policy(obs)
        if getattr(policy, "done", False) or ended or len(rewards) == max_steps:
            break
        obs, reward, terminated, truncated, info = env.step(action)
        rewards.append(float(reward))
        actions.append(np.asarray(action, dtype=np.float64))
        ended = terminated or truncated
    return Episode(env.unwrapped.domain, np.array(observations), np.array(recorded), np.array(rewards),
                   np.array(actions))


def run_policy(env: gym.Env, policy: SkillPolicy, seed: int, params: dict[str, float]) -> np.ndarray:
    """Run ``policy`` in ``env`` from the skill's start until the skill is done or the episode ends; the recorded
    observations, float64[T, state_dim] (the rollout's states)."""
    return run_episode(env, policy, seed, params).states


def register_envs() -> list[str]:
    """Register the env of every domain with a step interface not registered yet (call again after adding
    domains); the ids registered now."""
    made = []
    for name in domain_names():
        if env_id(name) not in gym.registry and has_simulator(name):
            gym.register(id=env_id(name), entry_point="rba.gym:SkillEnv", kwargs={"domain": name})
            made.append(env_id(name))
    return made


register_envs()
