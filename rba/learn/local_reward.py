"""RBA-Local: the behaviour-editing reward rθ([s, e_α, h, φ(τ_c)]) (paper §4.3, eq. 5).

φ is a bidirectional LSTM over the anchor τ_c's states, trained jointly with the per-state
MLP by the Bradley-Terry loss: the labelled minimal change τ_t must out-score negatives.
Negatives are random ``train`` rollouts (the paper's choice) plus, label-free, the anchor
itself (the "no change" failure mode). Each labelled pair is also used backwards
(τ_c is a minimal change of τ_t the other way), which doubles the data without new labels.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn
from torch.nn.utils.rnn import pack_padded_sequence

from rba.data.labels import LocalPairs
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
    torch_threads,
)


@dataclass
class LocalRewardConfig:
    """Options of rθ (RBA-Local) training; the architecture fields are saved in the model card."""

    hidden: int = 128  # MLP width (paper: 512, 1024 with language); see the walker benchmark for 128 vs 512
    layers: int = 3  # fully connected layers
    lstm_hidden: int = 128  # anchor encoder width per direction (paper: 128)
    lstm_layers: int = 2  # stacked bidirectional LSTM layers (paper: 2)
    anchor_stride: int = 2  # the encoder reads every n-th anchor state (halves LSTM time; attributes are slow)
    steps: int = 1500  # gradient steps
    batch_pairs: int = 32  # labelled pairs per step
    negatives: int = 8  # random train negatives per pair
    anchor_negative: bool = True  # the anchor itself is a negative ("no change" must lose)
    reverse_pairs: bool = True  # also train on each pair read backwards (no extra labels)
    near_copy: float = 0.25  # near-copy radius in φ space, as a fraction of the median labelled-pair distance
    lr: float = 1e-3
    weight_decay: float = 1e-4
    threads: int = 1  # torch threads while training (measured: one is fastest for these batch sizes on 2 cores)
    seed: int = 0


class AnchorEncoder(nn.Module):
    """φ(τ): the final hidden states of both directions of the top LSTM layer, concatenated."""

    def __init__(self, state_dim: int, hidden: int = 128, layers: int = 2) -> None:
        super().__init__()
        self.lstm = nn.LSTM(state_dim, hidden, layers, batch_first=True, bidirectional=True)
        self.out_dim = 2 * hidden

    def forward(self, padded: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        packed = pack_padded_sequence(padded, lengths.cpu(), batch_first=True, enforce_sorted=False)
        _, (h, _) = self.lstm(packed)
        return torch.cat([h[-2], h[-1]], 1)


class LocalReward(nn.Module):
    """rθ([s, e_α, h, φ(τ_c)]): per-state reward; a trajectory's return is the sum over its states."""

    def __init__(self, state_dim: int, attr_embed: torch.Tensor, hidden: int = 128, layers: int = 3,
                 lstm_hidden: int = 128, lstm_layers: int = 2, anchor_stride: int = 2) -> None:
        super().__init__()
        self.state_dim = state_dim
        self.anchor_stride = anchor_stride
        self.register_buffer("attr_embed", torch.as_tensor(attr_embed, dtype=torch.float32))
        self.norm = Normalizer(state_dim)
        self.encoder = AnchorEncoder(state_dim, lstm_hidden, lstm_layers)
        self.cond_dim = self.attr_embed.shape[1] + 1 + self.encoder.out_dim
        self.f = mlp(state_dim + self.cond_dim, hidden, layers)

    @property
    def num_attributes(self) -> int:
        return self.attr_embed.shape[0]

    def encode(self, data: Ragged, idx: torch.Tensor) -> torch.Tensor:
        """φ of trajectories ``idx``: float32[len(idx), 2·lstm_hidden]."""
        states, seg = data.select(idx)
        lengths = data.lengths[idx]
        starts = torch.repeat_interleave(torch.cumsum(lengths, 0) - lengths, lengths)
        pos = torch.arange(len(seg)) - starts
        keep = pos % self.anchor_stride == 0
        states, seg, pos = states[keep], seg[keep], pos[keep] // self.anchor_stride
        new_len = (lengths + self.anchor_stride - 1) // self.anchor_stride
        padded = states.new_zeros(len(idx), int(new_len.max()), self.state_dim)
        padded[seg, pos] = self.norm(states)
        return self.encoder(padded, new_len)

    @torch.no_grad()
    def encode_all(self, data: Ragged, batch: int = 256) -> torch.Tensor:
        self.eval()
        return torch.cat([self.encode(data, torch.arange(i, min(i + batch, len(data))))
                          for i in range(0, len(data), batch)])

    def condition(self, phi: torch.Tensor, attr: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
        """[e_α, h, φ(τ_c)] per query: float32[B, cond_dim]."""
        check_shape(phi, None, self.encoder.out_dim, name="anchor embedding")
        if int(attr.min()) < 0 or int(attr.max()) >= self.num_attributes:
            raise ValueError(f"attribute index out of range [0, {self.num_attributes})")
        return torch.cat([self.attr_embed[attr], direction.float().unsqueeze(1), phi], 1)

    def forward(self, states: torch.Tensor, cond: torch.Tensor, query: torch.Tensor | None = None) -> torch.Tensor:
        """Per-state reward float32[N] for states float32[N, D] under query conditions float32[B, C].

        State i is scored under condition ``query[i]`` (default: row i, so B = N). The first
        layer is applied to the state and the condition separately (W·[s, c] = W_s·s + W_c·c),
        so the long condition vector is multiplied once per query, not once per state.
        """
        check_shape(states, None, self.state_dim, name="states")
        check_shape(cond, len(states) if query is None else None, self.cond_dim, name="conditions")
        first: nn.Linear = self.f[0]
        d = self.state_dim
        shift = cond @ first.weight[:, d:].T + first.bias
        h = self.norm(states) @ first.weight[:, :d].T + (shift if query is None else shift[query])
        return self.f[1:](h).squeeze(1)


class LocalLibraryScorer:
    """Σ_t rθ(s_t | α, h, φ(anchor)) for every trajectory of a library, fast for repeated queries.

    The first layer splits into W_s·s + W_c·[e_α, h, φ]; W_s·s is computed once for all states
    and φ once for every library trajectory (every anchor the agent uses is a library rollout),
    so a query costs one matrix-vector product plus the remaining layers.
    """

    def __init__(self, model: LocalReward, data: Ragged, chunk: int = 32768) -> None:
        self.model = model.eval()
        self.seg = data.segment_ids()
        self.n = len(data)
        self.chunk = chunk
        first: nn.Linear = model.f[0]
        d = model.state_dim
        with torch.no_grad():
            self.w_c = first.weight[:, d:].clone()
            self.bias = first.bias.clone()
            self.pre = torch.cat([model.norm(data.states[i:i + chunk]) @ first.weight[:, :d].T
                                  for i in range(0, len(data.states), chunk)])
        self.rest = model.f[1:]
        self.phi = model.encode_all(data)

    @torch.no_grad()
    def returns(self, phi: torch.Tensor, attr: int, direction: int) -> np.ndarray:
        """float64[N]: every trajectory's return for the edit (attr, direction) of the anchor with embedding φ."""
        cond = self.model.condition(phi.reshape(1, -1), torch.tensor([attr]), torch.tensor([direction]))[0]
        shift = self.w_c @ cond + self.bias
        r = torch.cat([self.rest(self.pre[i:i + self.chunk] + shift).squeeze(1)
                       for i in range(0, len(self.pre), self.chunk)])
        return segment_sum(r, self.seg, self.n).double().numpy()

    def phi_distances(self, phi: torch.Tensor) -> np.ndarray:
        """float64[N]: distance in φ space from ``phi`` to every library trajectory."""
        return (self.phi - phi.reshape(1, -1)).norm(dim=1).double().numpy()


def training_pool(pairs: LocalPairs, reverse: bool) -> LocalPairs:
    return pairs.concat(pairs.reversed()) if reverse else pairs


def train_local_reward(data: Ragged, pairs: LocalPairs, attr_embed: np.ndarray, cfg: LocalRewardConfig,
                       progress: Progress | None = None, curve: CurveOf | None = None) -> tuple[LocalReward, dict]:
    """Fit rθ on labelled pairs of ``data`` rows, with negatives drawn from all of ``data`` (``curve``: where its
    training curve goes)."""
    if len(pairs) == 0:
        raise ValueError("no local-change pairs to train on; widen the change band or label more clips")
    with torch_threads(cfg.threads):
        return _train(data, pairs, attr_embed, cfg, progress, curve)


def _train(data: Ragged, pairs: LocalPairs, attr_embed: np.ndarray, cfg: LocalRewardConfig,
           progress: Progress | None, curve: CurveOf | None) -> tuple[LocalReward, dict]:
    gen = seed_everything(cfg.seed)
    pool = training_pool(pairs, cfg.reverse_pairs)
    model = LocalReward(data.states.shape[1], torch.as_tensor(attr_embed), cfg.hidden, cfg.layers,
                        cfg.lstm_hidden, cfg.lstm_layers, cfg.anchor_stride)
    model.norm.fit(data.states.numpy())
    loop = StepLoop(torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay), cfg.steps,
                    progress, curve=curve(model) if curve else None)
    labelled = tuple(torch.as_tensor(x) for x in (pool.anchor, pool.target, pool.attr, pool.direction))
    model.train()
    for step in range(cfg.steps):
        loop.step(step, _batch_loss(model, data, labelled, cfg, gen))
    model.eval()
    with torch.no_grad():
        phi = model.encode_all(data)
        pair_dist = (phi[torch.as_tensor(pairs.anchor)] - phi[torch.as_tensor(pairs.target)]).norm(dim=1)
    near_copy = float(cfg.near_copy * pair_dist.median())
    return model, {"labelled_pairs": len(pairs), "training_pairs": len(pool), "final_loss": round(loop.loss, 5),
                   "near_copy_radius": near_copy, "config": asdict(cfg)}


def _batch_loss(model: LocalReward, data: Ragged, labelled: tuple[torch.Tensor, ...], cfg: LocalRewardConfig,
                gen: torch.Generator) -> torch.Tensor:
    """Bradley-Terry of a batch of pairs: each labelled target must out-score its pair's negatives.

    ``labelled`` is the training pool as tensors (anchor, target, attr, direction).
    """
    anchor, target, attr, direction = labelled
    b = cfg.batch_pairs
    rows = torch.randint(len(anchor), (b,), generator=gen)
    c, t = anchor[rows], target[rows]
    cols = [t.unsqueeze(1), torch.randint(len(data), (b, cfg.negatives), generator=gen)]
    if cfg.anchor_negative:
        cols.append(c.unsqueeze(1))
    traj = torch.cat(cols, 1)  # [b, C]: the target first, then negatives
    width = traj.shape[1]
    cond = model.condition(model.encode(data, c), attr[rows], direction[rows])
    states, seg = data.select(traj.reshape(-1))
    returns = segment_sum(model(states, cond, seg // width), seg, b * width).view(b, width)
    return bradley_terry_loss(returns[:, :1], returns[:, 1:], mask=traj[:, 1:] != t.unsqueeze(1))


def pair_metrics(scorer: LocalLibraryScorer, pairs: LocalPairs) -> dict[str, float]:
    """Held-out ranking quality on pairs whose anchors, targets and negatives all come from one library.

    ``target_vs_negative``: fraction of (pair, negative) with R(τ_t) > R(τ_n), every other library
    rollout being a negative (the paper's binary-classification accuracy). ``target_vs_anchor``:
    fraction of pairs where the edit beats "no change".
    """
    above, vs_anchor = [], []
    for c, t, a, h in zip(pairs.anchor, pairs.target, pairs.attr, pairs.direction, strict=True):
        ret = scorer.returns(scorer.phi[c], int(a), int(h))
        neg = np.ones(scorer.n, dtype=bool)
        neg[[c, t]] = False
        above.append(float(np.mean(ret[t] > ret[neg])))
        vs_anchor.append(float(ret[t] > ret[c]))
    return {"pairs": len(pairs), "target_vs_negative": round(float(np.mean(above)), 4),
            "target_vs_anchor": round(float(np.mean(vs_anchor)), 4)}


def edit_metrics(scorer: LocalLibraryScorer, anchor_phi: torch.Tensor, anchor_proxies: np.ndarray,
                 candidate_proxies: np.ndarray, pairs: LocalPairs, epsilons: np.ndarray,
                 near_copy_radius: float) -> dict[str, float]:
    """What the agent would do: argmax over the scorer's library for each pair's (anchor, α, h).

    A *useful edit* moves α the asked way by more than 0 and at most 2ε and every other attribute
    by at most ε (so it can never overshoot a target the user asked to move toward). A *no-change*
    edit (the paper's failure mode) moves α by less than ε/4 either way.
    """
    useful, step, other, still = [], [], [], []
    for i, (a, h) in enumerate(zip(pairs.attr, pairs.direction, strict=True)):
        ret = scorer.returns(anchor_phi[i], int(a), int(h))
        ret[scorer.phi_distances(anchor_phi[i]) < near_copy_radius] = -np.inf
        j = int(np.argmax(ret))
        delta = (candidate_proxies[j] - anchor_proxies[i]) / epsilons
        moved = h * delta[a]
        rest = np.delete(np.abs(delta), a)
        useful.append(bool(0 < moved <= 2 and np.all(rest <= 1)))
        still.append(abs(moved) < 0.25)
        step.append(moved)
        other.append(float(rest.max()) if len(rest) else 0.0)
    return {"queries": len(pairs), "useful_edit_rate": round(float(np.mean(useful)), 4),
            "no_change_rate": round(float(np.mean(still)), 4),
            "mean_step_epsilons": round(float(np.mean(step)), 3),
            "mean_other_change_epsilons": round(float(np.mean(other)), 3)}
