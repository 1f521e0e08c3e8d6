"""PbRL baseline (Christiano et al. 2017; PEBBLE): a Bradley-Terry reward on states from A/B labels.

An ensemble of small MLPs r_m(s); a trajectory's return is Σ_t r_m(s_t). The members are stored
as stacked weight tensors so that the whole ensemble scores a library in a few batched matrix
products, and they (de)serialise to one base64 string so that an agent's state stays JSON.
"""

from __future__ import annotations

import base64
import itertools
import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from rba.learn.common import Ragged, StepLoop, bradley_terry_loss, check_shape, segment_sum, torch_threads


@dataclass
class PbRLConfig:
    """Options of the online preference learner and its query rule (the best measured on the walker)."""

    members: int = 3  # ensemble size
    hidden: int = 64  # MLP width
    layers: int = 3  # fully connected layers
    state_stride: int = 2  # the reward reads every n-th state (the return sums those)
    steps_per_label: int = 10  # gradient steps after each new label (warm start)
    batch_pairs: int = 64  # labelled pairs per gradient step and member (all of them while fewer)
    lr: float = 3e-3
    weight_decay: float = 1e-4
    candidates: int = 8  # queries are pairs among this many best rollouts by ensemble-mean return (8 < 16 < 32)
    query: str = "disagreement"  # "disagreement" (max std of P[a ≻ b] across members) or "random"
    threads: int = 1  # torch threads during an update (one is fastest for these small products)
    seed: int = 0

    def __post_init__(self) -> None:
        if self.query not in ("disagreement", "random"):
            raise ValueError(f"unknown query rule {self.query!r}; valid: disagreement, random")


class RewardEnsemble(nn.Module):
    """``members`` independent MLPs on states, evaluated together with batched matrix products."""

    def __init__(self, state_dim: int, members: int = 3, hidden: int = 64, layers: int = 3,
                 generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.state_dim = state_dim
        dims = [state_dim] + [hidden] * (layers - 1) + [1]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for d_in, d_out in itertools.pairwise(dims):
            bound = 1 / math.sqrt(d_in)  # PyTorch's default nn.Linear init, but from our generator
            self.weights.append(nn.Parameter((torch.rand(members, d_in, d_out, generator=generator) * 2 - 1) * bound))
            self.biases.append(nn.Parameter((torch.rand(members, 1, d_out, generator=generator) * 2 - 1) * bound))

    @property
    def members(self) -> int:
        return self.weights[0].shape[0]

    def forward(self, states: torch.Tensor) -> torch.Tensor:
        """Per-state rewards float32[M, N] for (normalised) states float32[N, D]."""
        check_shape(states, None, self.state_dim, name="states")
        h = states.unsqueeze(0).expand(self.members, -1, -1)
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = torch.baddbmm(b, h, w)
            if i < last:
                h = F.relu(h)
        return h.squeeze(2)

    def to_base64(self) -> str:
        flat = torch.cat([p.detach().reshape(-1) for p in self.parameters()]).numpy().astype("<f4")
        return base64.b64encode(flat.tobytes()).decode("ascii")

    def load_base64(self, text: str) -> RewardEnsemble:
        flat = torch.from_numpy(np.frombuffer(base64.b64decode(text), dtype="<f4").copy())
        total = sum(p.numel() for p in self.parameters())
        if len(flat) != total:
            raise ValueError(f"ensemble weights have {len(flat)} values; this architecture needs {total}")
        with torch.no_grad():
            i = 0
            for p in self.parameters():
                p.copy_(flat[i:i + p.numel()].view_as(p))
                i += p.numel()
        return self


def returns(model: RewardEnsemble, states: torch.Tensor, seg: torch.Tensor, n: int,
            chunk: int = 65536) -> torch.Tensor:
    """Σ_t r_m(s_t) per member and trajectory: float32[M, n] (chunked over states)."""
    out = states.new_zeros(model.members, n)
    for i in range(0, len(states), chunk):
        out += segment_sum(model(states[i:i + chunk]), seg[i:i + chunk], n)
    return out


def fit_preferences(model: RewardEnsemble, states: torch.Tensor, offsets: torch.Tensor, labels: np.ndarray,
                    cfg: PbRLConfig, generator: torch.Generator) -> float:
    """A few warm-started gradient steps of the Bradley-Terry loss on all labels so far.

    ``labels`` is float[L, 3]: (index a, index b, P[a ≻ b] in {1, 0, 0.5}), indices into the
    trajectories described by ``offsets`` over ``states``. Each member draws its own minibatch
    (a bootstrap), which keeps the ensemble's disagreement informative. Returns the last loss.
    """
    if not len(labels):
        return float("nan")
    with torch_threads(cfg.threads):
        return _fit(model, Ragged(states, offsets), labels, cfg, generator)


def _fit(model: RewardEnsemble, data: Ragged, labels: np.ndarray, cfg: PbRLConfig, generator: torch.Generator
         ) -> float:
    a_idx = torch.as_tensor(labels[:, 0], dtype=torch.int64)
    b_idx = torch.as_tensor(labels[:, 1], dtype=torch.int64)
    pref = torch.as_tensor(labels[:, 2], dtype=torch.float32)
    # only the labelled trajectories matter: gather their states once
    used, inverse = torch.unique(torch.cat([a_idx, b_idx]), return_inverse=True)
    sub_states, sub_seg = data.select(used)
    ia, ib = inverse[: len(a_idx)], inverse[len(a_idx):]
    loop = StepLoop(torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay),
                    cfg.steps_per_label)
    m, n_lab = model.members, len(labels)
    for step in range(cfg.steps_per_label):
        ret = segment_sum(model(sub_states), sub_seg, len(used))  # [M, U]
        if n_lab <= cfg.batch_pairs:
            rows = torch.arange(n_lab).expand(m, -1)
        else:
            rows = torch.randint(n_lab, (m, cfg.batch_pairs), generator=generator)
        member = torch.arange(m).unsqueeze(1).expand_as(rows)
        loop.step(step, bradley_terry_loss(ret[member, ia[rows]], ret[member, ib[rows]], pref[rows]))
    return loop.loss


def choose_pair(ret: np.ndarray, cfg: PbRLConfig, asked: set[tuple[int, int]], rng: np.random.Generator
                ) -> tuple[int, int]:
    """The next A/B query among the ``cfg.candidates`` best rollouts by ensemble-mean return.

    "disagreement": the pair whose predicted preference P_m[a ≻ b] varies most across members
    (never a pair already asked). "random": a uniformly random unasked pair among them.
    """
    mean = ret.mean(0)
    top = np.argsort(-mean, kind="stable")[: max(cfg.candidates, 2)]
    i, j = np.triu_indices(len(top), 1)
    a, b = top[i], top[j]
    fresh = np.array([(int(x), int(y)) not in asked and (int(y), int(x)) not in asked for x, y in zip(a, b,
                                                                                                     strict=True)])
    if not fresh.any():  # every pair among the candidates was asked: widen to the whole library
        top = np.argsort(-mean, kind="stable")
        i, j = np.triu_indices(min(len(top), 4 * max(cfg.candidates, 2)), 1)
        a, b = top[i], top[j]
        fresh = np.array([(int(x), int(y)) not in asked and (int(y), int(x)) not in asked
                          for x, y in zip(a, b, strict=True)])
    a, b = a[fresh], b[fresh]
    if cfg.query == "random":
        k = int(rng.integers(len(a)))
        return int(a[k]), int(b[k])
    p = 1 / (1 + np.exp(-np.clip(ret[:, a] - ret[:, b], -30, 30)))  # [M, pairs]
    k = int(np.argmax(p.std(0)))
    return int(a[k]), int(b[k])
