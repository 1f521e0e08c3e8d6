"""RBA-Global step 2: the target-conditioned reward rθ([s, v_t]) (paper §4.2, eq. 4).

Trained as a state-only Bradley-Terry reward on triplets (τ0, τ1, τ2): with v_t near
v(τ0), τ1 ≻ τ2 when ‖v(τ1) − v_t‖ < ‖v(τ2) − v_t‖ − ξ. Labels come from ζσ only (no
proxies). Departures from the paper, both measured to help the argmax land near v_t:
targets are also drawn uniformly from the box the binary search explores, and half the
compared trajectories are the target's near neighbours (hard pairs).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

from rba.learn.common import Normalizer, Ragged, bradley_terry_loss, check_shape, mlp, seed_everything, segment_sum

log = logging.getLogger(__name__)


@dataclass
class GlobalRewardConfig:
    """Options of rθ training."""

    hidden: int = 256  # MLP width
    layers: int = 3
    steps: int = 2000  # gradient steps
    batch_triplets: int = 128
    slack: float = 0.05  # ξ_r, in standardised ζ units
    target_noise: float = 0.1  # std of the jitter added to v(τ0), standardised units
    uniform_targets: float = 0.5  # fraction of targets drawn uniformly from the ζ box
    hard_fraction: float = 0.5  # fraction of compared trajectories drawn among the target's neighbours
    neighbours: int = 24
    lr: float = 1e-3
    weight_decay: float = 1e-5
    seed: int = 0


class GlobalReward(nn.Module):
    """rθ([s, v]) with v = standardised ζ target vector (k values)."""

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

    def library_scorer(self, data: Ragged) -> LibraryScorer:
        return LibraryScorer(self, data)


class LibraryScorer:
    """Σ_t rθ(s_t | v) for every trajectory of a library, fast for repeated queries.

    The first layer splits into W_s·s + W_v·v; W_s·s is computed once for all states, so a
    query costs the remaining layers only.
    """

    def __init__(self, model: GlobalReward, data: Ragged, chunk: int = 32768) -> None:
        self.model = model.eval()
        self.seg = data.segment_ids()
        self.n = len(data)
        first: nn.Linear = model.f[0]
        d = model.state_dim
        with torch.no_grad():
            self.w_v = first.weight[:, d:].clone()
            self.bias = first.bias.clone()
            self.pre = torch.cat([model.norm(data.states[i:i + chunk]) @ first.weight[:, :d].T
                                  for i in range(0, len(data.states), chunk)])
        self.rest = model.f[1:]

    @torch.no_grad()
    def returns(self, zeta_target: np.ndarray) -> np.ndarray:
        """float64[N]: the return of every trajectory under rθ(·|v_t = standardised ζ target)."""
        v = self.model.zeta_norm(torch.as_tensor(np.asarray(zeta_target), dtype=torch.float32))
        h = self.pre + (self.w_v @ v + self.bias)
        r = self.rest(h).squeeze(1)
        return segment_sum(r, self.seg, self.n).double().numpy()

    def argmax(self, zeta_target: np.ndarray, exclude: np.ndarray | None = None) -> int:
        ret = self.returns(zeta_target)
        if exclude is not None and exclude.any() and not exclude.all():
            ret[exclude] = -np.inf
        return int(np.argmax(ret))


def train_global_reward(data: Ragged, zeta: np.ndarray, cfg: GlobalRewardConfig,
                        progress=None) -> tuple[GlobalReward, dict]:
    """Fit rθ on trajectories ``data`` whose ζσ scores are ``zeta`` (float[N, k])."""
    gen = seed_everything(cfg.seed)
    torch.set_num_threads(2)
    n, k = zeta.shape
    model = GlobalReward(data.states.shape[1], k, cfg.hidden, cfg.layers)
    model.norm.fit(data.states.numpy())
    model.zeta_norm.fit(zeta)
    v_all = model.zeta_norm(torch.as_tensor(zeta, dtype=torch.float32))
    lo, hi = v_all.min(0).values, v_all.max(0).values
    # neighbours in standardised ζ space, for hard pairs
    dist = torch.cdist(v_all, v_all)
    nbrs = dist.topk(min(cfg.neighbours + 1, n), largest=False).indices[:, 1:]
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    b = cfg.batch_triplets
    loss_val = float("nan")
    for step in range(cfg.steps):
        t0 = torch.randint(n, (b,), generator=gen)
        vt = v_all[t0] + cfg.target_noise * torch.randn(b, k, generator=gen)
        uniform = torch.rand(b, generator=gen) < cfg.uniform_targets
        vt[uniform] = lo + (hi - lo) * torch.rand(int(uniform.sum()), k, generator=gen)
        # nearest library trajectory to each target anchors the hard pairs
        anchor = torch.cdist(vt, v_all).argmin(1)
        pair = torch.randint(n, (b, 2), generator=gen)
        hard = torch.rand(b, 2, generator=gen) < cfg.hard_fraction
        near = nbrs[anchor.unsqueeze(1).expand(b, 2), torch.randint(nbrs.shape[1], (b, 2), generator=gen)]
        pair = torch.where(hard, near, pair)
        d = (v_all[pair] - vt.unsqueeze(1)).norm(dim=2)
        pref = torch.full((b,), 0.5)
        pref[d[:, 0] < d[:, 1] - cfg.slack] = 1.0
        pref[d[:, 0] > d[:, 1] + cfg.slack] = 0.0
        keep = (pref != 0.5) & (pair[:, 0] != pair[:, 1])
        pair, vt, pref = pair[keep], vt[keep], pref[keep]
        m = len(pair)
        states, seg = data.select(torch.cat([pair[:, 0], pair[:, 1]]))
        v_rows = torch.cat([vt, vt])[seg]
        returns = segment_sum(model(states, v_rows), seg, 2 * m)
        loss = bradley_terry_loss(returns[:m], returns[m:], pref)
        opt.zero_grad()
        loss.backward()
        opt.step()
        loss_val = loss.item()
        if progress and (step % 50 == 0 or step == cfg.steps - 1):
            progress(step + 1, cfg.steps, loss_val)
    model.eval()
    return model, {"trajectories": n, "final_loss": round(loss_val, 5), "config": asdict(cfg)}
