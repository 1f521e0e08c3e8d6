"""RBA-Global agent: binary search per attribute in ζσ space (paper appendix), query = argmax rθ.

State per attribute: a belief interval [lower, upper] for the user's target score and the
current target v_t. "More α" about a shown rollout with score z means the target lies
above z: lower ← z (and symmetrically for "less"); the new target is the interval's
midpoint. When feedback contradicts the interval (z beyond the other bound) the interval
extrapolates past z by a quarter of its initial width.

Guard against the paper's failure mode (rθ returns the same behaviour for a nudged
target): if the argmax is the rollout just shown, or does not move the asked attributes
the asked way, the target is pushed further in the asked direction (doubling the step)
until it does. Rollouts that already received non-satisfied feedback are not shown again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rba.artifacts import load_model
from rba.interact.base import SATISFIED, Agent, Feedback, validate_feedback
from rba.learn.common import Ragged
from rba.learn.global_reward import LibraryScorer
from rba.library import SkillLibrary

MAX_PUSHES = 8  # doublings of the push step before giving up on a move


@dataclass
class GlobalContext:
    """Loaded models and the serve library, shared by every global agent of a domain/rep."""

    domain: str
    rep: str
    attribute_names: tuple[str, ...]
    serve: SkillLibrary
    serve_zeta: np.ndarray  # float64[N, k]: ζσ of every serve rollout
    bounds: np.ndarray  # float64[2, k]: min / max ζσ over train
    scorer: LibraryScorer
    model_version: str

    @classmethod
    def load(cls, domain: str, rep: str, data_root=None, models_root=None) -> GlobalContext:
        ranker = load_model(domain, "ranker", rep, models_root)
        reward = load_model(domain, "global_reward", rep, models_root)
        serve = SkillLibrary.load(domain, "serve", data_root)
        data = Ragged.from_numpy(serve.states, serve.state_offsets)
        zeta = ranker.model.score(data)
        bounds = np.array(reward.card["zeta_bounds"], dtype=np.float64)
        version = f"{ranker.card['weights_sha']}-{reward.card['weights_sha']}"
        return cls(domain, rep, serve.attribute_names, serve, zeta, bounds,
                   LibraryScorer(reward.model, data), version)


class GlobalAgent(Agent):
    method = "global"

    def __init__(self, ctx: GlobalContext, lower=None, upper=None, target=None, shown: int | None = None,
                 rejected: list[int] | None = None) -> None:
        self.ctx = ctx
        self.lower = np.array(ctx.bounds[0] if lower is None else lower, dtype=np.float64)
        self.upper = np.array(ctx.bounds[1] if upper is None else upper, dtype=np.float64)
        self.target = (self.lower + self.upper) / 2 if target is None else np.array(target, dtype=np.float64)
        self.shown = shown
        self.rejected = list(rejected or [])

    @property
    def _width0(self) -> np.ndarray:
        return self.ctx.bounds[1] - self.ctx.bounds[0]

    def _argmax(self) -> int:
        exclude = np.zeros(len(self.ctx.serve), dtype=bool)
        exclude[self.rejected] = True
        return self.ctx.scorer.argmax(self.target, exclude)

    def first_query(self) -> str:
        self.shown = self._argmax()
        return self.ctx.serve.ids[self.shown]

    def update(self, feedback: Feedback) -> str:
        if self.shown is None:
            raise RuntimeError("update() before first_query()")
        validate_feedback(feedback, self.ctx.attribute_names)
        if feedback == SATISFIED:
            return self.ctx.serve.ids[self.shown]
        z = self.ctx.serve_zeta[self.shown]
        asked = [(self.ctx.attribute_names.index(fb.attribute), fb.direction) for fb in feedback]
        for a, h in asked:
            if h > 0:
                self.lower[a] = z[a]
                if self.upper[a] <= z[a]:
                    self.upper[a] = z[a] + self._width0[a] / 4
            else:
                self.upper[a] = z[a]
                if self.lower[a] >= z[a]:
                    self.lower[a] = z[a] - self._width0[a] / 4
            self.target[a] = (self.lower[a] + self.upper[a]) / 2
        self.rejected.append(self.shown)
        nxt = self._argmax()
        step = {a: (self.upper[a] - self.lower[a]) / 4 for a, _ in asked}
        for _ in range(MAX_PUSHES):
            moved = all(h * (self.ctx.serve_zeta[nxt, a] - z[a]) > 0 for a, h in asked)
            if moved:
                break
            for a, h in asked:
                self.target[a] += h * step[a]
                step[a] *= 2
            nxt = self._argmax()
        self.shown = nxt
        return self.ctx.serve.ids[nxt]

    def state_dict(self) -> dict:
        return {"method": self.method, "lower": self.lower.tolist(), "upper": self.upper.tolist(),
                "target": self.target.tolist(), "shown": self.shown, "rejected": list(self.rejected)}

    @classmethod
    def from_state(cls, state: dict, context: GlobalContext) -> GlobalAgent:
        return cls(context, state["lower"], state["upper"], state["target"], state["shown"], state["rejected"])
