"""PbRL baseline agent: A/B preference queries over ``serve``; shows the argmax of the learned reward.

Protocol (paper §5.1, made a strong baseline as the paper does): the agent shows the serve
rollout with the highest ensemble-mean return; between shows it asks one A/B question
(``query_pair``), chosen by ensemble disagreement among the current best candidates. Each
answer (``update(Preference(...))``) warm-starts a few gradient steps of the Bradley-Terry
loss on every label so far, then the argmax is shown again. Feedback is counted in binary
labels.

The agent's state is JSON: the labels, the pending pair, and the ensemble weights as one
base64 string, so a restored agent continues with identical queries. Each update draws its
minibatches from a generator seeded by (seed, number of labels), not from a saved RNG state.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from rba.core.methods import Method
from rba.data.library import SkillLibrary
from rba.interact.base import Agent, Feedback
from rba.learn.common import Normalizer, Ragged, torch_threads
from rba.learn.embed import check_rep
from rba.learn.pbrl import PbRLConfig, RewardEnsemble, choose_pair, fit_preferences, returns


@dataclass
class PbRLContext:
    """The serve library with normalised (and strided) states precomputed; no trained model needed."""

    domain: str
    rep: str
    attribute_names: tuple[str, ...]
    serve: SkillLibrary
    states: torch.Tensor  # float32[S, D]: normalised serve states, every ``cfg.state_stride``-th
    offsets: torch.Tensor  # int64[N + 1]
    seg: torch.Tensor  # int64[S]
    cfg: PbRLConfig
    model_version: str = "online"

    @classmethod
    def load(cls, domain: str, rep: str = "onehot", data_root=None, models_root=None,
             cfg: PbRLConfig | None = None) -> PbRLContext:
        check_rep(rep)  # PbRL has no attribute representation; accepted for a uniform interface
        serve = SkillLibrary.load(domain, "serve", data_root)
        return cls.from_library(serve, rep, cfg or PbRLConfig())

    @classmethod
    def from_library(cls, serve: SkillLibrary, rep: str, cfg: PbRLConfig) -> PbRLContext:
        states, offsets = stride_states(serve.states, serve.state_offsets, cfg.state_stride)
        norm = Normalizer(states.shape[1]).fit(states)
        with torch.no_grad():
            x = norm(torch.as_tensor(states))
        data = Ragged(x, torch.as_tensor(offsets))
        return cls(serve.domain, rep, serve.attribute_names, serve, x, data.offsets, data.segment_ids(), cfg)

    def with_config(self, **changes) -> PbRLContext:
        """The same precomputed library under other options (for ablations); the stride must not change."""
        cfg = replace(self.cfg, **changes)
        if cfg.state_stride != self.cfg.state_stride:
            return PbRLContext.from_library(self.serve, self.rep, cfg)
        return replace(self, cfg=cfg)


def stride_states(states: np.ndarray, offsets: np.ndarray, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Keep every ``stride``-th state of each trajectory (its first state always)."""
    if stride == 1:
        return states, offsets
    lengths = np.diff(offsets)
    starts = np.repeat(offsets[:-1], lengths)
    keep = (np.arange(len(states)) - starts) % stride == 0
    new_len = (lengths + stride - 1) // stride
    return states[keep], np.concatenate([[0], np.cumsum(new_len)]).astype(np.int64)


class PbRLAgent(Agent):
    method = "pbrl"
    feedback_kind = "preference"  # A/B questions instead of attribute feedback

    def __init__(self, ctx: PbRLContext, weights: str | None = None, labels: list[list[float]] | None = None,
                 shown: int | None = None, pending: list[int] | None = None) -> None:
        self.ctx = ctx
        cfg = ctx.cfg
        self.model = RewardEnsemble(ctx.states.shape[1], cfg.members, cfg.hidden, cfg.layers,
                                    generator=torch.Generator().manual_seed(cfg.seed))
        if weights is not None:
            self.model.load_base64(weights)
        self.labels = [list(row) for row in labels or []]
        self.shown = shown
        self.pending = list(pending) if pending else None
        self._returns: np.ndarray | None = None

    # -- the learned reward over the library --------------------------------------------
    def _library_returns(self) -> np.ndarray:
        if self._returns is None:
            with torch.no_grad(), torch_threads(self.ctx.cfg.threads):
                self._returns = returns(self.model, self.ctx.states, self.ctx.seg, len(self.ctx.serve)).double().numpy()
        return self._returns

    def _argmax(self) -> int:
        return int(np.argmax(self._library_returns().mean(0)))

    # -- the Agent contract ------------------------------------------------------------
    def first_query(self) -> str:
        self.shown = self._argmax()
        return self.ctx.serve.ids[self.shown]

    def query_pair(self) -> tuple[str, str]:
        """The A/B question to ask next (the same one until it is answered)."""
        if self.pending is None:
            asked = {(int(a), int(b)) for a, b, _ in self.labels}
            rng = np.random.default_rng([self.ctx.cfg.seed, len(self.labels)])
            self.pending = list(choose_pair(self._library_returns(), self.ctx.cfg, asked, rng))
        a, b = self.pending
        return self.ctx.serve.ids[a], self.ctx.serve.ids[b]

    def update(self, feedback: Feedback) -> str:
        """Take the answer to the pending A/B question (``Preference``), retrain, show the new argmax."""
        if self._is_satisfied(feedback, self.ctx.attribute_names):
            return self.ctx.serve.ids[self.shown]
        if self.pending is None:
            raise ValueError("no A/B question is pending; call query_pair() first")
        a, b = self.pending
        ids = self.ctx.serve.ids
        if feedback.preferred is None:
            label = 0.5
        elif feedback.preferred in (ids[a], ids[b]):
            label = 1.0 if feedback.preferred == ids[a] else 0.0
        else:
            raise ValueError(f"preferred rollout {feedback.preferred!r} is not in the pending pair "
                             f"({ids[a]}, {ids[b]})")
        self.labels.append([a, b, label])
        self.pending = None
        gen = torch.Generator().manual_seed(self.ctx.cfg.seed * 1_000_003 + len(self.labels))
        fit_preferences(self.model, self.ctx.states, self.ctx.offsets, np.array(self.labels, dtype=np.float64),
                        self.ctx.cfg, gen)
        self._returns = None
        self.shown = self._argmax()
        return ids[self.shown]

    def state_dict(self) -> dict:
        return {"method": self.method, "weights": self.model.to_base64(), "labels": [list(r) for r in self.labels],
                "shown": self.shown, "pending": self.pending}

    @classmethod
    def from_state(cls, state: dict, context: PbRLContext) -> PbRLAgent:
        return cls(context, state["weights"], state["labels"], state["shown"], state["pending"])


# PbRL learns its reward online, from the A/B answers: no model files, nothing to train beforehand,
# no attribute representation.
METHOD = Method(agent=PbRLAgent, label="PbRL", load_context=PbRLContext.load, model_kinds=(), trainer=None,
                presets=(), reps=(), description="Asks which of two clips you prefer and learns a reward from "
                "those choices (a baseline).")
