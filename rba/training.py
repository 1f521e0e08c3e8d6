"""`rba train`: fit RBA-Global (ζσ, rθ) or RBA-Local (rθ) models, measure them on `test`, save with cards."""

from __future__ import annotations

import hashlib
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from rba.artifacts import save_model
from rba.domains import get_domain
from rba.embed import attribute_embeddings, check_rep
from rba.labels import LocalLabelConfig, LocalPairs, local_pairs, pair_counts
from rba.labelsets import LabelSet, merge_pairs
from rba.learn.common import Ragged
from rba.learn.global_reward import GlobalRewardConfig, LibraryScorer, train_global_reward
from rba.learn.local_reward import (
    LocalLibraryScorer,
    LocalRewardConfig,
    edit_metrics,
    pair_metrics,
    train_local_reward,
)
from rba.learn.ranker import AttributeLabels, RankerConfig, proxy_labels, ranking_metrics, train_ranker
from rba.library import SkillLibrary

log = logging.getLogger(__name__)


PRESETS = ("default", "quick", "tiny")  # 'quick': full ζσ, a shorter rθ; 'tiny': seconds-long smoke runs


@dataclass
class GlobalTrainConfig:
    ranker: RankerConfig = field(default_factory=RankerConfig)
    reward: GlobalRewardConfig = field(default_factory=GlobalRewardConfig)

    @classmethod
    def preset(cls, name: str, seed: int = 0, domain: str | None = None) -> GlobalTrainConfig:
        """``tiny`` (CI), ``quick`` or ``default``; ``default`` takes ``domain``'s ζσ steps if it sets them."""
        if name == "tiny":
            return cls(RankerConfig(steps=200, hidden=64, seed=seed),
                       GlobalRewardConfig(steps=120, hidden=64, seed=seed))
        if name == "quick":
            return cls(RankerConfig(seed=seed), GlobalRewardConfig(steps=300, hidden=128, seed=seed))
        steps = get_domain(domain).ranker_steps if domain else None
        return cls(RankerConfig(seed=seed, **({"steps": steps} if steps else {})), GlobalRewardConfig(seed=seed))


def weights_sha(model: torch.nn.Module) -> str:
    h = hashlib.sha256()
    for name, t in sorted(model.state_dict().items()):
        h.update(name.encode() + t.detach().contiguous().numpy().tobytes())
    return h.hexdigest()[:12]


def argmax_match_rate(scorer: LibraryScorer, serve: SkillLibrary, target_zeta: np.ndarray,
                      target_proxies: np.ndarray, eps: np.ndarray) -> float:
    """Fraction of targets for which argmax_serve Σ rθ(·|ζ(target)) is within ε on every attribute."""
    hits = [np.all(np.abs(serve.proxies[scorer.argmax(z)] - p) <= eps)
            for z, p in zip(target_zeta, target_proxies, strict=True)]
    return float(np.mean(hits))


Progress = Callable[[str, int, int, float], None]  # (stage, step, total steps, loss)


def _progress(name: str, on_progress: Progress | None = None):
    def report(step: int, total: int, loss: float) -> None:
        log.info("%s step %d/%d loss %.4f", name, step, total, loss)
        if on_progress is not None:
            on_progress(name, step, total, loss)
    return report


def _training_inputs(domain_name: str, rep: str, data_root: Path | None, extra_attributes=()):
    """What every trainer starts from: the domain, its three splits, e_α for each attribute, card entries."""
    check_rep(rep)
    domain = get_domain(domain_name)
    libs = tuple(SkillLibrary.load(domain_name, s, data_root) for s in ("train", "serve", "test"))
    attrs = [{"name": a.name, "description": a.description, "unit": a.unit} for a in domain.attributes]
    attrs += [{"name": a.name, "description": a.description, "unit": ""} for a in extra_attributes]
    embed = attribute_embeddings([a["description"] for a in attrs], rep)
    return domain, libs, embed, attrs


@dataclass
class LabelSource:
    """Labels from an agent designer, with the trajectories uploaded beside them (name -> float[T, D])."""

    labels: LabelSet
    trajectories: dict[str, np.ndarray] = field(default_factory=dict)


class _Pool:
    """Every trajectory a ranker can learn from: train, serve, then uploaded ones; refs -> rows."""

    def __init__(self, train: SkillLibrary, serve: SkillLibrary, sources: list[LabelSource]) -> None:
        self.library_index = {rid: i for i, rid in enumerate(train.ids)}
        self.library_index |= {rid: len(train) + i for i, rid in enumerate(serve.ids)}
        arrays = [train.states, serve.states]
        offsets = [train.state_offsets[:-1], serve.state_offsets[:-1] + len(train.states)]
        self.uploaded: list[dict[str, int]] = []
        n, rows = len(train) + len(serve), len(train.states) + len(serve.states)
        for src in sources:
            names = {}
            for name, traj in src.trajectories.items():
                names[name] = n
                arrays.append(np.asarray(traj, dtype=np.float32))
                offsets.append(np.array([rows]))
                n, rows = n + 1, rows + len(traj)
            self.uploaded.append(names)
        self.data = Ragged.from_numpy(np.concatenate(arrays), np.concatenate([*offsets, [rows]]))

    def index(self, source: int, ref: str) -> int:
        return self.uploaded[source].get(ref, self.library_index.get(ref, -1))

    def pairs(self, sources: list[LabelSource], attribute: str) -> list[list[tuple[int, int]]]:
        return [[(self.index(i, hi), self.index(i, lo)) for hi, lo in src.labels.pairs(attribute)]
                for i, src in enumerate(sources)]

    def local_pairs(self, sources: list[LabelSource], attribute_names: list[str]) -> LocalPairs:
        """The sources' local changes as RBA-Local pairs over the pool's rows."""
        rows = [(self.index(i, c.anchor), self.index(i, c.changed), attribute_names.index(c.attribute),
                 1 if c.direction == "more" else -1)
                for i, src in enumerate(sources) for c in src.labels.local_changes]
        cols = np.array(rows, dtype=np.int64).reshape(-1, 4)
        return LocalPairs(cols[:, 0], cols[:, 1], cols[:, 2], cols[:, 3])


def _declared(sources: list[LabelSource], labelled: Callable[[LabelSet, str], bool]) -> dict:
    """New attributes the sources declare and label in the way this trainer learns from."""
    declared = {a.name: a for src in sources for a in src.labels.new_attributes}
    return {n: a for n, a in declared.items() if any(labelled(src.labels, n) for src in sources)}


def _split_pairs(labels, seed: int, held_out: float = 0.2):
    """(train labels, held-out (more, less) pairs): a seeded share of the pairs is kept for measuring."""
    hi, lo = np.nonzero(labels.more)
    pairs = np.stack([labels.clips[hi], labels.clips[lo]], 1)
    rng = np.random.default_rng(seed)
    test = rng.random(len(pairs)) < held_out
    if test.sum() < 5 or (~test).sum() == 0:
        return labels, pairs[:0]
    return AttributeLabels.from_pairs([tuple(p) for p in pairs[~test]]), pairs[test]


def train_global(domain_name: str, rep: str, cfg: GlobalTrainConfig | None = None,
                 data_root: Path | None = None, models_root: Path | None = None,
                 sources: list[LabelSource] | None = None, on_progress: Progress | None = None) -> dict:
    """Train, evaluate and save ``ranker-<rep>`` and ``global_reward-<rep>``; return the metrics.

    The domain's attributes are labelled by proxy (``max_labelled`` train clips), plus what
    ``sources`` say about them; attributes that ``sources`` declare new are labelled by
    ``sources`` alone, and a fifth of their pairs is held out to measure ζσ on.
    """
    cfg = cfg or GlobalTrainConfig.preset("default", domain=domain_name)
    sources = sources or []
    declared = _declared(sources, lambda labels, name: bool(labels.pairs(name)))
    domain, (train, serve, test), embed, attrs = _training_inputs(domain_name, rep, data_root, declared.values())
    pool = _Pool(train, serve, sources)
    builtin = proxy_labels(train, cfg.ranker.max_labelled, cfg.ranker.seed)
    labels, held_out_pairs = [], {}
    for a, spec in enumerate(attrs):
        given = pool.pairs(sources, spec["name"])
        if a < len(builtin):
            base = builtin[a]
            hi, lo = np.nonzero(base.more)
            labels.append(merge_pairs([list(zip(base.clips[hi], base.clips[lo], strict=True)), *given]))
        else:
            merged = merge_pairs(given)
            fit, held_out_pairs[spec["name"]] = _split_pairs(merged, cfg.ranker.seed)
            labels.append(fit)

    t0 = time.perf_counter()
    ranker, rstats = train_ranker(pool.data, labels, embed, cfg.ranker,
                                  progress=_progress(f"ranker[{rep}]", on_progress))
    ranker_seconds = time.perf_counter() - t0
    test_zeta = ranker.score_library(test)
    k = len(domain.attributes)
    rmetrics = ranking_metrics(test_zeta[:, :k], test.proxies, domain.attribute_names)
    pool_zeta = ranker.score(pool.data)
    for name, pairs in held_out_pairs.items():
        a = next(i for i, spec in enumerate(attrs) if spec["name"] == name)
        acc = float(np.mean(pool_zeta[pairs[:, 0], a] > pool_zeta[pairs[:, 1], a])) if len(pairs) else None
        rmetrics[name] = {"held_out_pair_accuracy": acc, "held_out_pairs": len(pairs)}
    log.info("ranker[%s] held out: %s", rep, rmetrics)
    train_zeta = pool_zeta[: len(train)]
    common = {"domain": domain_name, "representation": rep, "attributes": attrs,
              "data": {"train": train.version, "serve": serve.version, "test": test.version}}
    if sources:
        common["labels"] = {"sources": len(sources), "uploaded_trajectories": len(pool.data) - len(train) - len(serve),
                            "new_attributes": sorted(declared)}
    save_model(ranker, {**common, "kind": "ranker", "weights_sha": weights_sha(ranker),
                        "architecture": {"state_dim": domain.state_dim, "num_attributes": len(attrs),
                                         "embed_dim": int(embed.shape[1]), "hidden": cfg.ranker.hidden,
                                         "layers": cfg.ranker.layers, "clip": cfg.ranker.clip},
                        "training": {**rstats, "seconds": round(ranker_seconds, 1)},
                        "held_out": {"split": "test", "rollouts": len(test), **rmetrics}}, models_root)

    # rθ learns from ζσ labels only: every pooled trajectory (train, serve, uploaded), no proxies.
    t0 = time.perf_counter()
    reward, gstats = train_global_reward(pool.data, pool_zeta, cfg.reward,
                                         progress=_progress(f"global_reward[{rep}]", on_progress))
    reward_seconds = time.perf_counter() - t0
    scorer = LibraryScorer(reward, Ragged.from_numpy(serve.states, serve.state_offsets))
    match = {p: argmax_match_rate(scorer, serve, test_zeta, test.proxies, domain.epsilons(p))
             for p in ("normal", "high")}
    log.info("global_reward[%s] argmax within ε on test: %s", rep, match)
    bounds = np.stack([train_zeta.min(0), train_zeta.max(0)])
    save_model(reward, {**common, "kind": "global_reward", "weights_sha": weights_sha(reward),
                        "architecture": {"state_dim": domain.state_dim, "num_attributes": len(attrs),
                                         "hidden": cfg.reward.hidden, "layers": cfg.reward.layers},
                        "zeta_bounds": bounds.tolist(),
                        "training": {**gstats, "seconds": round(reward_seconds, 1),
                                     "labels": "zeta of train+serve (no proxies)"},
                        "held_out": {"split": "test", "rollouts": len(test),
                                     "argmax_within_epsilon": match["normal"],
                                     "argmax_within_high_precision_epsilon": match["high"]}}, models_root)
    return {"ranker": rmetrics, "argmax_within_epsilon": match,
            "seconds": {"ranker": round(ranker_seconds, 1), "global_reward": round(reward_seconds, 1)}}


@dataclass
class LocalTrainConfig:
    """RBA-Local training: which pairs get labelled, and how rθ is fitted."""

    labels: LocalLabelConfig = field(default_factory=LocalLabelConfig)
    reward: LocalRewardConfig = field(default_factory=LocalRewardConfig)

    @classmethod
    def preset(cls, name: str, seed: int = 0) -> LocalTrainConfig:
        if name in ("tiny", "quick"):
            return cls(LocalLabelConfig(seed=seed), LocalRewardConfig(steps=150, hidden=64, lstm_hidden=32, seed=seed))
        return cls(LocalLabelConfig(seed=seed), LocalRewardConfig(seed=seed))


def train_local(domain_name: str, rep: str, cfg: LocalTrainConfig | None = None,
                data_root: Path | None = None, models_root: Path | None = None,
                sources: list[LabelSource] | None = None, on_progress: Progress | None = None) -> dict:
    """Train, evaluate and save ``local_reward-<rep>``; return the metrics.

    Pairs come from the proxies of ``train`` plus the local changes ``sources`` label (then
    negatives are drawn from train, serve and uploaded trajectories). Held-out numbers use pairs
    built the same way among ``test`` rollouts (anchors, targets and negatives all from test),
    plus what the agent would do: the argmax over ``serve`` for each test anchor and asked edit.
    """
    cfg = cfg or LocalTrainConfig()
    sources = sources or []
    declared = _declared(sources, lambda labels, name: any(c.attribute == name for c in labels.local_changes))
    domain, (train, serve, test), embed, attrs = _training_inputs(domain_name, rep, data_root, declared.values())
    names = [a["name"] for a in attrs]
    eps = domain.epsilons()
    pairs = local_pairs(train.proxies, eps, domain.attribute_names, cfg.labels)  # rows of train = first pool rows
    data = Ragged.from_numpy(train.states, train.state_offsets)
    if sources:
        pool = _Pool(train, serve, sources)
        pairs, data = pairs.concat(pool.local_pairs(sources, names)), pool.data
    log.info("local pairs: %s", pair_counts(pairs, names))
    t0 = time.perf_counter()
    model, stats = train_local_reward(data, pairs, embed, cfg.reward,
                                      progress=_progress(f"local_reward[{rep}]", on_progress))
    seconds = time.perf_counter() - t0
    test_pairs = local_pairs(test.proxies, eps, domain.attribute_names, cfg.labels, max_pairs=len(test))
    test_scorer = LocalLibraryScorer(model, Ragged.from_numpy(test.states, test.state_offsets))
    ranking = pair_metrics(test_scorer, test_pairs)
    serve_scorer = LocalLibraryScorer(model, Ragged.from_numpy(serve.states, serve.state_offsets))
    anchors = torch.as_tensor(test_pairs.anchor)
    edits = edit_metrics(serve_scorer, test_scorer.phi[anchors], test.proxies[test_pairs.anchor], serve.proxies,
                         test_pairs, eps, stats["near_copy_radius"])
    log.info("local_reward[%s] on test: %s; argmax over serve: %s", rep, ranking, edits)
    save_model(model, {"domain": domain_name, "representation": rep, "attributes": attrs, "kind": "local_reward",
                       "data": {"train": train.version, "serve": serve.version, "test": test.version},
                       "weights_sha": weights_sha(model),
                       "architecture": {"state_dim": domain.state_dim, "num_attributes": len(attrs),
                                        "embed_dim": int(embed.shape[1]), "hidden": cfg.reward.hidden,
                                        "layers": cfg.reward.layers, "lstm_hidden": cfg.reward.lstm_hidden,
                                        "lstm_layers": cfg.reward.lstm_layers,
                                        "anchor_stride": cfg.reward.anchor_stride},
                       "near_copy_radius": stats["near_copy_radius"],
                       "labels": {**asdict(cfg.labels), "pairs": pair_counts(pairs, names)},
                       "training": {**stats, "seconds": round(seconds, 1)},
                       "held_out": {"split": "test", "rollouts": len(test), **ranking, "argmax_over_serve": edits}},
               models_root)
    return {"local_reward": ranking, "argmax_over_serve": edits, "seconds": {"local_reward": round(seconds, 1)}}
