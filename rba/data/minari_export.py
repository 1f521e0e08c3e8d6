"""Clips as a Minari dataset (``rba export --format minari``): each clip re-simulated through its ``rba.gym`` env.

A clip's stored ``states`` are features at the domain's recording rate, not the environment's stream of
observations and actions, so every clip is run again in ``rba/<Domain>-v0`` with the scripted skill
(``rba.gym.skill_policy``) from its params and seed, and the dataset records every env step:

* ``observations`` float64[T+1, state_dim] and ``actions`` float64[T, A] (clipped into the action box, as
  the env applies them); ``infos["recorded"]`` bool[T+1] marks the observations the clip keeps as its
  states, so ``observations[infos["recorded"]]`` is the clip's ``states`` (float64 before they were stored
  as float32; within ``STATES_ATOL``: the walker's skill policy rounds a few near-zero features apart).
* ``terminations`` are all False (the env has no terminal state); ``truncations`` are True at the last step
  only: the skill finished there (or the env's time limit cut it).
* ``rewards``: 0 (the env has no task), or with a profile (an export zip holding rθ) what
  ``rba.gym.ExportedReward`` pays: rθ(s | condition) of each recorded observation, the first paid with the
  first step, so an episode's return is Σ_t rθ(s_t | v*) over the clip's states.
* each episode's ``seed`` and ``options`` (``{"params": ...}``) re-run it: ``env.reset(seed=..., options=...)``,
  and its ``rollout_id`` names the clip (``dataset.storage.get_episode_metadata``).
* the dataset's metadata key ``"rba"`` says where the clips came from (``DatasetSource.about``: a library
  split, a session's rounds, admin labels as pairs of episode indices) and what the rewards are.

A clip whose re-simulated states (or proxies) differ from the stored ones stops the export: a dataset never
silently differs from its library. The dataset is built in a hidden folder beside its place and renamed into
``<out>/rba/<name>-v0``, so ``minari.load_dataset("rba/<name>-v0")`` with ``MINARI_DATASETS_PATH=<out>`` reads it.
Nothing here talks to a dataset hub.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import minari
import numpy as np
from minari.data_collector.episode_buffer import EpisodeBuffer
from minari.dataset.minari_storage import MinariStorage

from rba.core.fileio import save_text
from rba.data.export_zip import ExportedRewardModel, read_export
from rba.data.library import SkillLibrary
from rba.domains import Domain, Rollout, domain_names, get_domain
from rba.gym import env_id, has_simulator, register_envs, run_episode

NAMESPACE = "rba"  # the datasets' Minari namespace: ids are rba/<name>-v0
VERSION = 0
FORMAT = 1  # of the "rba" metadata below
NAME = re.compile(r"^[a-z0-9][a-z0-9_-]{0,99}$")  # a dataset name: registry names and database ids only
CHUNK = 32  # episodes held in memory before they are written
# a re-simulated clip against the stored one, as tests/test_gym.py holds the env to the rollout: the walker's
# observation-only skill policy rounds a few near-zero features apart from the rollout's own controller (1e-13)
STATES_RTOL = STATES_ATOL = 1e-6
PROXY_RTOL, PROXY_ATOL = 1e-9, 1e-12
INFOS = "recorded: bool[T+1], True where the observation is one of the clip's stored states"


class MinariExportError(ValueError):
    """An export that cannot be made: a one-line reason naming what is valid (``rba`` exits 2)."""


@dataclass(frozen=True)
class Clip:
    """One episode to write: a clip by id, what re-simulates it, and what it must re-simulate to."""

    rollout_id: str
    params: dict[str, float]
    seed: int
    states: np.ndarray  # float32[T, state_dim]: the stored states
    proxies: dict[str, float]


@dataclass(frozen=True)
class DatasetSource:
    """What a dataset is made of: clips of one domain and what the metadata tells about them (``about``: the
    source's kind and its own fields; a new kind of source, e.g. a study's clips, is one more of these)."""

    domain: str
    name: str  # the dataset's name: rba/<name>-v0
    description: str
    clips: list[Clip]
    about: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Written:
    """A dataset written: its id, folder, episodes and steps."""

    dataset_id: str
    path: Path
    episodes: int
    steps: int


def dataset_id(name: str) -> str:
    return f"{NAMESPACE}/{name}-v{VERSION}"


def exportable_domains() -> list[str]:
    """Domains whose clips can be re-simulated through a step interface (the raw and image views cannot)."""
    return [name for name in domain_names() if has_simulator(name)]


def check_domain(domain: str) -> Domain:
    if domain not in domain_names():
        raise MinariExportError(f"unknown domain {domain!r}; valid: {', '.join(exportable_domains())}")
    if not has_simulator(domain):
        raise MinariExportError(f"domain {domain!r} has no step interface (its states are not what the skill's "
                                f"policy reads), so it has no Minari dataset; valid: {', '.join(exportable_domains())}")
    return get_domain(domain)


def rollout_clip(rollout_id: str, rollout: Rollout) -> Clip:
    return Clip(rollout_id, dict(rollout.params), int(rollout.seed), rollout.states, dict(rollout.proxies))


def library_clip(library: SkillLibrary, i: int) -> Clip:
    params = dict(zip(library.param_names, (float(p) for p in library.params[i]), strict=True))
    return Clip(library.ids[i], params, int(library.seeds[i]), library.trajectory(i), library.proxies_of(i))


def library_source(domain: str, split: str, data_root: Path | None = None,
                   indices: list[int] | None = None) -> DatasetSource:
    """A library split's clips (all, or those at ``indices``): dataset ``rba/<domain>-<split>-v0``."""
    check_domain(domain)
    library = SkillLibrary.load(domain, split, data_root)
    picked = range(len(library)) if indices is None else indices
    return DatasetSource(domain, f"{domain}-{split}", f"{domain}'s {split} skill library, re-simulated in "
                         f"{env_id(domain)} with the scripted skill", [library_clip(library, i) for i in picked],
                         {"source": "library", "split": split, "library_version": library.version})


class RewardSource:
    """The rewards of every step: 0, or a profile's rθ as ``rba.gym.ExportedReward`` pays it."""

    def __init__(self, domain: str, profile: Path | None) -> None:
        self.model: ExportedRewardModel | None = None
        self.about: dict[str, Any] = {"kind": "zero", "note": "the env has no task reward"}
        if profile is None:
            return
        export = read_export(Path(profile))
        p = export.profile
        if export.reward is None:
            raise MinariExportError(f"the profile has no reward model ({p.reward_note}); give an export whose "
                                    "profile.json names a reward, or no --profile for zero rewards")
        if p.domain != domain:
            raise MinariExportError(f"the profile's reward is for {p.domain!r}, these clips are {domain!r}'s; give "
                                    f"an export of a {domain} session")
        self.model = export.reward
        digest = hashlib.sha256(Path(profile).read_bytes()).hexdigest()
        self.about = {"kind": export.reward.kind, "note": "r_theta(s | condition) of each recorded observation, "
                      "as rba.gym.ExportedReward pays it", "profile_sha256": digest, "profile_rollout_id":
                      p.rollout_id, "method": p.method, "rep": p.rep, "condition": export.reward.condition}

    def rewards(self, observations: np.ndarray, recorded: np.ndarray) -> np.ndarray:
        """float64[T] for observations [T+1]: step t pays the recorded observation t+1 (step 0 also the first's)."""
        out = np.zeros(len(observations) - 1)
        if self.model is None:
            return out
        paid = np.zeros(len(observations))
        paid[recorded] = self.model.rewards(observations[recorded])
        out += paid[1:]
        out[0] += paid[0]
        return out


def record(env: gym.Env, domain: Domain, clip: Clip) -> dict[str, np.ndarray]:
    """One clip run again in its env: observations, actions, recorded; ``MinariExportError`` if it differs."""
    policy = domain.skill_policy(clip.params, clip.seed)
    episode = run_episode(env, policy, clip.seed, clip.params)
    observations = episode.observations.astype(np.float64)
    _check(clip, observations[episode.recorded].astype(np.float32), policy.measured(), domain.name)
    if not len(episode.actions):
        raise MinariExportError(f"clip {clip.rollout_id} ended before its first step: an episode needs one")
    actions = np.clip(episode.actions, env.action_space.low, env.action_space.high)  # as the env applies them
    return {"observations": observations, "actions": actions, "recorded": episode.recorded}


def _check(clip: Clip, states: np.ndarray, measured: dict[str, float], domain: str) -> None:
    """The re-simulated clip is the stored one: its states and proxies within the tolerances above."""
    problem = None
    if states.shape != clip.states.shape:
        problem = f"{len(states)} states, stored {len(clip.states)}"
    elif not np.allclose(states, clip.states, rtol=STATES_RTOL, atol=STATES_ATOL):
        problem = f"states differ by up to {float(np.max(np.abs(states - clip.states))):.3g}"
    else:
        off = [a for a, v in clip.proxies.items()
               if not np.isclose(measured[a], v, rtol=PROXY_RTOL, atol=PROXY_ATOL)]
        problem = f"proxies {', '.join(off)} differ" if off else None
    if problem:
        raise MinariExportError(f"{domain} clip {clip.rollout_id} re-simulated differently from the stored one "
                                f"({problem}): the simulator is not the one the clips were made with; nothing "
                                "was written")


def _buffers(source: DatasetSource, rewards: RewardSource) -> Iterator[tuple[EpisodeBuffer, str]]:
    domain, env = get_domain(source.domain), gym.make(env_id(source.domain))
    try:
        for i, clip in enumerate(source.clips):
            run = record(env, domain, clip)
            n = len(run["actions"])
            truncations = np.zeros(n, dtype=bool)
            truncations[-1] = True
            yield EpisodeBuffer(id=i, seed=clip.seed, options={"params": clip.params},
                                observations=run["observations"], actions=run["actions"],
                                rewards=rewards.rewards(run["observations"], run["recorded"]),
                                terminations=np.zeros(n, dtype=bool), truncations=truncations,
                                infos={"recorded": run["recorded"]}), clip.rollout_id
    finally:
        env.close()


def _metadata(source: DatasetSource, rewards: RewardSource) -> dict[str, Any]:
    return {"dataset_id": dataset_id(source.name), "minari_version": minari.__version__,
            "description": source.description,
            "algorithm_name": f"the scripted skill of {source.domain} with each clip's params and seed "
                              "(rba.gym.skill_policy)",
            "rba": {"format": FORMAT, "domain": source.domain, **source.about, "rewards": rewards.about,
                    "infos": INFOS, "episode_metadata": "rollout_id, seed and options ({'params'}) of each clip"}}


def _namespace(out: Path) -> None:
    """The namespace folder's metadata file, as ``minari.namespace.create_namespace`` writes it."""
    path = out / NAMESPACE / "namespace_metadata.json"
    if not path.exists():
        save_text(path, json.dumps({"description": "RBA Studio clips, re-simulated (rba export --format minari)"}))


def write_dataset(out: Path, source: DatasetSource, profile: Path | None = None,
                  on_episode: Callable[[int], None] | None = None) -> Written:
    """Write ``source`` as ``<out>/rba/<name>-v0`` (built beside it, then renamed); rewards from ``profile``."""
    check_domain(source.domain)
    register_envs()  # domains registered after rba.gym was imported
    if not NAME.match(source.name):
        raise MinariExportError(f"dataset name {source.name!r} is not lower-case letters, digits, '_' and '-'")
    if not source.clips:
        raise MinariExportError(f"no clips to export for {dataset_id(source.name)}")
    rewards = RewardSource(source.domain, profile)
    out = Path(out)
    final = out / NAMESPACE / f"{source.name}-v{VERSION}"
    if final.exists():
        raise MinariExportError(f"{final} exists already; remove it or give another --out")
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=final.parent, prefix=f".{final.name}.", suffix=".tmp"))
    try:
        spec = gym.spec(env_id(source.domain))
        env = gym.make(spec)
        storage = MinariStorage.new(tmp / "data", observation_space=env.observation_space,
                                    action_space=env.action_space, env_spec=spec)
        env.close()
        chunk: list[tuple[EpisodeBuffer, str]] = []
        for done, item in enumerate(_buffers(source, rewards), 1):
            chunk.append(item)
            if len(chunk) == CHUNK or done == len(source.clips):
                storage.update_episodes(buffer for buffer, _ in chunk)
                storage.update_episode_metadata([{"rollout_id": rid} for _, rid in chunk],
                                                [buffer.id for buffer, _ in chunk])
                chunk = []
            if on_episode:
                on_episode(done)
        storage.update_metadata(_metadata(source, rewards))
        episodes, steps = storage.total_episodes, storage.total_steps
        os.chmod(tmp, 0o755)  # mkdtemp makes 0700; a dataset is meant to be read by others
        os.rename(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _namespace(out)
    return Written(dataset_id(source.name), final, episodes, steps)
