"""RBA-Global step 1: the attribute strength estimator ζσ(τ, α) = clip(Σ_t fσ([s_t, e_α])).

The clip is soft (c·tanh(x / c), c = 20 as in the paper): a hard clamp has zero gradient
once a sum saturates, and with ~100 states per clip a freshly initialised fσ saturates at
once and never recovers. The last layer also starts small, so sums start near zero.

Trained with the Bradley-Terry loss (paper §4.2, eq. 3) on ``AttributeLabels``: for each
attribute, which labelled trajectory shows more of it than which. By default they are the
orderings by proxy of at most ``max_labelled`` ``train`` clips (the stand-in for an agent
designer's labels); ``RankerConfig.labels`` can ask for a simulated annotator's noisy pairwise
answers instead; admins add orderings and comparisons of their own (``rba.data.labels``).
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass, field

import numpy as np
import torch
from torch import nn

from rba.core.settings import LibrarySettings
from rba.data.labels import AttributeLabels, GlobalLabelConfig
from rba.data.library import SkillLibrary
from rba.learn.common import (
    CurveOf,
    Normalizer,
    Progress,
    Ragged,
    StepLoop,
    bradley_terry_loss,
    check_shape,
    mlp,
    seed_everything,
    segment_sum,
)


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
    labels: GlobalLabelConfig = field(default_factory=GlobalLabelConfig)  # proxy ordering or annotator pairs


class AttributeRanker(nn.Module):
    """fσ([s, e_α]) summed over a trajectory; ``attr_embed`` holds e_α for every attribute.

    fσ's last layer is linear, so ζσ is soft_clip(φ(τ, α) · w + T b), φ the last layer's input summed over the
    trajectory (``summed_features``): a copy ``with_heads`` gives each attribute a last layer of its own
    (``rba.interact.refit``: re-fitted near a session's target on its answers) while sharing everything below."""

    heads: tuple[torch.Tensor, torch.Tensor] | None = None  # per-attribute last layers (float32[k, H], [k])

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
        x = torch.cat([self.norm(states), self.attr_embed[attr].expand(len(states), -1)], 1)
        if self.heads is None:
            return self.f(x).squeeze(1)
        weight, bias = self.heads
        return self.f[:-1](x) @ weight[attr] + bias[attr]

    def trained_head(self) -> tuple[np.ndarray, np.ndarray]:
        """The trained last layer, as each attribute's: float64[k, H] weights, float64[k] biases."""
        last = self.f[-1]
        k = self.num_attributes
        return (np.tile(last.weight.detach().double().numpy()[0], (k, 1)),
                np.full(k, float(last.bias.detach()[0])))

    def head(self) -> tuple[np.ndarray, np.ndarray]:
        """Each attribute's last layer as used now (``with_heads``, else the trained one)."""
        if self.heads is None:
            return self.trained_head()
        return self.heads[0].double().numpy(), self.heads[1].double().numpy()

    def with_heads(self, weight: np.ndarray, bias: np.ndarray) -> AttributeRanker:
        """A copy (sharing every other weight) that scores attribute a with last layer ``weight[a], bias[a]``."""
        check_shape(torch.as_tensor(weight), self.num_attributes, self.f[-1].in_features, name="weight")
        check_shape(torch.as_tensor(bias), self.num_attributes, name="bias")
        out = copy.copy(self)
        out.heads = (torch.as_tensor(weight, dtype=torch.float32), torch.as_tensor(bias, dtype=torch.float32))
        return out

    @torch.no_grad()
    def summed_features(self, data: Ragged, batch_states: int = 65536) -> tuple[np.ndarray, np.ndarray]:
        """φ per attribute and trajectory, float64[k, N, H], and trajectory lengths T, float64[N]:
        ζσ = soft_clip(φ · w + T b) for a last layer (w, b) (``zeta_of``)."""
        self.eval()
        seg = data.segment_ids()
        out = np.zeros((self.num_attributes, len(data), self.f[-1].in_features))
        for a in range(self.num_attributes):
            for lo in range(0, len(data.states), batch_states):
                s = data.states[lo:lo + batch_states]
                h = self.f[:-1](torch.cat([self.norm(s), self.attr_embed[a].expand(len(s), -1)], 1))
                out[a] += segment_sum(h.T, seg[lo:lo + batch_states], len(data)).T.double().numpy()
        return out, data.lengths.double().numpy()

    def zeta_of(self, features: np.ndarray, lengths: np.ndarray, weight: np.ndarray, bias: np.ndarray
                ) -> np.ndarray:
        """ζσ, float64[N, k], of trajectories given their ``summed_features``, under last layers (weight, bias)."""
        raw = np.einsum("knh,kh->nk", features, weight) + lengths[:, None] * bias[None, :]
        return self.clip * np.tanh(raw / self.clip)

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


def train_ranker(data: Ragged, labels: list[AttributeLabels], attr_embed: np.ndarray, cfg: RankerConfig,
                 progress: Progress | None = None, curve: CurveOf | None = None) -> tuple[AttributeRanker, dict]:
    """Fit ζσ on ``labels`` (one entry per row of ``attr_embed``); returns the model and stats (``curve``: where
    its training curve goes).

    Each step scores a batch of each attribute's labelled clips and takes the loss over every
    labelled pair in the batch: the same compute as a few pairs, many times the signal.
    """
    if len(labels) != len(attr_embed):
        raise ValueError(f"{len(labels)} label sets for {len(attr_embed)} attributes")
    if empty := [a for a, lab in enumerate(labels) if lab.num_pairs == 0]:
        raise ValueError(f"attributes {empty} have no labelled pairs")
    gen = seed_everything(cfg.seed)
    torch.set_num_threads(LibrarySettings().train_threads)
    model = AttributeRanker(data.states.shape[1], torch.as_tensor(attr_embed), cfg.hidden, cfg.layers, cfg.clip)
    used = torch.as_tensor(np.unique(np.concatenate([lab.clips for lab in labels])))
    model.norm.fit(data.select(used)[0].numpy())
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    loop = StepLoop(opt, cfg.steps, progress, torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(cfg.steps, 1)),
                    curve=curve(model) if curve else None)
    clips = [torch.as_tensor(lab.clips) for lab in labels]
    more = [torch.as_tensor(lab.more) for lab in labels]
    for step in range(cfg.steps):
        losses = []
        for a in range(len(labels)):
            batch = torch.randperm(len(clips[a]), generator=gen)[: cfg.batch_clips]
            pairs = more[a][batch][:, batch]
            if not pairs.any():
                continue
            states, seg = data.select(clips[a][batch])
            scores = model.trajectory_scores(states, seg, len(batch), a)
            losses.append(bradley_terry_loss(scores[:, None], scores[None, :], torch.ones(int(pairs.sum())),
                                             mask=pairs))
        if losses:
            loop.step(step, sum(losses) / len(losses))
    model.eval()
    stats = {"labelled_clips": len(used), "labelled_pairs": [lab.num_pairs for lab in labels]}
    return model, {**stats, "final_loss": round(loop.loss, 5), "config": asdict(cfg)}


def ranking_metrics(zeta: np.ndarray, proxies: np.ndarray, attribute_names) -> dict[str, dict[str, float]]:
    """Per attribute: pairwise ordering accuracy and Kendall τ between ζσ and the proxy (``scipy.stats`` is
    imported here: it takes a second, and a server loads this module before it answers)."""
    from scipy.stats import kendalltau

    out = {}
    for a, name in enumerate(attribute_names):
        z, p = zeta[:, a], proxies[:, a]
        dz, dp = np.sign(z[:, None] - z[None, :]), np.sign(p[:, None] - p[None, :])
        mask = dp != 0
        acc = float((dz[mask] == dp[mask]).mean())
        out[name] = {"pairwise_accuracy": round(acc, 4), "kendall_tau": round(float(kendalltau(z, p).statistic), 4)}
    return out
