"""Train a Stable-Baselines3 policy on an export's reward and measure how close its attributes come to the profile.

The policy acts in the domain's ``rba.gym`` env, every episode starting where the chosen behaviour starts (its params
and seed) and lasting as many steps as the scripted skill took for it; its reward is the export's rθ(s | v*) on each
recorded state (``rba.gym.ExportedReward``). Nothing else tells it what the profile is. Afterwards the learned
policy (deterministic) runs one episode and its attributes are measured from the observations
(``rba.gym.Episode.proxies``): the distance to the profile's, per attribute, in the domain's normal-precision ε.
Three references put that number in context: the same network before training, uniformly random actions, and the
scripted skill at the profile's params (which reproduces the profile: ~0).

    python examples/sb3_policy/train.py --export behaviour.zip --algo SAC --steps 50000
    python examples/sb3_policy/train.py --domain lane_change --rollout serve-00042 --steps 20000

``--domain`` + ``--rollout`` first writes an export of that library rollout as the chosen behaviour (rθ conditioned
on its ζσ, as the app's export of a session that ended satisfied with it; no clip), so the example runs from a fresh
clone with the shipped models. ``--out`` receives ``model.zip`` (``PPO.load`` / ``SAC.load``), ``report.json`` and
the export it trained on.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from rba.core.fileio import load_json, save_text
from rba.core.store import model_files
from rba.data.export_zip import Export, ExportError, ExportSource, Profile, read_export, write_export
from rba.data.library import SPLITS, SkillLibrary
from rba.domains import Domain, domain_names, get_domain
from rba.gym import Episode, ExportedReward, env_id, has_simulator, run_episode, skill_policy

ALGORITHMS: dict[str, type[BaseAlgorithm]] = {"PPO": PPO, "SAC": SAC}
PPO_ROLLOUT = 2048  # PPO's steps per update (SB3's default), fewer when the whole run is shorter
PPO_BATCH = 64
RANDOM_EPISODES = 3  # random actions' distance is the mean over this many episodes


def export_library_rollout(domain: str, rollout_id: str, out: Path, rep: str = "onehot",
                           data_root: Path | None = None, models_root: Path | None = None) -> Path:
    """Write the export of library rollout ``rollout_id`` (``<split>-<number>``) as the chosen behaviour of an
    RBA-Global session satisfied with it at once: rθ conditioned on its ζσ, re-fitted on the serve library where the
    domain does so; no clip (training reads the profile and the reward only)."""
    split = rollout_id.split("-")[0]
    if split not in SPLITS:
        raise ExportError(f"rollout id {rollout_id!r} names no library: <split>-<number> with split one of "
                          f"{', '.join(SPLITS)} (e.g. serve-00042)")
    library, serve = SkillLibrary.load(domain, split, data_root), SkillLibrary.load(domain, "serve", data_root)
    if rollout_id not in library:
        raise ExportError(f"{domain}'s {split} library has no rollout {rollout_id!r}; it holds {library.ids[0]} to "
                          f"{library.ids[-1]}")
    models = model_files(models_root)
    version = "-".join(load_json(models.card(domain, kind, rep))["weights_sha"] for kind in ("ranker", "global_reward"))
    rounds = [{"step": 0, "feedback": "satisfied", "rollout_before": rollout_id, "rollout_after": rollout_id}]
    chosen = None if split == "serve" else library.rollout(library.index_of(rollout_id))
    write_export(out, ExportSource(domain, "global", rep, version, "builtin", models.root, serve, rollout_id, rounds,
                                   clip=b"", rollout=chosen))
    return out


class ProfileStart(gym.Wrapper):
    """Every reset starts where the profile's behaviour starts (its params and seed), whatever the caller asks."""

    def __init__(self, env: gym.Env, profile: Profile) -> None:
        super().__init__(env)
        self.profile = profile

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        return self.env.reset(seed=self.profile.seed, options={"params": self.profile.params})


def skill_steps(profile: Profile) -> int:
    """Env steps the scripted skill takes for the profile's behaviour: the length of every training episode."""
    env = gym.make(env_id(profile.domain))
    return len(run_episode(env, skill_policy(profile), profile.seed, profile.params).rewards)


def training_env(export: Export, steps: int) -> gym.Env:
    """The env the policy learns in: the export's reward, the profile's start, ``steps`` per episode, actions
    rescaled to [-1, 1] (the walker's torso assist spans ±5000 N; its motors ±1)."""
    env = ProfileStart(ExportedReward(export), export.profile)
    return gym.wrappers.RescaleAction(gym.wrappers.TimeLimit(env, steps), -1.0, 1.0)


@dataclass(frozen=True)
class Measured:
    """One policy's episode against the profile: its attributes, their distance and the export's return."""

    proxies: dict[str, float]
    distance: dict[str, float]  # |reached - profile| per attribute, in the attribute's units
    in_epsilon: dict[str, float]  # the same in ε (normal precision)
    within: bool  # every attribute within ε
    reward: float  # Σ rθ over the episode: what the policy was trained to raise

    @classmethod
    def of(cls, episode: Episode, profile: Profile, eps: dict[str, float]) -> Measured:
        proxies = episode.proxies()
        distance = {a: abs(proxies[a] - profile.proxies[a]) for a in eps}
        in_eps = {a: distance[a] / eps[a] for a in eps}
        return cls(proxies, distance, in_eps, all(d <= 1.0 for d in in_eps.values()), float(episode.rewards.sum()))


def mean_of(runs: list[Measured]) -> dict[str, Any]:
    """Several episodes' measures (random actions) as one: means, and the share within ε."""
    first = runs[0]
    return {"proxies": {a: float(np.mean([r.proxies[a] for r in runs])) for a in first.proxies},
            "distance": {a: float(np.mean([r.distance[a] for r in runs])) for a in first.distance},
            "in_epsilon": {a: float(np.mean([r.in_epsilon[a] for r in runs])) for a in first.in_epsilon},
            "within": float(np.mean([r.within for r in runs])), "reward": float(np.mean([r.reward for r in runs])),
            "episodes": len(runs)}


def measure(export: Export, policy: Callable[[np.ndarray], np.ndarray], steps: int, eps: dict[str, float],
            scaled: bool = True) -> Measured:
    """``policy``'s episode from the profile's start, ``steps`` long, measured against the profile; ``scaled``:
    it acts in [-1, 1] as the trained one does (else in the env's own units, as the skill does)."""
    p = export.profile
    env = ExportedReward(export)
    env = gym.wrappers.RescaleAction(env, -1.0, 1.0) if scaled else env
    return Measured.of(run_episode(env, policy, p.seed, p.params, max_steps=steps), p, eps)


class Budget(BaseCallback):
    """Stops learning after ``seconds`` of training (None: never), so a benchmark reports what a time budget
    reaches, and measures the policy every ``every`` steps (0: never): the curve of its distance to the profile.
    The measuring is not training time."""

    def __init__(self, seconds: float | None, every: int, measure_now: Callable[[], Measured]) -> None:
        super().__init__()
        self.seconds, self.every, self.measure_now = seconds, every, measure_now
        self.start, self.measuring = time.monotonic(), 0.0
        self.curve: list[dict[str, Any]] = []

    def training_seconds(self) -> float:
        return time.monotonic() - self.start - self.measuring

    def _on_step(self) -> bool:
        if self.every and self.num_timesteps % self.every == 0:
            started = time.monotonic()
            m = self.measure_now()
            self.measuring += time.monotonic() - started
            self.curve.append({"steps": self.num_timesteps, "seconds": round(self.training_seconds(), 1),
                               "in_epsilon": m.in_epsilon, "within": m.within, "reward": m.reward})
        return self.seconds is None or self.training_seconds() < self.seconds


def make_model(algo: str, env: gym.Env, steps: int, seed: int) -> BaseAlgorithm:
    """SB3's defaults, except PPO's update size for runs shorter than one (a multiple of its batch), and the rewards
    the learner sees scaled by a running estimate of the return's spread (``VecNormalize``, rewards only: the policy
    reads raw observations, so ``model.zip`` alone acts): rθ far from the states it was trained on reaches -1e6 per
    state, beside a few per state on the skill's."""
    env = VecNormalize(DummyVecEnv([lambda: env]), norm_obs=False, norm_reward=True)
    if algo == "PPO":
        n_steps = max(PPO_BATCH, min(PPO_ROLLOUT, steps // PPO_BATCH * PPO_BATCH))
        return PPO("MlpPolicy", env, n_steps=n_steps, batch_size=PPO_BATCH, seed=seed, device="cpu", verbose=0)
    return ALGORITHMS[algo]("MlpPolicy", env, seed=seed, device="cpu", verbose=0)


def act_with(model: BaseAlgorithm) -> Callable[[np.ndarray], np.ndarray]:
    return lambda obs: model.predict(obs, deterministic=True)[0]


def train(export_path: Path, algo: str, steps: int, seed: int, out: Path, seconds: float | None = None,
          every: int = 0, data_root: Path | None = None) -> dict[str, Any]:
    """Train on the export's reward for ``steps`` env steps (or ``seconds`` of training), measuring the policy every
    ``every`` steps (0: at the end only); save ``model.zip`` and ``report.json`` in ``out``; the report."""
    export = read_export(export_path)
    p = export.profile
    domain = get_domain(p.domain)
    if type(domain).observed_proxies is Domain.observed_proxies:
        raise ExportError(f"domain {p.domain!r} measures its attributes only through its scripted skill, so a "
                          "learned policy's cannot be measured (Domain.observed_proxies)")
    eps = dict(zip(domain.attribute_names,
                   domain.epsilons(SkillLibrary.load(p.domain, "serve", data_root).proxies, "normal").tolist(),
                   strict=True))
    episode = skill_steps(p)
    model = make_model(algo, training_env(export, episode), steps, seed)
    untrained = measure(export, act_with(model), episode, eps)
    budget = Budget(seconds, every, lambda: measure(export, act_with(model), episode, eps))
    model.learn(total_timesteps=steps, callback=budget)
    wall = budget.training_seconds()
    out.mkdir(parents=True, exist_ok=True)
    model.save(out / "model.zip")
    rng = np.random.default_rng(seed)

    def random_act(obs: np.ndarray) -> np.ndarray:
        return rng.uniform(-1.0, 1.0, model.action_space.shape)

    report = {
        "domain": p.domain, "rollout_id": p.rollout_id, "algorithm": algo, "seed": seed, "profile": p.proxies,
        "epsilon": eps, "episode_steps": episode, "steps": int(model.num_timesteps), "steps_asked": steps,
        "wall_seconds": round(wall, 1), "steps_per_second": round(model.num_timesteps / max(wall, 1e-9), 1),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "trained": vars(measure(export, act_with(model), episode, eps)),
        "untrained": vars(untrained),
        "random": mean_of([measure(export, random_act, episode, eps) for _ in range(RANDOM_EPISODES)]),
        "skill": vars(measure(export, skill_policy(p), episode, eps, scaled=False)),
        "curve": budget.curve,
    }
    save_text(out / "report.json", json.dumps(report, indent=2) + "\n")
    return report


def summary(report: dict[str, Any]) -> str:
    """The report in a few lines: distance to the profile per attribute, in ε, for the policy and the references."""
    attrs = list(report["epsilon"])
    lines = [f"{report['algorithm']} on {report['domain']} {report['rollout_id']}: {report['steps']} steps in "
             f"{report['wall_seconds']:g} s (load {report['load_average'][0]:g})",
             "policy       " + "  ".join(f"{a:>12}" for a in attrs) + "   within ε   Σ rθ"]
    for name in ("trained", "untrained", "random", "skill"):
        r = report[name]
        lines.append(f"{name:<12} " + "  ".join(f"{r['in_epsilon'][a]:>10.2f} ε" for a in attrs)
                     + f"   {r['within']!s:>8}   {r['reward']:.2f}")
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--export", type=Path, help="an export zip (`rba export` or the page's download)")
    p.add_argument("--domain", help="with --rollout: export this library rollout first (a domain with an rba.gym "
                                    "env and observed attributes: walker, lane_change)")
    p.add_argument("--rollout", help="a library rollout id, <split>-<number> (e.g. serve-00042, test-00007)")
    p.add_argument("--rep", default="onehot", help="the shipped models' representation the export's reward uses")
    p.add_argument("--algo", choices=sorted(ALGORITHMS), default="PPO")
    p.add_argument("--steps", type=int, default=20_000, help="env steps to train for")
    p.add_argument("--seconds", type=float, default=None, help="stop earlier after this much training time")
    p.add_argument("--every", type=int, default=0, help="also measure the policy every this many steps (0: never)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path("sb3_policy_run"), help="folder for model.zip and report.json")
    args = p.parse_args(argv)
    if (args.export is None) == (args.domain is None and args.rollout is None) or (
            args.export is None and (args.domain is None or args.rollout is None)):
        p.error("give --export ZIP, or --domain and --rollout (a library rollout to export first)")
    if args.domain is not None:
        envs = [d for d in domain_names() if has_simulator(d)]
        if args.domain not in envs:
            p.error(f"unknown domain {args.domain!r} or one without an rba.gym env; valid: {', '.join(envs)}")
    if args.steps < 1 or args.every < 0:
        p.error(f"--steps must be a positive number of env steps and --every one or 0, got {args.steps} and "
                f"{args.every}")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    torch.set_num_threads(1)  # small networks: threads cost more than they give, and the machine is shared
    try:
        if args.export is None:
            args.out.mkdir(parents=True, exist_ok=True)
            args.export = export_library_rollout(args.domain, args.rollout, args.out / "export.zip", args.rep)
        report = train(args.export, args.algo, args.steps, args.seed, args.out, args.seconds, args.every)
    except ExportError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(summary(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
