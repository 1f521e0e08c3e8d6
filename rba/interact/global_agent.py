"""RBA-Global agent: a search per attribute in ζσ space (paper appendix), query = argmax rθ.

The paper bisects an interval [lower, upper] per attribute. A single wrong answer then
excludes the true target for good, so we run *probabilistic* bisection instead
(``rba.interact.bisection``): a belief over a grid of ζ values per attribute, uniform over
the ζ range seen in ``train`` (with a thin tail beyond it, so targets outside can still be
reached) or, where the generating agent asks (``GlobalContext.prior_width``), mostly where the
serve clips lie; the new target is the belief's median. With a small error rate this moves almost
exactly like bisection (no extra feedback when users are right), and a wrong answer is
outvoted by the next right ones instead of trapping the search.

Guard against the paper's failure mode (rθ returns the same behaviour for a nudged
target): if the argmax is the rollout just shown, or does not move the asked attributes
the asked way, rθ is asked again for a point pushed further in the asked direction
(doubling the step, within the belief's grid) until it does. The push serves that one
query only: the target stays the belief's median (generation aims there). Rollouts that
received non-satisfied feedback in the last ``REJECT_MEMORY`` rounds are not shown again;
older ones may be (a user whose target drifts can come back to one). A round the user skips
is no update at all.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rba.core.artifacts import load_model
from rba.core.methods import Method
from rba.data.library import SkillLibrary
from rba.interact.base import REJECT_MEMORY, Agent, Feedback
from rba.interact.bisection import kernel_prior, posterior, quantile
from rba.learn.common import Ragged
from rba.learn.embed import REPRESENTATIONS
from rba.learn.global_reward import LibraryScorer
from rba.learn.training import PRESETS, GlobalTrainConfig, train_global

if TYPE_CHECKING:
    from rba.learn.training import LabelSource, StageProgress

MAX_PUSHES = 8  # doublings of the push step before giving up on a move
GRID = 401  # belief grid points per attribute
TAIL = 0.5  # the grid extends this fraction of the train ζ range beyond each end
TAIL_DENSITY = 0.05  # prior density beyond the train range, relative to inside it
PRIOR_FLOOR = 0.05  # share of a library prior (``GlobalContext.prior_width``) kept uniform: no target ruled out
ERROR_RATE = 0.1  # assumed probability that an answer is wrong
SHORTLIST = 32  # rollouts nearest the target in ζσ space that rθ ranks (None: all); see benchmarks/results/shortlist.md


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
    shortlist: int | None = SHORTLIST
    # the belief starts where the serve clips lie in ζσ: a Gaussian kernel of this share of ζσ's train range (0:
    # uniform over the train range). Targets are behaviours of the same skill, so most lie where its clips do
    prior_width: float = 0.0

    @classmethod
    def load(cls, domain: str, rep: str, data_root=None, models_root=None) -> GlobalContext:
        ranker = load_model(domain, "ranker", rep, models_root)
        reward = load_model(domain, "global_reward", rep, models_root)
        serve = SkillLibrary.load(domain, "serve", data_root)
        data = Ragged.from_numpy(serve.states, serve.state_offsets)
        zeta = ranker.model.score(data)
        bounds = np.array(reward.card["zeta_bounds"], dtype=np.float64)
        version = f"{ranker.card['weights_sha']}-{reward.card['weights_sha']}"
        names = tuple(a["name"] for a in reward.card["attributes"])  # may include attributes admins added
        return cls(domain, rep, names, serve, zeta, bounds,
                   LibraryScorer(reward.model, data), version)

    def first(self, n: int) -> GlobalContext:
        """This context over the serve library's first ``n`` rollouts (a random sample: its parameters are
        drawn from a seeded stream), to measure how small a library generation needs."""
        if not 0 < n <= len(self.serve):
            raise ValueError(f"the serve library has {len(self.serve)} rollouts; asked for the first {n}")
        serve = self.serve.subset(range(n))
        scorer = LibraryScorer(self.scorer.model, Ragged.from_numpy(serve.states, serve.state_offsets))
        return replace(self, serve=serve, serve_zeta=self.serve_zeta[:n], scorer=scorer)

    def candidates(self, target: np.ndarray, exclude: np.ndarray) -> np.ndarray | None:
        """The ``shortlist`` non-excluded rollouts nearest ``target`` in ζσ space (ranges scaled to 1).

        rθ then ranks only these: for the walker, 35-60x faster queries than over the whole library,
        and more of them within ε of the target (benchmarks/results/shortlist.md).
        """
        if self.shortlist is None or self.shortlist >= len(self.serve):
            return None
        scale = np.maximum(self.bounds[1] - self.bounds[0], 1e-9)
        dist = np.linalg.norm((self.serve_zeta - target) / scale, axis=1)
        dist[exclude] = np.inf
        return np.argpartition(dist, self.shortlist)[: self.shortlist]

    def grid(self, a: int) -> np.ndarray:
        lo, hi = self.bounds[:, a]
        return np.linspace(lo - TAIL * (hi - lo), hi + TAIL * (hi - lo), GRID)

    def prior(self, a: int) -> np.ndarray:
        """The belief's log prior over ``grid(a)``: uniform over the train range with a thin tail beyond it, or with
        ``prior_width`` mostly where the serve clips lie, the uniform one kept as a ``PRIOR_FLOOR`` share."""
        g = self.grid(a)
        inside = (g >= self.bounds[0, a]) & (g <= self.bounds[1, a])
        flat = np.where(inside, 1.0, TAIL_DENSITY)
        width = self.prior_width * float(self.bounds[1, a] - self.bounds[0, a])
        return kernel_prior(g, self.serve_zeta[:, a], width, PRIOR_FLOOR, flat) if width else np.log(flat)


class GlobalAgent(Agent):
    method = "global"
    feedback_kind = "attribute"

    def __init__(self, ctx: GlobalContext, answers: list | None = None, shown: int | None = None,
                 rejected: list[int] | None = None, error_rate: float = ERROR_RATE, zeta_noise: float = 0.0) -> None:
        self.ctx = ctx
        self.error_rate = error_rate
        self.zeta_noise = zeta_noise  # the answers' soft step, a share of ζσ's train range (0: the hard step)
        self._beliefs: dict[int, tuple[tuple, np.ndarray]] = {}  # attribute -> (its answers, belief): ``belief``
        self.answers: list[tuple[int, float, int]] = [tuple(x) for x in (answers or [])]  # (attribute, z, ±1)
        self.target = self._medians()  # a function of the answers: kept up to date by update, never stored
        self.shown = shown
        self.rejected = list(rejected or [])
        # set by rba.interact.generating_agent for one update: the ζσ of the clip shown when it is a generated one
        self.shown_zeta: np.ndarray | None = None

    def belief(self, a: int) -> np.ndarray:
        """Posterior over ``ctx.grid(a)`` given every answer about attribute ``a`` (normalised).

        Kept for the answers it was computed from: an update asks for each quantile of it in turn."""
        answers = tuple((z, h) for attr, z, h in self.answers if attr == a)
        kept = self._beliefs.get(a)
        if kept is None or kept[0] != answers:
            width = self.zeta_noise * float(self.ctx.bounds[1, a] - self.ctx.bounds[0, a])
            kept = self._beliefs[a] = (answers, posterior(self.ctx.grid(a), self.ctx.prior(a), answers,
                                                          self.error_rate, width))
        return kept[1]

    def _quantile(self, a: int, q: float) -> float:
        return quantile(self.ctx.grid(a), self.belief(a), q)

    def _medians(self) -> np.ndarray:
        return np.array([self._quantile(a, 0.5) for a in range(len(self.ctx.attribute_names))])

    def widths(self, mass: float = 0.5) -> np.ndarray:
        """The belief's central ``mass`` per attribute, as a width in ζσ (0.5: the interquartile range)."""
        return np.array([self._quantile(a, (1 + mass) / 2) - self._quantile(a, (1 - mass) / 2)
                         for a in range(len(self.ctx.attribute_names))])

    def target_ranks(self, mass: float = 0.5) -> dict[str, tuple[float, float]]:
        """The belief's central ``mass`` per attribute, as the share of serve rollouts scoring below each end."""
        out = {}
        for a, name in enumerate(self.ctx.attribute_names):
            ends = (self._quantile(a, (1 - mass) / 2), self._quantile(a, (1 + mass) / 2))
            scores = self.ctx.serve_zeta[:, a]
            lo, hi = (float(np.mean(scores <= z)) for z in ends)
            out[name] = (lo, hi)
        return out

    def use_context(self, ctx: GlobalContext) -> None:
        """Read everything under ``ctx`` from now on (ζσ re-fitted, ``rba.interact.refit``): the beliefs too, whose
        prior may lie where ``ctx`` reads the serve clips."""
        self.ctx = ctx
        self._beliefs.clear()
        self.target = self._medians()

    def reread(self, answers: list[tuple[int, float, int]]) -> None:
        """The same answers placed again, at where ζσ reads their clips now (``rba.interact.refit``)."""
        if [(a, h) for a, _, h in answers] != [(a, h) for a, _, h in self.answers]:
            raise ValueError("reread places the answers given again, each at a new ζ; not other answers")
        self.answers = list(answers)
        self.target = self._medians()

    def _argmax(self, query: np.ndarray) -> int:
        exclude = np.zeros(len(self.ctx.serve), dtype=bool)
        exclude[self.rejected[-REJECT_MEMORY:]] = True
        return self.ctx.scorer.argmax(query, exclude, self.ctx.candidates(query, exclude))

    def first_query(self) -> str:
        self.shown = self._argmax(self.target)
        return self.ctx.serve.ids[self.shown]

    def update(self, feedback: Feedback) -> str:
        if self._is_satisfied(feedback, self.ctx.attribute_names):
            return self.ctx.serve.ids[self.shown]
        z = self.ctx.serve_zeta[self.shown] if self.shown_zeta is None else self.shown_zeta
        asked = [(self.ctx.attribute_names.index(fb.attribute), fb.direction) for fb in feedback]
        self.answers += [(a, float(z[a]), h) for a, h in asked]
        self.target = self._medians()
        self.rejected.append(self.shown)
        self.shown = self._pushed_argmax(z, asked)
        return self.ctx.serve.ids[self.shown]

    def _pushed_argmax(self, z: np.ndarray, asked: list[tuple[int, int]]) -> int:
        """The library clip for the target or, when that does not move the asked attributes the asked way from
        ``z``, for a query pushed further that way (the step doubling). The query stays on the belief's grid and
        is dropped afterwards: the target stays the belief's median, which generation aims at."""
        query = self.target.copy()
        nxt = self._argmax(query)
        width = self.ctx.bounds[1] - self.ctx.bounds[0]
        step = {a: max(self._quantile(a, 0.75) - self._quantile(a, 0.25), 0.01 * width[a]) / 2 for a, _ in asked}
        ends = {a: self.ctx.grid(a)[[0, -1]] for a, _ in asked}
        for _ in range(MAX_PUSHES):
            if all(h * (self.ctx.serve_zeta[nxt, a] - z[a]) > 0 for a, h in asked):
                break
            for a, h in asked:
                query[a] = float(np.clip(query[a] + h * step[a], *ends[a]))
                step[a] *= 2
            nxt = self._argmax(query)
        return nxt

    def state_dict(self) -> dict:
        return {"method": self.method, "answers": [list(x) for x in self.answers], "shown": self.shown,
                "rejected": list(self.rejected), "error_rate": self.error_rate, "zeta_noise": self.zeta_noise}

    @classmethod
    def from_state(cls, state: dict, context: GlobalContext) -> GlobalAgent:
        """The agent of ``state`` (a ``"target"`` stored by older versions is ignored: the answers give it; a state
        from before ``zeta_noise`` had the hard step)."""
        return cls(context, state["answers"], state["shown"], state["rejected"], state["error_rate"],
                   state.get("zeta_noise", 0.0))


def train(domain: str, rep: str, preset: str, seed: int = 0, data_root: Path | None = None,
          models_root: Path | None = None, sources: list[LabelSource] | None = None,
          on_progress: StageProgress | None = None) -> dict:
    """Fit ζσ then rθ at ``preset`` (the domain may set its own ζσ steps)."""
    return train_global(domain, rep, GlobalTrainConfig.preset(preset, seed, domain), data_root=data_root,
                        models_root=models_root, sources=sources, on_progress=on_progress)


METHOD = Method(agent=GlobalAgent, label="RBA-Global", load_context=GlobalContext.load,
                model_kinds=("ranker", "global_reward"), trainer=train, presets=PRESETS, reps=REPRESENTATIONS,
                generating="rba.interact.generating_agent:METHOD",
                description="Works out from all your answers where you want each attribute and shows the clip "
                "closest to that (the paper's RBA-Global).")
