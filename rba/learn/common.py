"""Pieces shared by every model: MLPs, ragged trajectory batches, the Bradley-Terry loss, the step loop."""

from __future__ import annotations

import random
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F


def seed_everything(seed: int) -> torch.Generator:
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)
    return torch.Generator().manual_seed(seed)


def mlp(in_dim: int, hidden: int, layers: int = 3, out_dim: int = 1) -> nn.Sequential:
    """``layers`` fully connected layers with ReLU between them (the paper's 3-layer MLP)."""
    mods: list[nn.Module] = []
    dim = in_dim
    for _ in range(layers - 1):
        mods += [nn.Linear(dim, hidden), nn.ReLU()]
        dim = hidden
    mods.append(nn.Linear(dim, out_dim))
    return nn.Sequential(*mods)


class Normalizer(nn.Module):
    """Fixed standardisation of states, fitted on training data and saved with the model."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("std", torch.ones(dim))

    def fit(self, x: np.ndarray) -> Normalizer:
        self.mean.copy_(torch.as_tensor(x.mean(0), dtype=torch.float32))
        self.std.copy_(torch.as_tensor(x.std(0) + 1e-6, dtype=torch.float32))
        return self

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.mean) / self.std


@dataclass
class Ragged:
    """Trajectories as one flat state tensor plus offsets; the fast layout for segment sums."""

    states: torch.Tensor  # float32[sum T, D]
    offsets: torch.Tensor  # int64[N + 1]

    @classmethod
    def from_numpy(cls, states: np.ndarray, offsets: np.ndarray) -> Ragged:
        return cls(torch.as_tensor(states, dtype=torch.float32), torch.as_tensor(offsets, dtype=torch.int64))

    @property
    def lengths(self) -> torch.Tensor:
        return self.offsets[1:] - self.offsets[:-1]

    def __len__(self) -> int:
        return len(self.offsets) - 1

    def segment_ids(self) -> torch.Tensor:
        return torch.repeat_interleave(torch.arange(len(self)), self.lengths)

    def select(self, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """States of trajectories ``idx`` (in order) and, per state, its position in ``idx``."""
        lengths = self.lengths[idx]
        starts = self.offsets[idx]
        seg = torch.repeat_interleave(torch.arange(len(idx)), lengths)
        first = torch.repeat_interleave(starts - torch.cumsum(lengths, 0) + lengths, lengths)
        rows = first + torch.arange(int(lengths.sum()))
        return self.states[rows], seg


def segment_sum(values: torch.Tensor, seg: torch.Tensor, n: int) -> torch.Tensor:
    """Sum ``values[..., i]`` into ``n`` buckets by ``seg[i]`` (last dim)."""
    out = values.new_zeros((*values.shape[:-1], n))
    return out.index_add_(-1, seg, values)


def bradley_terry_loss(return_a: torch.Tensor, return_b: torch.Tensor, pref_a: torch.Tensor | None = None,
                       weight: torch.Tensor | None = None, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean cross-entropy of P[a ≻ b] = σ(R_a − R_b) against labels ``pref_a`` (1 = a, 0 = b, 0.5 = tie).

    ``return_a − return_b`` may broadcast (every pair of a batch); ``mask`` then picks the labelled
    pairs, and ``weight`` weighs each picked pair. Without ``pref_a`` every pair prefers a: the loss
    is then written softplus(R_b − R_a), masked after, as RBA-Local was trained (equal in value to
    the cross-entropy form, not in float bits, and the shipped models' training is kept bit for bit).
    """
    margin = return_a - return_b
    if pref_a is None:
        if weight is not None:
            raise ValueError("weight needs pref_a")
        loss = F.softplus(-margin)
        return (loss if mask is None else loss[mask]).mean()
    return F.binary_cross_entropy_with_logits(margin if mask is None else margin[mask], pref_a, weight=weight)


@contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run a block with ``n`` torch threads: small updates are fastest on one (no sync cost)."""
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


Progress = Callable[[int, int, float], None]  # (step done, total steps, loss)


class Curve(Protocol):
    """Where a training run's curve goes (``rba.learn.curves.CurveWriter``): told every step's loss."""

    def record(self, step: int, total: int, loss: float) -> None: ...


CurveOf = Callable[[nn.Module], Curve]  # the model being fitted -> its curve (which measures it now and then)


class StepLoop:
    """The tail every training loop shares: one optimiser (and schedule) step per loss, progress reports, the
    training curve.

    ``loss`` is the last step's loss value (nan before the first), which trainers report as final.
    """

    def __init__(self, opt: torch.optim.Optimizer, steps: int, progress: Progress | None = None,
                 sched: torch.optim.lr_scheduler.LRScheduler | None = None, report_every: int = 50,
                 curve: Curve | None = None) -> None:
        self.opt, self.steps, self.progress, self.sched, self.report_every = opt, steps, progress, sched, report_every
        self.curve = curve
        self.loss = float("nan")

    def step(self, step: int, loss: torch.Tensor) -> None:
        """Back-propagate ``loss`` of step ``step`` (0-based), step the optimiser, report every so often."""
        self.opt.zero_grad()
        loss.backward()
        self.opt.step()
        if self.sched is not None:
            self.sched.step()
        self.loss = loss.item()
        if self.curve is not None:
            self.curve.record(step + 1, self.steps, self.loss)
        if self.progress and (step % self.report_every == 0 or step == self.steps - 1):
            self.progress(step + 1, self.steps, self.loss)


def check_shape(x: torch.Tensor, *shape: int | None, name: str = "input") -> None:
    """Raise a clear error when ``x`` does not have ``shape`` (None = any size)."""
    if x.dim() != len(shape) or any(s is not None and s != d for s, d in zip(shape, x.shape, strict=True)):
        want = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise ValueError(f"{name} has shape {list(x.shape)}; expected {want}")
