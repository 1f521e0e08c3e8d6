"""RBA-Global step 1: the attribute strength estimator ζσ(τ, α) = clip(Σ_t fσ([s_t, e_α])).

The clip is soft (c·tanh(x / c), c = 20 as in the paper): a hard clamp has zero gradient
once a sum saturates, and with ~100 states per clip a freshly initialised fσ saturates at
once and never recovers. The last layer also starts small, so sums start near zero.

Trained with the Bradley-Terry loss (paper §4.2, eq. 3) on ``AttributeLabels``: for each
attribute, which labelled trajectory shows more of it than which. By default they are the
orderings by proxy of at most ``max_labelled`` ``train`` clips (the stand-in for an agent
designer's labels); admins add orderings and comparisons of their own (``rba.labelsets``).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass

import numpy as np
import torch
from scipy.stats import kendalltau
from torch import nn
from torch.nn import functional as F

from rba.learn.common import Normalizer, Ragged, check_shape, mlp, seed_everything, segment_sum
from rba.library import SkillLibrary

log = logging.getLogger(__name__)


@dataclass
class RankerConfig:
    """Options of ζσ training (CLI flags map onto these)."""

    hidden: int = 256  # MLP width (the paper's 512/1024 is ~4x slower on 2 CPU cores for no accuracy gain here)
    layers: int = 3  # fully connected layers
    clip: float = 20.0  # ζ is clipped to [-clip, clip] as in the paper
    max_labelled: int = 200  # labelled train clips (the paper's label budget)
    steps: int = 800  # gradient steps, cosine-decayed lr (snake: 400 left bend_width at 0.948 pairwise accuracy)
    batch_clips: int = 64  # labelled clips per step and attribute; the loss covers every labelled pair among them
    lr: float = 1e-3
    weight_decay: float = 1e-5
    seed: int = 0


class AttributeRanker(nn.Module):
    """fσ([s, e_α]) summed over a trajectory; ``attr_embed`` holds e_α for every attribute."""

    def __init__(self, state_dim: int, attr_embed: torch.Tensor, hidden: int = 256, layers: int = 3,
                 clip: float = 20.0) -> None:
        super().__init__()
        self.state_dim = state_dim
        self.clip = clip
        self.register_buffer("attr_embed", torch.as_tensor(attr_embed, dtype=torch.float32))
        self.norm = Normalizer(state_dim)
        self.f = mlp(state_dim + self.attr_embed.shape[1], hidden, layers)
        with torch.no_grad():
            self.f[-1].weight.mul_(0.01)
            self.f[-1].bias.zero_()

    def soft_clip(self, z: torch.Tensor) -> torch.Tensor:
        return self.clip * torch.tanh(z / self.clip)

    @property
    def num_attributes(self) -> int:
        return self.attr_embed.shape[0]

    def per_state(self, states: torch.Tensor, attr: int) -> torch.Tensor:
        """fσ for each state: float32[N] for float32[N, state_dim]."""
        check_shape(states, None, self.state_dim, name="states")
        e = self.attr_embed[attr].expand(len(states), -1)
        return self.f(torch.cat([self.norm(states), e], 1)).squeeze(1)

    def trajectory_scores(self, states: torch.Tensor, seg: torch.Tensor, n: int, attr: int) -> torch.Tensor:
        """ζσ for ``n`` trajectories whose states are tagged by ``seg``: float32[n]."""
        return self.soft_clip(segment_sum(self.per_state(states, attr), seg, n))

    @torch.no_grad()
    def score(self, data: Ragged, batch_states: int = 65536) -> np.ndarray:
        """ζσ(τ, α) for every trajectory and attribute: float64[N, k] (vectorised, batched)."""
        self.eval()
        out = torch.zeros(len(data), self.num_attributes)
        seg = data.segment_ids()
        for a in range(self.num_attributes):
            for lo in range(0, len(data.states), batch_states):
                out[:, a] += segment_sum(self.per_state(data.states[lo:lo + batch_states], a),
                                         seg[lo:lo + batch_states], len(data))
        return self.soft_clip(out).double().numpy()

    def score_library(self, lib: SkillLibrary) -> np.ndarray:
        return self.score(Ragged.from_numpy(lib.states, lib.state_offsets))


def labelled_subset(lib: SkillLibrary, max_labelled: int, seed: int) -> np.ndarray:
    """Indices of the train clips an agent designer would label (a seeded random subset)."""
    rng = np.random.default_rng(seed)
    n = min(max_labelled, len(lib))
    return np.sort(rng.choice(len(lib), size=n, replace=False))


@dataclass
class AttributeLabels:
    """One attribute's labels: which labelled trajectory shows more of it than which."""

    clips: np.ndarray  # int64[m]: the labelled trajectories (indices into the training data)
    more: np.ndarray  # bool[m, m]: more[i, j] = clips[i] shows more of the attribute than clips[j]

    def __post_init__(self) -> None:
        m = len(self.clips)
        if self.more.shape != (m, m):
            raise ValueError(f"more must be [{m}, {m}], got {list(self.more.shape)}")
        if (self.more & self.more.T).any():
            raise ValueError("contradictory labels: some pair is labelled both ways")

    @classmethod
    def from_values(cls, clips: np.ndarray, values: np.ndarray) -> AttributeLabels:
        """A total order by ``values`` (ties stay unlabelled): how proxies label clips."""
        values = np.asarray(values, dtype=np.float64)
        return cls(np.asarray(clips, dtype=np.int64), values[:, None] > values[None, :])

    @classmethod
    def from_pairs(cls, pairs: list[tuple[int, int]]) -> AttributeLabels:
        """From (more, less) trajectory pairs; orderings become the pairs they imply."""
        clips = np.unique(np.asarray(pairs, dtype=np.int64).reshape(-1))
        pos = {int(c): i for i, c in enumerate(clips)}
        more = np.zeros((len(clips), len(clips)), dtype=bool)
        for hi, lo in pairs:
            more[pos[int(hi)], pos[int(lo)]] = True
        return cls(clips, more)

    @property
    def num_pairs(self) -> int:
        return int(self.more.sum())


def proxy_labels(lib: SkillLibrary, max_labelled: int, seed: int) -> list[AttributeLabels]:
    """Every attribute's ordering, by proxy, of the same ``max_labelled`` clips of ``lib``."""
    idx = labelled_subset(lib, max_labelled, seed)
    return [AttributeLabels.from_values(idx, lib.proxies[idx, a]) for a in range(lib.proxies.shape[1])]


def labelled_pairs_loss(scores: torch.Tensor, more: torch.Tensor) -> torch.Tensor:
    """Bradley-Terry loss over every labelled pair (i more than j) of a batch."""
    return F.binary_cross_entropy_with_logits((scores[:, None] - scores[None, :])[more],
                                              torch.ones(int(more.sum())))


def train_ranker(data: Ragged, labels: list[AttributeLabels], attr_embed: np.ndarray, cfg: RankerConfig,
                 progress=None) -> tuple[AttributeRanker, dict]:
    """Fit ζσ on ``labels`` (one entry per row of ``attr_embed``); returns the model and stats.

    Each step scores a batch of each attribute's labelled clips and takes the loss over every
    labelled pair in the batch: the same compute as a few pairs, many times the signal.
    """
    if len(labels) != len(attr_embed):
        raise ValueError(f"{len(labels)} label sets for {len(attr_embed)} attributes")
    if empty := [a for a, lab in enumerate(labels) if lab.num_pairs == 0]:
        raise ValueError(f"attributes {empty} have no labelled pairs")
    gen = seed_everything(cfg.seed)
    torch.set_num_threads(2)
    model = AttributeRanker(data.states.shape[1], torch.as_tensor(attr_embed), cfg.hidden, cfg.layers, cfg.clip)
    used = torch.as_tensor(np.unique(np.concatenate([lab.clips for lab in labels])))
    model.norm.fit(data.select(used)[0].numpy())
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(cfg.steps, 1))
    clips = [torch.as_tensor(lab.clips) for lab in labels]
    more = [torch.as_tensor(lab.more) for lab in labels]
    loss_val = float("nan")
    for step in range(cfg.steps):
        losses = []
        for a in range(len(labels)):
            batch = torch.randperm(len(clips[a]), generator=gen)[: cfg.batch_clips]
            pairs = more[a][batch][:, batch]
            if not pairs.any():
                continue
            states, seg = data.select(clips[a][batch])
            losses.append(labelled_pairs_loss(model.trajectory_scores(states, seg, len(batch), a), pairs))
        if not losses:
            continue
        loss = sum(losses) / len(losses)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        loss_val = loss.item()
        if progress and (step % 50 == 0 or step == cfg.steps - 1):
            progress(step + 1, cfg.steps, loss_val)
    model.eval()
    stats = {"labelled_clips": len(used), "labelled_pairs": [lab.num_pairs for lab in labels]}
    return model, {**stats, "final_loss": round(loss_val, 5), "config": asdict(cfg)}


def ranking_metrics(zeta: np.ndarray, proxies: np.ndarray, attribute_names) -> dict[str, dict[str, float]]:
    """Per attribute: pairwise ordering accuracy and Kendall τ between ζσ and the proxy."""
    out = {}
    for a, name in enumerate(attribute_names):
        z, p = zeta[:, a], proxies[:, a]
        dz, dp = np.sign(z[:, None] - z[None, :]), np.sign(p[:, None] - p[None, :])
        mask = dp != 0
        acc = float((dz[mask] == dp[mask]).mean())
        out[name] = {"pairwise_accuracy": round(acc, 4), "kendall_tau": round(float(kendalltau(z, p).statistic), 4)}
    return out
