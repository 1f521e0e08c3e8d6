"""The tables' reference rows: a floor (random clips) and a ceiling (an oracle that knows every clip's proxies).

Neither is a method people use: their records are ``reference="floor"`` / ``"ceiling"``, so the web app
never offers them; ``rba eval`` and ``benchmarks/paper_tables.py`` run them beside the methods, with the same
simulated users, ε and success rule.

- **Random** ignores what the user says: it shows serve clips drawn at random (none that got feedback in
  the last ``REJECT_MEMORY`` rounds). Its generator is seeded by the answers so far, so its state is JSON
  and different targets see different clips.
- **Oracle** is the one agent that reads proxies: it knows the true proxies of every serve clip and runs
  probabilistic bisection (``rba.interact.bisection``) on them with the user's answers, per attribute; an
  attribute the user is silent about keeps the value it had in the clip just shown. It shows the clip
  nearest the estimate (attributes scaled by their robust range): the ceiling that the library allows to
  an agent that understands the answers perfectly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rba.core.methods import Method
from rba.data.library import SkillLibrary
from rba.interact.base import REJECT_MEMORY, Agent, AttributeFeedback, Feedback
from rba.interact.bisection import posterior, quantile
from rba.learn.embed import check_rep

RANDOM_SEED = 0
GRID = 401  # belief grid points per attribute
TAIL = 0.1  # the grid extends this fraction of the serve range beyond each end
ERROR_RATE = 0.1  # assumed probability that an answer is wrong (as RBA-Global's)


@dataclass
class ReferenceContext:
    """The serve library (the oracle also reads its proxies); nothing is trained."""

    domain: str
    rep: str
    attribute_names: tuple[str, ...]
    serve: SkillLibrary
    grids: np.ndarray  # float64[k, GRID]: oracle belief grids over each proxy's serve range
    scale: np.ndarray  # float64[k]: each proxy's 1st-99th percentile range over serve
    model_version: str = "reference"

    @classmethod
    def load(cls, domain: str, rep: str = "onehot", data_root=None, models_root=None) -> ReferenceContext:
        check_rep(rep)  # no attribute representation; accepted for a uniform interface
        return cls.from_library(SkillLibrary.load(domain, "serve", data_root), rep)

    @classmethod
    def from_library(cls, serve: SkillLibrary, rep: str = "onehot") -> ReferenceContext:
        p = serve.proxies.astype(np.float64)
        lo, hi = p.min(0), p.max(0)
        pad = TAIL * (hi - lo)
        grids = np.stack([np.linspace(a, b, GRID) for a, b in zip(lo - pad, hi + pad, strict=True)])
        q1, q99 = np.percentile(p, [1.0, 99.0], axis=0)
        return cls(serve.domain, rep, serve.attribute_names, serve, grids, np.maximum(q99 - q1, 1e-12))

    def excluded(self, rejected: list[int]) -> np.ndarray:
        """A mask of the rollouts not to show: those rejected in the last ``REJECT_MEMORY`` rounds."""
        out = np.zeros(len(self.serve), dtype=bool)
        out[rejected[-REJECT_MEMORY:]] = True
        return out

    def indices(self, feedback: list[AttributeFeedback]) -> list[tuple[int, int]]:
        return [(self.attribute_names.index(fb.attribute), fb.direction) for fb in feedback]


class RandomAgent(Agent):
    """The floor: random serve clips, whatever the user says."""

    method = "random"
    feedback_kind = "attribute"

    def __init__(self, ctx: ReferenceContext, shown: int | None = None, rejected: list[int] | None = None,
                 history: list[int] | None = None) -> None:
        self.ctx = ctx
        self.shown = shown
        self.rejected = list(rejected or [])
        self.history = list(history or [])  # one code per answer: 2 × attribute + (more), -1 between rounds

    def _draw(self) -> int:
        rng = np.random.default_rng([RANDOM_SEED, *(c + 1 for c in self.history)])
        allowed = np.flatnonzero(~self.ctx.excluded(self.rejected))
        return int(rng.choice(allowed)) if len(allowed) else int(rng.integers(len(self.ctx.serve)))

    def first_query(self) -> str:
        self.shown = self._draw()
        return self.ctx.serve.ids[self.shown]

    def update(self, feedback: Feedback) -> str:
        if self._is_satisfied(feedback, self.ctx.attribute_names):
            return self.ctx.serve.ids[self.shown]
        self.history += [2 * a + (h > 0) for a, h in self.ctx.indices(feedback)] + [-1]
        self.rejected.append(self.shown)
        self.shown = self._draw()
        return self.ctx.serve.ids[self.shown]

    def state_dict(self) -> dict:
        return {"method": self.method, "shown": self.shown, "rejected": list(self.rejected),
                "history": list(self.history)}

    @classmethod
    def from_state(cls, state: dict, context: ReferenceContext) -> RandomAgent:
        return cls(context, state["shown"], state["rejected"], state["history"])


class OracleAgent(Agent):
    """The ceiling: probabilistic bisection on the true proxies of the serve clips."""

    method = "oracle"
    feedback_kind = "attribute"

    def __init__(self, ctx: ReferenceContext, target=None, answers: list | None = None, shown: int | None = None,
                 rejected: list[int] | None = None) -> None:
        self.ctx = ctx
        self.answers: list[tuple[int, float, int]] = [tuple(x) for x in (answers or [])]  # (attribute, proxy, ±1)
        self.target = (np.array([self._median(a) for a in range(len(ctx.attribute_names))]) if target is None
                       else np.array(target, dtype=np.float64))
        self.shown = shown
        self.rejected = list(rejected or [])

    def _median(self, a: int) -> float:
        grid = self.ctx.grids[a]
        belief = posterior(grid, np.zeros(len(grid)), ((v, h) for attr, v, h in self.answers if attr == a),
                           ERROR_RATE)
        return quantile(grid, belief, 0.5)

    def _nearest(self) -> int:
        dist = np.linalg.norm((self.ctx.serve.proxies - self.target) / self.ctx.scale, axis=1)
        dist[self.ctx.excluded(self.rejected)] = np.inf
        return int(np.argmin(dist))

    def first_query(self) -> str:
        self.shown = self._nearest()
        return self.ctx.serve.ids[self.shown]

    def update(self, feedback: Feedback) -> str:
        if self._is_satisfied(feedback, self.ctx.attribute_names):
            return self.ctx.serve.ids[self.shown]
        value = self.ctx.serve.proxies[self.shown].astype(np.float64)
        asked = dict(self.ctx.indices(feedback))
        for a in range(len(self.ctx.attribute_names)):
            if a in asked:
                self.answers.append((a, float(value[a]), asked[a]))
                self.target[a] = self._median(a)
            else:  # silent: fine as it is
                self.target[a] = value[a]
        self.rejected.append(self.shown)
        self.shown = self._nearest()
        return self.ctx.serve.ids[self.shown]

    def state_dict(self) -> dict:
        return {"method": self.method, "target": self.target.tolist(), "answers": [list(x) for x in self.answers],
                "shown": self.shown, "rejected": list(self.rejected)}

    @classmethod
    def from_state(cls, state: dict, context: ReferenceContext) -> OracleAgent:
        return cls(context, state["target"], state["answers"], state["shown"], state["rejected"])


RANDOM = Method(agent=RandomAgent, label="Random", load_context=ReferenceContext.load, model_kinds=(), trainer=None,
                presets=(), reps=(), reference="floor")
ORACLE = Method(agent=OracleAgent, label="Oracle", load_context=ReferenceContext.load, model_kinds=(), trainer=None,
                presets=(), reps=(), reference="ceiling")
