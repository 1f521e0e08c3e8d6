"""`rba train`: fit RBA-Global (ζσ, rθ) or RBA-Local (rθ) models, measure them on `val`, save with cards.

Also the learned state encoder a domain's states come from (lane_change_image's frame VAE),
which `rba build` trains before it simulates, when it is missing.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Collection, Iterable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import torch

from rba.core.artifacts import ModelNotFoundError, load_model, save_model, weights_sha
from rba.core.fileio import save_json
from rba.core.store import model_files
from rba.data.labels import (
    AttributeLabels,
    GlobalLabelConfig,
    LabelSet,
    LocalLabelConfig,
    LocalPairs,
    NewAttribute,
    annotator_labels,
    local_pairs,
    merge_pairs,
    pair_counts,
    proxy_labels,
)
from rba.data.library import SkillLibrary
from rba.domains import Domain, get_domain
from rba.learn.common import CurveOf, Progress, Ragged
from rba.learn.curves import Measure, curve_of
from rba.learn.embed import attribute_embeddings, check_rep
from rba.learn.global_reward import GlobalRewardConfig, LibraryScorer, train_global_reward
from rba.learn.local_reward import (
    LocalLibraryScorer,
    LocalReward,
    LocalRewardConfig,
    edit_metrics,
    pair_metrics,
    train_local_reward,
)
from rba.learn.ranker import AttributeRanker, RankerConfig, ranking_metrics, train_ranker
from rba.learn.vae import SIZE, STACK, VAEConfig, train_vae

log = logging.getLogger(__name__)

StageProgress = Callable[[str, int, int, float], None]  # (stage, step, total steps, loss)
T = TypeVar("T")


@dataclass(frozen=True)
class Typical:
    """How long a preset's phases take, as ``benchmarks/training_presets.py`` measured them on walker with 2 CPU
    cores: the estimate of a job's time left takes them for the phases it has not measured yet
    (``server.ops.training_jobs``), and the presets' descriptions their durations."""

    setup: float  # seconds before the first step: loading the libraries, making the labels
    step: dict[str, float]  # model kind -> seconds per gradient step
    measure: dict[str, float]  # model kind -> seconds from its last step on: held-out numbers on val, saving

    def seconds(self, steps: dict[str, int]) -> float:
        """A whole run fitting each kind of ``steps`` (kind -> gradient steps)."""
        return self.setup + sum(n * self.step[kind] + self.measure[kind] for kind, n in steps.items())


@dataclass(frozen=True)
class Preset:
    """One named training size: every trainer's config (the seed is set when the preset is used), what it is for
    and how long its phases typically take."""

    description: str  # one line: what it trains and how big (the admin page and GET /api/admin/presets show it)
    typical: Typical
    ranker: RankerConfig = field(default_factory=RankerConfig)
    global_reward: GlobalRewardConfig = field(default_factory=GlobalRewardConfig)
    local_reward: LocalRewardConfig = field(default_factory=LocalRewardConfig)
    domain_ranker_steps: bool = False  # ζσ takes the domain's steps (``Domain.ranker_steps``) if it sets them
    global_only: bool = False  # it only changes RBA-Global's ζσ (RBA-Local does not offer it)


_SHORT_LOCAL = LocalRewardConfig(steps=150, hidden=64, lstm_hidden=32)
# typical: benchmarks/results/training_presets.md (walker, CPU seconds; docs/decisions/0024-training-time-estimate.md)
_PRESETS = {
    "default": Preset(
        "the shipped models' size: ζσ 800 steps (or the domain's own) at width 256, rθ 1,000 steps at width 256 "
        "(RBA-Local: 1,500 steps at width 128)",
        Typical(3.1, dict(ranker=0.364, global_reward=0.729, local_reward=0.232),
                dict(ranker=1.6, global_reward=61.2, local_reward=39.5)), domain_ranker_steps=True),
    "pairwise": Preset(
        "as default, but ζσ learns from a simulated person's answers: 1,000 pairs of 200 clips, 10 % flipped, "
        "10 % \"can't tell\"",
        Typical(8.3, dict(ranker=0.379, global_reward=0.524), dict(ranker=1.6, global_reward=55.2)),
        RankerConfig(labels=GlobalLabelConfig(mode="pairwise")), domain_ranker_steps=True, global_only=True),
    "quick": Preset(
        "the full ζσ, a shorter rθ: 300 steps at width 128 (RBA-Local: 150 steps at width 64)",
        Typical(2.2, dict(ranker=0.274, global_reward=0.372, local_reward=0.081),
                dict(ranker=1.4, global_reward=19.4, local_reward=30.7)),
        global_reward=GlobalRewardConfig(steps=300, hidden=128), local_reward=_SHORT_LOCAL),
    "tiny": Preset(
        "a smoke run that checks the pipeline, not models to serve: ζσ 200 steps, rθ 120 steps, both at width 64 "
        "(RBA-Local: 150 steps at width 64)",
        Typical(18.3, dict(ranker=0.127, global_reward=0.394, local_reward=0.088),
                dict(ranker=0.7, global_reward=16.8, local_reward=24.5)),
        RankerConfig(steps=200, hidden=64), GlobalRewardConfig(steps=120, hidden=64), _SHORT_LOCAL),
}
PRESETS = tuple(_PRESETS)
LOCAL_PRESETS = tuple(name for name, p in _PRESETS.items() if not p.global_only)


def get_preset(name: str, valid: tuple[str, ...] = PRESETS) -> Preset:
    if name not in valid:
        raise ValueError(f"unknown preset {name!r}; valid: {', '.join(valid)}")
    return _PRESETS[name]


def about_preset(name: str, kinds: Iterable[str], domain: str | None = None) -> tuple[str, float]:
    """``name``'s description and its typical seconds when it fits ``kinds`` for ``domain`` (on 2 CPU cores)."""
    p = get_preset(name)
    return p.description, round(p.typical.seconds(plan_steps(name, kinds, domain)), 1)


# What was chosen by measuring, per model kind. Every such measurement used ``val``: it holds the rollouts of the
# first release's test split (split code 2), where these were chosen; ``test`` was then rebuilt from split code 3
# and is read only by `rba eval` and benchmarks/paper_tables.py. Each card says so (``tuning``).
TUNED = {
    "ranker": ("Domain.ranker_steps",),
    "global_reward": ("GlobalRewardConfig.focus", "rba.interact.global_agent.SHORTLIST", "Domain.serve_size",
                      "rba.interact.base.REJECT_MEMORY"),
    "local_reward": ("Domain.serve_size", "rba.interact.base.REJECT_MEMORY"),
}


def tuning_record(kind: str) -> dict:
    """A card's ``tuning``: which settings were chosen by measurement, and on which split (always val)."""
    return {"split": "val", "settings": list(TUNED.get(kind, ())),
            "note": "val = the first release's test rollouts (split code 2), where these were chosen; "
                    "test (split code 3) is only for `rba eval` and the tables"}


@dataclass
class GlobalTrainConfig:
    ranker: RankerConfig = field(default_factory=RankerConfig)
    reward: GlobalRewardConfig = field(default_factory=GlobalRewardConfig)

    @classmethod
    def preset(cls, name: str, seed: int = 0, domain: str | None = None) -> GlobalTrainConfig:
        """A preset of ``PRESETS``; ``default`` takes ``domain``'s ζσ steps if it sets them."""
        p = get_preset(name)
        steps = get_domain(domain).ranker_steps if domain and p.domain_ranker_steps else None
        return cls(replace(p.ranker, seed=seed, **({"steps": steps} if steps else {})),
                   replace(p.global_reward, seed=seed))


@dataclass
class LocalTrainConfig:
    """RBA-Local training: which pairs get labelled, and how rθ is fitted."""

    labels: LocalLabelConfig = field(default_factory=LocalLabelConfig)
    reward: LocalRewardConfig = field(default_factory=LocalRewardConfig)

    @classmethod
    def preset(cls, name: str, seed: int = 0) -> LocalTrainConfig:
        """A preset of ``PRESETS`` (``quick`` and ``tiny`` share a short rθ)."""
        return cls(LocalLabelConfig(seed=seed), replace(get_preset(name, LOCAL_PRESETS).local_reward, seed=seed))


def plan_steps(preset: str, kinds: Iterable[str], domain: str | None = None) -> dict[str, int]:
    """The gradient steps ``preset`` fits each model kind with (in ``kinds``' order): the stages a job will report."""
    p = get_preset(preset)
    ranker_steps = GlobalTrainConfig.preset(preset, domain=domain).ranker.steps
    steps = {"ranker": ranker_steps, "global_reward": p.global_reward.steps, "local_reward": p.local_reward.steps}
    return {kind: steps[kind] for kind in kinds}


def argmax_match_rate(scorer: LibraryScorer, serve: SkillLibrary, target_zeta: np.ndarray,
                      target_proxies: np.ndarray, eps: np.ndarray) -> float:
    """Fraction of targets for which argmax_serve Σ rθ(·|ζ(target)) is within ε on every attribute."""
    hits = [np.all(np.abs(serve.proxies[scorer.argmax(z)] - p) <= eps)
            for z, p in zip(target_zeta, target_proxies, strict=True)]
    return float(np.mean(hits))


def stage_name(kind: str, rep: str) -> str:
    """The stage a trainer reports while it fits the ``kind`` model of ``rep`` (the server weighs stages by it)."""
    return f"{kind}[{rep}]"


class StageClock:
    """Each stage's first, previous and latest progress report (its step and the seconds since the clock started),
    in the order the stages ran: the rate a stage's steps are going at, which the estimate of a job's time left
    needs (``server.ops.training_jobs``). The training process keeps one per job and stores ``mark``'s result."""

    def __init__(self) -> None:
        self.start = time.monotonic()
        self.stages: list[dict] = []

    def mark(self, stage: str, step: int, total: int) -> list[dict]:
        """Record a report; returns every stage's record so far (JSON)."""
        at = round(time.monotonic() - self.start, 3)
        if not self.stages or self.stages[-1]["stage"] != stage:
            self.stages.append({"stage": stage, "total": total, "first_step": step, "first_at": at, "step": step,
                                "at": at})
        last = self.stages[-1]
        last.update(total=total, before_step=last["step"], before_at=last["at"], step=step, at=at)
        return [dict(s) for s in self.stages]


def _progress(name: str, on_progress: StageProgress | None = None) -> Progress:
    def report(step: int, total: int, loss: float) -> None:
        log.info("%s step %d/%d loss %.4f", name, step, total, loss)
        if on_progress is not None:
            on_progress(name, step, total, loss)
    return report


def _timed(fn: Callable[..., T], *args, **kwargs) -> tuple[T, float]:
    """``fn(*args, **kwargs)`` and the seconds it took, rounded for a model card."""
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, round(time.perf_counter() - t0, 1)


@dataclass
class _Inputs:
    """What every trainer starts from: the domain, its three splits, e_α for each attribute."""

    name: str
    domain: Domain
    train: SkillLibrary
    serve: SkillLibrary
    val: SkillLibrary  # held out: the cards' metrics (never test: that is only for `rba eval`)
    embed: np.ndarray  # float32[k, E]
    attrs: list[dict]  # model card entries {name, description, unit}: the domain's, then declared ones

    @classmethod
    def load(cls, domain_name: str, rep: str, data_root: Path | None,
             extra_attributes: Iterable[NewAttribute] = ()) -> _Inputs:
        check_rep(rep)
        domain = get_domain(domain_name)
        libs = (SkillLibrary.load(domain_name, s, data_root) for s in ("train", "serve", "val"))
        attrs = [{"name": a.name, "description": a.description, "unit": a.unit} for a in domain.attributes]
        attrs += [{"name": a.name, "description": a.description, "unit": ""} for a in extra_attributes]
        return cls(domain_name, domain, *libs, attribute_embeddings([a["description"] for a in attrs], rep), attrs)

    @property
    def names(self) -> list[str]:
        return [a["name"] for a in self.attrs]

    def card(self, rep: str) -> dict:
        """The card entries every model trained on these inputs shares."""
        return {"domain": self.name, "representation": rep, "attributes": self.attrs,
                "data": {"train": self.train.version, "serve": self.serve.version, "val": self.val.version}}


@dataclass
class LabelSource:
    """Labels from an agent designer, with the trajectories uploaded beside them (name -> float[T, D])."""

    labels: LabelSet
    trajectories: dict[str, np.ndarray] = field(default_factory=dict)
    name: str = "labels"  # what errors call it, e.g. "dataset 3f2a..."

    def check(self, library_ids: Collection[str], state_dim: int) -> None:
        """ValueError naming this source unless every trajectory is [T, state_dim] and every clip its labels
        refer to is one of its trajectories or a library rollout (a stored dataset may have changed since
        it was checked)."""
        for ref, traj in self.trajectories.items():
            shape = np.shape(traj)
            if len(shape) != 2 or shape[0] < 1 or shape[1] != state_dim:
                raise ValueError(f"{self.name}: trajectory {ref!r} has shape {list(shape)}, expected [T, {state_dim}]")
        missing = sorted(r for r in self.labels.references() if r not in self.trajectories and r not in library_ids)
        if missing:
            shown = ", ".join(repr(m) for m in missing[:5]) + (" ..." if len(missing) > 5 else "")
            raise ValueError(f"{self.name}: its labels refer to {len(missing)} clip(s) that are neither its "
                             f"trajectories nor train/serve rollouts: {shown}")


class _Pool:
    """Every trajectory a ranker can learn from: train, serve, then uploaded ones; refs -> rows."""

    def __init__(self, train: SkillLibrary, serve: SkillLibrary, sources: list[LabelSource]) -> None:
        self.library_index = {rid: i for i, rid in enumerate(train.ids)}
        self.library_index |= {rid: len(train) + i for i, rid in enumerate(serve.ids)}
        self.library_rows = len(train) + len(serve)
        arrays = [train.states, serve.states]
        offsets = [train.state_offsets[:-1], serve.state_offsets[:-1] + len(train.states)]
        self.uploaded: list[dict[str, int]] = []
        n, rows = self.library_rows, len(train.states) + len(serve.states)
        for src in sources:
            src.check(self.library_index, train.states.shape[1])
            names = {}
            for name, traj in src.trajectories.items():
                names[name] = n
                arrays.append(np.asarray(traj, dtype=np.float32))
                offsets.append(np.array([rows]))
                n, rows = n + 1, rows + len(traj)
            self.uploaded.append(names)
        self.data = Ragged.from_numpy(np.concatenate(arrays), np.concatenate([*offsets, [rows]]))

    def index(self, source: int, ref: str) -> int:
        """The row of a clip the source refers to (``LabelSource.check`` made sure there is one)."""
        names = self.uploaded[source]
        return names[ref] if ref in names else self.library_index[ref]

    def pairs(self, sources: list[LabelSource], attribute: str) -> list[list[tuple[int, int]]]:
        return [[(self.index(i, hi), self.index(i, lo)) for hi, lo in src.labels.pairs(attribute)]
                for i, src in enumerate(sources)]

    def local_pairs(self, sources: list[LabelSource], attribute_names: list[str]) -> LocalPairs:
        """The sources' local changes as RBA-Local pairs over the pool's rows."""
        return LocalPairs.from_rows((self.index(i, c.anchor), self.index(i, c.changed),
                                     attribute_names.index(c.attribute), 1 if c.direction == "more" else -1)
                                    for i, src in enumerate(sources) for c in src.labels.local_changes)


def _declared(sources: list[LabelSource], labelled: Callable[[LabelSet, str], bool]) -> dict[str, NewAttribute]:
    """New attributes the sources declare and label in the way this trainer learns from."""
    declared = {a.name: a for src in sources for a in src.labels.new_attributes}
    return {n: a for n, a in declared.items() if any(labelled(src.labels, n) for src in sources)}


def _split_pairs(labels: AttributeLabels, seed: int, held_out: float = 0.2) -> tuple[AttributeLabels, np.ndarray]:
    """(train labels, held-out (more, less) pairs): a seeded share of the pairs is kept for measuring."""
    pairs = labels.pairs()
    rng = np.random.default_rng(seed)
    test = rng.random(len(pairs)) < held_out
    if test.sum() < 5 or (~test).sum() == 0:
        return labels, pairs[:0]
    return AttributeLabels.from_pairs([tuple(p) for p in pairs[~test]]), pairs[test]


def _builtin_labels(train: SkillLibrary, names: tuple[str, ...], cfg: RankerConfig
                    ) -> tuple[list[AttributeLabels], dict]:
    """The domain's attributes' labels made from proxies (``cfg.labels.mode``) and the card's ``training.labels``."""
    card: dict = {**asdict(cfg.labels), "max_labelled": cfg.max_labelled}
    if cfg.labels.mode == "ordering":
        labels = proxy_labels(train, cfg.max_labelled, cfg.seed)
        return labels, {**card, "made_by": "every pair of the labelled train clips, ordered by the true proxy"}
    labels, stats = annotator_labels(train, cfg.max_labelled, cfg.labels, cfg.seed)
    per_attribute = dict(zip(names, stats.pop("per_attribute"), strict=True))
    return labels, {**card, **stats, "per_attribute": per_attribute,
                    "made_by": "a simulated annotator's answers to pairs of train clips: P(i > j) = "
                               "sigmoid((p_i - p_j) / T), T set per attribute for the noise share; "
                               "can't-tell answers (the closest pairs) dropped"}


def _global_labels(inputs: _Inputs, pool: _Pool, sources: list[LabelSource], cfg: RankerConfig
                   ) -> tuple[list[AttributeLabels], dict[str, np.ndarray], dict]:
    """Each attribute's ζσ labels, the held-out pairs of the attributes the sources declare new, and how
    the domain's attributes were labelled (for the card).

    The domain's attributes: their proxy labels, overridden by what the sources say of the same pairs.
    New attributes: the sources' labels alone, minus a held-out share.
    """
    builtin, how = _builtin_labels(inputs.train, inputs.domain.attribute_names, cfg)
    labels, held_out = [], {}
    for a, name in enumerate(inputs.names):
        given = pool.pairs(sources, name)
        if a < len(builtin):
            labels.append(merge_pairs([builtin[a].pairs(), *given]))
        else:
            fit, held_out[name] = _split_pairs(merge_pairs(given), cfg.seed)
            labels.append(fit)
    return labels, held_out, how


def _ranker_metrics(ranker: AttributeRanker, inputs: _Inputs, pool: _Pool, held_out: dict[str, np.ndarray]
                    ) -> tuple[dict, np.ndarray, np.ndarray]:
    """(metrics, ζσ of val, ζσ of the pool): ranking quality on val by proxy, and on held-out pairs."""
    metrics, val_zeta = _val_ranking(ranker, inputs)
    pool_zeta = ranker.score(pool.data)
    for name, accuracy in _held_out_accuracy(pool_zeta, inputs, held_out).items():
        metrics[name] = {"held_out_pair_accuracy": accuracy, "held_out_pairs": len(held_out[name])}
    return metrics, val_zeta, pool_zeta


def _val_ranking(ranker: AttributeRanker, inputs: _Inputs) -> tuple[dict, np.ndarray]:
    """(ranking quality on val by proxy per attribute, ζσ of val)."""
    val_zeta = ranker.score_library(inputs.val)
    k = len(inputs.domain.attributes)
    return ranking_metrics(val_zeta[:, :k], inputs.val.proxies, inputs.domain.attribute_names), val_zeta


def _held_out_accuracy(pool_zeta: np.ndarray, inputs: _Inputs, held_out: dict[str, np.ndarray]
                       ) -> dict[str, float | None]:
    """Per new attribute, the share of its held-out pairs ``pool_zeta`` orders right (None without pairs)."""
    return {name: _pair_accuracy(pool_zeta[:, inputs.names.index(name)], pairs) for name, pairs in held_out.items()}


def _pair_accuracy(zeta: np.ndarray, pairs: np.ndarray) -> float | None:
    """The share of (more, less) ``pairs`` that ``zeta`` orders so; None without pairs."""
    return float(np.mean(zeta[pairs[:, 0]] > zeta[pairs[:, 1]])) if len(pairs) else None


HELD_OUT_SAMPLE = 32  # val targets (rθ) or val pairs (RBA-Local) a training curve's held-out point measures


def _curve(models_root: Path | None, inputs: _Inputs, kind: str, rep: str, measure: Measure, cfg: Any) -> CurveOf:
    """Where the training of ``<kind>-<rep>`` writes its curve: beside the model (``ModelFiles.curve``)."""
    return curve_of(model_files(models_root).curve(inputs.name, kind, rep), f"{inputs.name}/{kind}-{rep}", measure,
                    asdict(cfg))


def _ranker_measure(inputs: _Inputs, pool: _Pool, held_out: dict[str, np.ndarray]) -> Measure:
    """ζσ's curve's held-out numbers: the card's pairwise accuracy on val by proxy per attribute, and on the
    held-out pairs of new attributes (the whole pool is scored only when there are some)."""
    scored = any(len(p) for p in held_out.values())

    def measure(ranker: AttributeRanker) -> dict[str, float]:
        val, _ = _val_ranking(ranker, inputs)
        out = {f"pairwise_accuracy/{name}": m["pairwise_accuracy"] for name, m in val.items()}
        if scored:
            out |= {f"held_out_pair_accuracy/{name}": accuracy for name, accuracy
                    in _held_out_accuracy(ranker.score(pool.data), inputs, held_out).items() if accuracy is not None}
        return out
    return measure


def _global_measure(inputs: _Inputs, val_zeta: np.ndarray) -> Measure:
    """rθ's curve's held-out number: the card's argmax within ε, on the first ``HELD_OUT_SAMPLE`` val targets."""
    n = min(HELD_OUT_SAMPLE, len(inputs.val))
    serve = Ragged.from_numpy(inputs.serve.states, inputs.serve.state_offsets)
    eps = inputs.domain.epsilons(inputs.serve.proxies)
    return lambda reward: {"argmax_within_epsilon": argmax_match_rate(
        LibraryScorer(reward, serve), inputs.serve, val_zeta[:n], inputs.val.proxies[:n], eps)}


def _local_measure(inputs: _Inputs, cfg: LocalTrainConfig) -> Measure:
    """RBA-Local rθ's curve's held-out numbers: the card's ranking of val pairs, on ``HELD_OUT_SAMPLE`` of them."""
    val = inputs.val
    pairs = local_pairs(val.proxies, inputs.domain.epsilons(inputs.serve.proxies), inputs.domain.attribute_names,
                        cfg.labels, max_pairs=min(HELD_OUT_SAMPLE, len(val)))
    data = Ragged.from_numpy(val.states, val.state_offsets)

    def measure(model: LocalReward) -> dict[str, float]:
        ranking = pair_metrics(LocalLibraryScorer(model, data), pairs)
        return {k: ranking[k] for k in ("target_vs_negative", "target_vs_anchor")}
    return measure


def train_global(domain_name: str, rep: str, cfg: GlobalTrainConfig | None = None,
                 data_root: Path | None = None, models_root: Path | None = None,
                 sources: list[LabelSource] | None = None, on_progress: StageProgress | None = None) -> dict:
    """Train, evaluate and save ``ranker-<rep>`` and ``global_reward-<rep>``; return the metrics.

    The domain's attributes are labelled by proxy (``max_labelled`` train clips), plus what
    ``sources`` say about them; attributes that ``sources`` declare new are labelled by
    ``sources`` alone, and a fifth of their pairs is held out to measure ζσ on.
    """
    cfg = cfg or GlobalTrainConfig.preset("default", domain=domain_name)
    sources = sources or []
    declared = _declared(sources, lambda labels, name: bool(labels.pairs(name)))
    inputs = _Inputs.load(domain_name, rep, data_root, declared.values())
    pool = _Pool(inputs.train, inputs.serve, sources)
    labels, held_out, how = _global_labels(inputs, pool, sources, cfg.ranker)
    (ranker, rstats), ranker_seconds = _timed(
        train_ranker, pool.data, labels, inputs.embed, cfg.ranker,
        progress=_progress(stage_name("ranker", rep), on_progress),
        curve=_curve(models_root, inputs, "ranker", rep, _ranker_measure(inputs, pool, held_out), cfg.ranker))
    rmetrics, val_zeta, pool_zeta = _ranker_metrics(ranker, inputs, pool, held_out)
    log.info("ranker[%s] held out: %s", rep, rmetrics)
    common = inputs.card(rep)
    if sources:
        common["labels"] = {"sources": len(sources), "uploaded_trajectories": len(pool.data) - pool.library_rows,
                            "new_attributes": sorted(declared)}
    arch = {"state_dim": inputs.domain.state_dim, "num_attributes": len(inputs.attrs)}
    save_model(ranker, {**common, "kind": "ranker", "weights_sha": weights_sha(ranker),
                        "architecture": {**arch, "embed_dim": int(inputs.embed.shape[1]), "hidden": cfg.ranker.hidden,
                                         "layers": cfg.ranker.layers, "clip": cfg.ranker.clip},
                        "training": {**rstats, "seconds": ranker_seconds, "labels": how},
                        "tuning": tuning_record("ranker"),
                        "held_out": {"split": "val", "rollouts": len(inputs.val), **rmetrics}}, models_root)
    # rθ learns from ζσ labels only: every pooled trajectory (train, serve, uploaded), no proxies.
    (reward, gstats), reward_seconds = _timed(
        train_global_reward, pool.data, pool_zeta, cfg.reward,
        progress=_progress(stage_name("global_reward", rep), on_progress),
        curve=_curve(models_root, inputs, "global_reward", rep, _global_measure(inputs, val_zeta), cfg.reward))
    scorer = LibraryScorer(reward, Ragged.from_numpy(inputs.serve.states, inputs.serve.state_offsets))
    eps = {p: inputs.domain.epsilons(inputs.serve.proxies, p) for p in ("normal", "high")}
    match = {p: argmax_match_rate(scorer, inputs.serve, val_zeta, inputs.val.proxies, eps[p])
             for p in ("normal", "high")}
    log.info("global_reward[%s] argmax within ε on val: %s", rep, match)
    train_zeta = pool_zeta[: len(inputs.train)]
    save_model(reward, {**common, "kind": "global_reward", "weights_sha": weights_sha(reward),
                        "architecture": {**arch, "hidden": cfg.reward.hidden, "layers": cfg.reward.layers},
                        "zeta_bounds": np.stack([train_zeta.min(0), train_zeta.max(0)]).tolist(),
                        "training": {**gstats, "seconds": reward_seconds, "labels": "zeta of train+serve (no proxies)",
                                     "ranker_labels": how["mode"]},
                        "tuning": tuning_record("global_reward"),
                        "held_out": {"split": "val", "rollouts": len(inputs.val),
                                     "argmax_within_epsilon": match["normal"],
                                     "argmax_within_high_precision_epsilon": match["high"]}}, models_root)
    return {"ranker": rmetrics, "argmax_within_epsilon": match,
            "seconds": {"ranker": ranker_seconds, "global_reward": reward_seconds}}


def _local_metrics(model: LocalReward, inputs: _Inputs, cfg: LocalTrainConfig,
                   near_copy_radius: float) -> tuple[dict, dict]:
    """(ranking of val pairs among val rollouts, what the agent would do: argmax over serve per val edit)."""
    eps = inputs.domain.epsilons(inputs.serve.proxies)
    val = inputs.val
    val_pairs = local_pairs(val.proxies, eps, inputs.domain.attribute_names, cfg.labels, max_pairs=len(val))
    val_scorer = LocalLibraryScorer(model, Ragged.from_numpy(val.states, val.state_offsets))
    ranking = pair_metrics(val_scorer, val_pairs)
    serve_scorer = LocalLibraryScorer(model, Ragged.from_numpy(inputs.serve.states, inputs.serve.state_offsets))
    anchors = torch.as_tensor(val_pairs.anchor)
    edits = edit_metrics(serve_scorer, val_scorer.phi[anchors], val.proxies[val_pairs.anchor],
                         inputs.serve.proxies, val_pairs, eps, near_copy_radius)
    return ranking, edits


def train_local(domain_name: str, rep: str, cfg: LocalTrainConfig | None = None,
                data_root: Path | None = None, models_root: Path | None = None,
                sources: list[LabelSource] | None = None, on_progress: StageProgress | None = None) -> dict:
    """Train, evaluate and save ``local_reward-<rep>``; return the metrics.

    Pairs come from the proxies of ``train`` plus the local changes ``sources`` label (then
    negatives are drawn from train, serve and uploaded trajectories). Held-out numbers use pairs
    built the same way among ``val`` rollouts (anchors, targets and negatives all from val),
    plus what the agent would do: the argmax over ``serve`` for each val anchor and asked edit.
    """
    cfg = cfg or LocalTrainConfig()
    sources = sources or []
    declared = _declared(sources, lambda labels, name: any(c.attribute == name for c in labels.local_changes))
    inputs = _Inputs.load(domain_name, rep, data_root, declared.values())
    train = inputs.train
    eps = inputs.domain.epsilons(inputs.serve.proxies)
    pairs = local_pairs(train.proxies, eps, inputs.domain.attribute_names, cfg.labels)
    data = Ragged.from_numpy(train.states, train.state_offsets)  # rows of train = the first pool rows
    if sources:
        pool = _Pool(train, inputs.serve, sources)
        pairs, data = pairs.concat(pool.local_pairs(sources, inputs.names)), pool.data
    log.info("local pairs: %s", pair_counts(pairs, inputs.names))
    (model, stats), seconds = _timed(train_local_reward, data, pairs, inputs.embed, cfg.reward,
                                     progress=_progress(stage_name("local_reward", rep), on_progress),
                                     curve=_curve(models_root, inputs, "local_reward", rep,
                                                  _local_measure(inputs, cfg), cfg.reward))
    ranking, edits = _local_metrics(model, inputs, cfg, stats["near_copy_radius"])
    log.info("local_reward[%s] on val: %s; argmax over serve: %s", rep, ranking, edits)
    r = cfg.reward
    save_model(model, {**inputs.card(rep), "kind": "local_reward", "weights_sha": weights_sha(model),
                       "architecture": {"state_dim": inputs.domain.state_dim, "num_attributes": len(inputs.attrs),
                                        "embed_dim": int(inputs.embed.shape[1]), "hidden": r.hidden,
                                        "layers": r.layers, "lstm_hidden": r.lstm_hidden,
                                        "lstm_layers": r.lstm_layers, "anchor_stride": r.anchor_stride},
                       "near_copy_radius": stats["near_copy_radius"],
                       "labels": {**asdict(cfg.labels), "pairs": pair_counts(pairs, inputs.names),
                                  "epsilon": eps.tolist()},  # the ε the change bands are in units of
                       "training": {**stats, "seconds": seconds}, "tuning": tuning_record("local_reward"),
                       "held_out": {"split": "val", "rollouts": len(inputs.val), **ranking,
                                    "argmax_over_serve": edits}}, models_root)
    return {"local_reward": ranking, "argmax_over_serve": edits, "seconds": {"local_reward": seconds}}


VAE_ROLLOUTS = 300  # kinematic lane-change rollouts whose frames train the frame VAE


def train_frame_vae(domain_name: str, seed: int = 0, models_root: Path | None = None) -> dict:
    """Train and save an image view's frame VAE on frames of its kinematic rollouts; its stats."""
    domain = get_domain(domain_name)
    rng = np.random.default_rng(10_000 + seed)
    kinematic = [domain.kinematic_rollout(domain.sample_params(rng), seed=i) for i in range(VAE_ROLLOUTS)]
    frames = np.concatenate([domain.frames(r) for r in kinematic])
    log.info("training the frame VAE on %d stacked frames", len(frames))
    latent = domain.state_dim
    model, stats = train_vae(frames, VAEConfig(latent=latent, seed=seed), progress=_progress("vae[frames]"))
    kind, rep = domain.state_encoder
    save_model(model, {"domain": domain.name, "kind": kind, "representation": rep,
                       "architecture": {"latent": latent, "size": SIZE, "stack": STACK, **domain.frame_view},
                       "training": stats, "tuning": tuning_record(kind)}, models_root)
    return stats


def _ranker_held_out(card: dict, model, inputs: _Inputs, models_root: Path | None) -> dict:
    k = len(inputs.domain.attributes)
    return ranking_metrics(model.score_library(inputs.val)[:, :k], inputs.val.proxies, inputs.domain.attribute_names)


def _global_held_out(card: dict, model, inputs: _Inputs, models_root: Path | None) -> dict:
    val_zeta = load_model(inputs.name, "ranker", card["representation"], models_root).model.score_library(inputs.val)
    scorer = LibraryScorer(model, Ragged.from_numpy(inputs.serve.states, inputs.serve.state_offsets))
    eps = {p: inputs.domain.epsilons(inputs.serve.proxies, p) for p in ("normal", "high")}
    match = {p: argmax_match_rate(scorer, inputs.serve, val_zeta, inputs.val.proxies, eps[p]) for p in eps}
    return {"argmax_within_epsilon": match["normal"], "argmax_within_high_precision_epsilon": match["high"]}


def _local_held_out(card: dict, model, inputs: _Inputs, models_root: Path | None) -> dict:
    labels = {k: v for k, v in card["labels"].items() if k in LocalLabelConfig.__dataclass_fields__}
    ranking, edits = _local_metrics(model, inputs, LocalTrainConfig(LocalLabelConfig(**labels)),
                                    card["near_copy_radius"])
    return {**ranking, "argmax_over_serve": edits}


_HELD_OUT = {"ranker": _ranker_held_out, "global_reward": _global_held_out, "local_reward": _local_held_out}


def remeasure(domain_name: str, rep: str, data_root: Path | None = None, models_root: Path | None = None) -> dict:
    """Recompute the held-out numbers of the saved ``rep`` models' cards on val with today's ε (`rba train
    --remeasure`): after a change of split or ε the cards tell the truth again; the weights stay as they are."""
    inputs = _Inputs.load(domain_name, rep, data_root)
    files, out = model_files(models_root), {}
    for kind, measure in _HELD_OUT.items():
        try:
            artifact = load_model(domain_name, kind, rep, models_root)
        except ModelNotFoundError:
            continue
        held = {"split": "val", "rollouts": len(inputs.val), **measure(artifact.card, artifact.model, inputs,
                                                                         models_root)}
        card = dict(artifact.card, data=inputs.card(rep)["data"], held_out=held, tuning=tuning_record(kind))
        save_json(files.card(domain_name, kind, rep), card)
        out[kind] = held
    return out


# A domain's ``state_encoder`` kind -> what trains it: (domain, seed, models_root) -> training stats.
ENCODER_TRAINERS: dict[str, Callable[[str, int, Path | None], dict]] = {"vae": train_frame_vae}


def prepare_states(domain_name: str, seed: int = 0, models_root: Path | None = None) -> None:
    """Train the state encoder ``domain_name``'s rollouts load unless it is saved (most domains need none)."""
    domain = get_domain(domain_name)
    if domain.state_encoder is None:
        return
    kind, rep = domain.state_encoder
    try:
        load_model(domain_name, kind, rep, models_root)
    except ModelNotFoundError:
        ENCODER_TRAINERS[kind](domain_name, seed, models_root)
