"""`rba train`: fit RBA-Global (ζσ, rθ) or RBA-Local (rθ) models, measure them on `test`, save with cards."""

from __future__ import annotations

import hashlib
import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from rba.artifacts import save_model
from rba.domains import get_domain
from rba.embed import attribute_embeddings, check_rep
from rba.labels import LocalLabelConfig, local_pairs, pair_counts
from rba.learn.common import Ragged
from rba.learn.global_reward import GlobalRewardConfig, LibraryScorer, train_global_reward
from rba.learn.local_reward import (
    LocalLibraryScorer,
    LocalRewardConfig,
    edit_metrics,
    pair_metrics,
    train_local_reward,
)
from rba.learn.ranker import RankerConfig, ranking_metrics, train_ranker
from rba.library import SkillLibrary

log = logging.getLogger(__name__)


@dataclass
class GlobalTrainConfig:
    ranker: RankerConfig = field(default_factory=RankerConfig)
    reward: GlobalRewardConfig = field(default_factory=GlobalRewardConfig)


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


def _progress(name: str):
    def report(step: int, total: int, loss: float) -> None:
        log.info("%s step %d/%d loss %.4f", name, step, total, loss)
    return report


def _training_inputs(domain_name: str, rep: str, data_root: Path | None):
    """What every trainer starts from: the domain, its three splits, e_α for each attribute, card entries."""
    check_rep(rep)
    domain = get_domain(domain_name)
    libs = tuple(SkillLibrary.load(domain_name, s, data_root) for s in ("train", "serve", "test"))
    embed = attribute_embeddings([a.description for a in domain.attributes], rep)
    attrs = [{"name": a.name, "description": a.description, "unit": a.unit} for a in domain.attributes]
    return domain, libs, embed, attrs


def train_global(domain_name: str, rep: str, cfg: GlobalTrainConfig | None = None,
                 data_root: Path | None = None, models_root: Path | None = None) -> dict:
    """Train, evaluate and save ``ranker-<rep>`` and ``global_reward-<rep>``; return the metrics."""
    cfg = cfg or GlobalTrainConfig()
    domain, (train, serve, test), embed, attrs = _training_inputs(domain_name, rep, data_root)

    t0 = time.perf_counter()
    ranker, rstats = train_ranker(train, embed, cfg.ranker, progress=_progress(f"ranker[{rep}]"))
    ranker_seconds = time.perf_counter() - t0
    test_zeta = ranker.score_library(test)
    rmetrics = ranking_metrics(test_zeta, test.proxies, domain.attribute_names)
    log.info("ranker[%s] on test: %s", rep, rmetrics)
    train_zeta = ranker.score_library(train)
    common = {"domain": domain_name, "representation": rep, "attributes": attrs,
              "data": {"train": train.version, "serve": serve.version, "test": test.version}}
    save_model(ranker, {**common, "kind": "ranker", "weights_sha": weights_sha(ranker),
                        "architecture": {"state_dim": domain.state_dim, "num_attributes": len(attrs),
                                         "embed_dim": int(embed.shape[1]), "hidden": cfg.ranker.hidden,
                                         "layers": cfg.ranker.layers, "clip": cfg.ranker.clip},
                        "training": {**rstats, "seconds": round(ranker_seconds, 1)},
                        "held_out": {"split": "test", "rollouts": len(test), **rmetrics}}, models_root)

    # rθ learns from ζσ labels only: all train + serve trajectories, no proxies.
    states = np.concatenate([train.states, serve.states])
    offsets = np.concatenate([train.state_offsets, serve.state_offsets[1:] + train.state_offsets[-1]])
    data = Ragged.from_numpy(states, offsets)
    zeta = np.concatenate([train_zeta, ranker.score_library(serve)])
    t0 = time.perf_counter()
    reward, gstats = train_global_reward(data, zeta, cfg.reward, progress=_progress(f"global_reward[{rep}]"))
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


def train_local(domain_name: str, rep: str, cfg: LocalTrainConfig | None = None,
                data_root: Path | None = None, models_root: Path | None = None) -> dict:
    """Train, evaluate and save ``local_reward-<rep>``; return the metrics.

    Held-out numbers use pairs built the same way among ``test`` rollouts (anchors, targets and
    negatives all from test), plus what the agent would do: the argmax over ``serve`` for each
    test anchor and asked edit.
    """
    cfg = cfg or LocalTrainConfig()
    domain, (train, serve, test), embed, attrs = _training_inputs(domain_name, rep, data_root)
    eps = domain.epsilons()
    pairs = local_pairs(train.proxies, eps, domain.attribute_names, cfg.labels)
    log.info("local pairs from train: %s", pair_counts(pairs, domain.attribute_names))
    t0 = time.perf_counter()
    model, stats = train_local_reward(train, pairs, embed, cfg.reward, progress=_progress(f"local_reward[{rep}]"))
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
                       "labels": {**asdict(cfg.labels), "pairs": pair_counts(pairs, domain.attribute_names)},
                       "training": {**stats, "seconds": round(seconds, 1)},
                       "held_out": {"split": "test", "rollouts": len(test), **ranking, "argmax_over_serve": edits}},
               models_root)
    return {"local_reward": ranking, "argmax_over_serve": edits, "seconds": {"local_reward": round(seconds, 1)}}
