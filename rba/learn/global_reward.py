"""RBA-Global step 2: the target-conditioned reward rθ([s, v_t]) (paper §4.2, eq. 4).

Trained as a state-only Bradley-Terry reward on triplets (τ0, τ1, τ2): with v_t near
v(τ0), τ1 ≻ τ2 when ‖v(τ1) − v_t‖ < ‖v(τ2) − v_t‖ − ξ. Labels come from ζσ only (no
proxies). Departures from the paper: targets are also drawn uniformly from the box the
search explores (its queries are rarely exactly some v(τ0)), each step compares every pair
of a trajectory batch under every target of a target batch (many triplets per pass), and
triplets are weighted by how close their nearer trajectory is to the target (``focus``):
the agent only ever uses the top of rθ's ranking, so that is where its accuracy matters
(walker, argmax over serve within ε of a test target: 0.83 unweighted, 0.93 with focus 0.3).
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

from rba.core.settings import LibrarySettings
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
class GlobalRewardConfig:
    """Options of rθ training."""

    hidden: int = 256  # MLP width
    layers: int = 3
    steps: int = 1000  # gradient steps (cosine-decayed learning rate)
    batch_trajectories: int = 48  # trajectories per step
    batch_targets: int = 16  # targets per step; every trajectory pair is compared for every target
    slack: float = 0.05  # ξ_r, in standardised ζ units
    target_noise: float = 0.1  # std of the jitter added to v(τ0), standardised units
    uniform_targets: float = 0.5  # fraction of targets drawn uniformly from the ζ box
    focus: float | None = 0.3  # triplet weight ∝ exp(−d(target, nearer)/focus), standardised ζ units; None: equal
    lr: float = 1e-3
    weight_decay: float = 1e-5
    seed: int = 0


class GlobalReward(nn.Module):
    """rθ([s, v]) with v = standardised ζ target vector (k values).

    The first layer splits into W_s·s + W_v·v, so many targets can share one pass over the
    states: ``state_features`` once, then ``rewards`` per target.
    """

    def __init__(self, state_dim: int, num_attributes: int, hidden: int = 256, layers: int = 3) -> None:
        super().__init__()
        self.state_dim, self.num_attributes = state_dim, num_attributes
        self.norm = Normalizer(state_dim)
        self.zeta_norm = Normalizer(num_attributes)  # ζ -> standardised v
        self.f = mlp(state_dim + num_attributes, hidden, layers)

    def forward(self, states: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Per-state reward float32[N] for states float32[N, D] and standardised targets float32[N, k]."""
        check_shape(states, None, self.state_dim, name="states")
        check_shape(v, len(states), self.num_attributes, name="targets")
        return self.f(torch.cat([self.norm(states), v], 1)).squeeze(1)

    def state_features(self, states: torch.Tensor) -> torch.Tensor:
        """W_s·norm(s): float32[N, hidden], the target-independent part of the first layer."""
        check_shape(states, None, self.state_dim, name="states")
        return self.norm(states) @ self.f[0].weight[:, : self.state_dim].T

    def rewards(self, features: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Per-state rewards float32[B, N] for ``state_features`` [N, H] and targets v [B, k]."""
        check_shape(v, None, self.num_attributes, name="targets")
        h = features.unsqueeze(0) + (v @ self.f[0].weight[:, self.state_dim:].T + self.f[0].bias).unsqueeze(1)
        return self.f[1:](h).squeeze(-1)


class LibraryScorer:
    """Σ_t rθ(s_t | v) for every trajectory of a library, fast for repeated queries.

    The state features of the whole library are computed once; a query costs the layers
    after the first only, over every trajectory or over a ``candidates`` subset of them.
    """

    def __init__(self, model: GlobalReward, data: Ragged, chunk: int = 32768) -> None:
        self.model = model.eval()
        self.seg = data.segment_ids()
        self.n = len(data)
        with torch.no_grad():
            features = torch.cat([model.state_features(data.states[i:i + chunk])
                                  for i in range(0, len(data.states), chunk)])
        self.features = Ragged(features, data.offsets)  # per-state first-layer features, same layout

    @torch.no_grad()
    def returns(self, zeta_target: np.ndarray, candidates: np.ndarray | None = None) -> np.ndarray:
        """float64[N]: every trajectory's return under rθ(·|v_t = standardised ζ target).

        With ``candidates`` (indices), only those are scored; the others get −inf.
        """
        v = self.model.zeta_norm(torch.as_tensor(np.asarray(zeta_target), dtype=torch.float32)).unsqueeze(0)
        if candidates is None:
            r = self.model.rewards(self.features.states, v)[0]
            return segment_sum(r, self.seg, self.n).double().numpy()
        idx = torch.as_tensor(np.asarray(candidates), dtype=torch.int64)
        feats, seg = self.features.select(idx)
        out = np.full(self.n, -np.inf)
        out[idx.numpy()] = segment_sum(self.model.rewards(feats, v)[0], seg, len(idx)).double().numpy()
        return out

    def argmax(self, zeta_target: np.ndarray, exclude: np.ndarray | None = None,
               candidates: np.ndarray | None = None) -> int:
        """The best trajectory for the target, skipping ``exclude`` (bool[N]) unless that excludes all."""
        ret = self.returns(zeta_target, candidates)
        if exclude is not None and exclude.any():
            kept = np.where(exclude, -np.inf, ret)
            if np.isfinite(kept).any():
                ret = kept
        return int(np.argmax(ret))


def focus_weights(nearer: torch.Tensor, focus: float | None) -> torch.Tensor | None:
    """Triplet weights ∝ exp(−nearer / focus), mean 1: close calls near the target count most."""
    if focus is None:
        return None
    if focus <= 0:
        raise ValueError(f"focus must be positive or None, got {focus}")
    weight = torch.exp(-nearer / focus)
    return weight / weight.mean()


def train_global_reward(data: Ragged, zeta: np.ndarray, cfg: GlobalRewardConfig,
                        progress: Progress | None = None, curve: CurveOf | None = None) -> tuple[GlobalReward, dict]:
    """Fit rθ on trajectories ``data`` whose ζσ scores are ``zeta`` (float[N, k]) (``curve``: where its training
    curve goes).

    Each step takes a batch of trajectories and a batch of targets and uses every
    (target, pair of trajectories) whose distances to the target differ by more than ξ.
    """
    gen = seed_everything(cfg.seed)
    torch.set_num_threads(LibrarySettings().train_threads)
    n, k = zeta.shape
    model = GlobalReward(data.states.shape[1], k, cfg.hidden, cfg.layers)
    model.norm.fit(data.states.numpy())
    model.zeta_norm.fit(zeta)
    v_all = model.zeta_norm(torch.as_tensor(zeta, dtype=torch.float32))
    box = v_all.min(0).values, v_all.max(0).values
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    loop = StepLoop(opt, cfg.steps, progress, torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(cfg.steps, 1)),
                    curve=curve(model) if curve else None)
    m = min(cfg.batch_trajectories, n)
    for step in range(cfg.steps):
        idx = torch.randperm(n, generator=gen)[:m]
        vt = _targets(v_all[idx[:cfg.batch_targets]], box, cfg, gen)
        states, seg = data.select(idx)
        returns = segment_sum(model.rewards(model.state_features(states), vt), seg, m)  # [B, M]
        loop.step(step, _triplet_loss(returns, torch.cdist(vt, v_all[idx]), cfg.slack, cfg.focus))
    model.eval()
    return model, {"trajectories": n, "final_loss": round(loop.loss, 5), "config": asdict(cfg)}


def _targets(near: torch.Tensor, box: tuple[torch.Tensor, torch.Tensor], cfg: GlobalRewardConfig,
             gen: torch.Generator) -> torch.Tensor:
    """A step's targets: near some of the batch's own trajectories (close calls) or anywhere in the ζ box."""
    (b, k), (lo, hi) = near.shape, box
    vt = near + cfg.target_noise * torch.randn(b, k, generator=gen)
    uniform = torch.rand(b, generator=gen) < cfg.uniform_targets
    vt[uniform] = lo + (hi - lo) * torch.rand(int(uniform.sum()), k, generator=gen)
    return vt


def _triplet_loss(returns: torch.Tensor, dist: torch.Tensor, slack: float, focus: float | None) -> torch.Tensor:
    """Bradley-Terry over every (target b, trajectories i < j) whose distances to b differ by more than ξ.

    ``returns`` and ``dist`` are [B, M]: each trajectory's return and distance under each target.
    """
    gap = dist[:, None, :] - dist[:, :, None]  # gap[b, i, j] = d_j − d_i > 0: i is closer
    mask = torch.triu(gap.abs() > slack, diagonal=1)
    weight = focus_weights(torch.minimum(dist[:, :, None], dist[:, None, :])[mask], focus)
    return bradley_terry_loss(returns[:, :, None], returns[:, None, :], (gap[mask] > 0).float(), weight, mask)


@dataclass
class RefitConfig:
    """Options of ``refit_for_target``: rθ's last layer re-fitted to rank the serve library for one v*."""

    nearest: int = 300  # trajectories nearest v* (standardised ζσ) whose pairs are ranked
    steps: int = 300  # full-batch Adam steps
    lr: float = 1e-2
    pull: float = 1e-2  # L2 weight pulling the layer back to the trained one (per unit of squared change)
    slack: float = 0.05  # ξ_r (GlobalRewardConfig's default)
    focus: float | None = 0.3  # GlobalRewardConfig's default


def refit_for_target(model: GlobalReward, data: Ragged, zeta: np.ndarray, zeta_target: np.ndarray,
                     cfg: RefitConfig | None = None) -> tuple[GlobalReward, dict]:
    """A copy of rθ whose last layer ranks the trajectories ``data`` (ζσ ``zeta``) for ``zeta_target`` alone.

    Why: an export's reward is only ever asked about one v*, and a search that sees nothing else climbs to
    rθ's top for it. Training spread rθ's accuracy over every target; near one target its top can hold
    behaviours farther in ζσ than the chosen one (``benchmarks/results/reward_only_*.md``). With v* fixed,
    each trajectory's return is linear in the last layer (Σ_t of the penultimate features), so re-fitting it
    with training's loss on the same ζσ labels, focused at v*, costs one forward pass and a few hundred small
    steps.
    """
    cfg = RefitConfig() if cfg is None else cfg
    if len(model.f) < 3:
        raise ValueError("a re-fit needs rθ with at least 2 layers (a last layer over penultimate features)")
    refit = copy.deepcopy(model).eval()
    last = refit.f[-1]
    with torch.no_grad():
        v = refit.zeta_norm(torch.as_tensor(np.asarray(zeta_target), dtype=torch.float32).reshape(1, -1))
        dist = torch.cdist(v, refit.zeta_norm(torch.as_tensor(zeta, dtype=torch.float32)))
        idx = torch.argsort(dist[0])[:cfg.nearest]
        states, seg = data.select(idx)
        # the first layer as in ``rewards``, its terms summed in another order: changing it moves the fitted bits,
        # and every reported reward-only count is of these
        first = refit.state_features(states) + v @ refit.f[0].weight[:, refit.state_dim:].T + refit.f[0].bias
        penultimate = refit.f[1:-1](first)
        phi = segment_sum(penultimate.T, seg, len(idx)).T  # [n, H]: Σ_t penultimate features
        steps_of = data.lengths[idx].float()  # [n]: each trajectory's length
    d = dist[:, idx]  # [1, n]: one target, as training's loss takes them
    info = {"trajectories": len(idx), "config": asdict(cfg)}
    if float(d.max() - d.min()) <= cfg.slack:  # no pair farther apart than the slack: nothing to rank by
        return refit, info
    w0, b0 = last.weight.detach().clone(), last.bias.detach().clone()
    w, b = w0.clone().requires_grad_(True), b0.clone().requires_grad_(True)
    opt = torch.optim.Adam([w, b], lr=cfg.lr)

    def loss_of() -> torch.Tensor:
        ret = (phi @ w[0] + steps_of * b[0]).unsqueeze(0)
        pull = (w - w0).pow(2).sum() + (b - b0).pow(2).sum()
        return _triplet_loss(ret, d, cfg.slack, cfg.focus) + cfg.pull * pull

    with torch.no_grad():
        before = float(loss_of())
    for _ in range(cfg.steps):
        opt.zero_grad()
        loss = loss_of()
        loss.backward()
        opt.step()
    with torch.no_grad():
        after = float(loss_of())
        last.weight.copy_(w)
        last.bias.copy_(b)
    return refit, {**info, "loss_before": round(before, 5), "loss_after": round(after, 5)}
