"""RBA-Local agent: the shown rollout becomes the anchor; next = argmax_serve rθ(·|α, h, φ(anchor)).

Several attributes in one round are handled one at a time, by *chaining* edits: the first
(attribute, direction) in the round edits the shown rollout, the result (not shown) is the
anchor of the second edit, and so on; only the last result is shown. Every answer is
acted on (each costs the user one feedback), and because rθ is trained to keep the
other attributes unchanged, one edit does not undo another.

Guard against the paper's failure mode (rθ returns the anchor or a near copy): rollouts whose
anchor embedding φ lies within the model's near-copy radius of the current anchor are
excluded, as is every rollout shown in the last ``REJECT_MEMORY`` rounds. Excluding shown
rollouts is safe even with a user who makes mistakes: mistakes flip "more" and "less" but
never fake "not satisfied", so a rollout that got feedback is truly not the target; only
for that long, though, since a user whose target drifts can come back to one.

Mistakes (``--noise``): the agent keeps no belief that a wrong answer could corrupt (unlike an
interval that a binary search shrinks): a flipped answer costs one step away and one step
back, and the next answers steer the walk again, so every trial can still succeed. Two
alternatives were simulated (a 1-D walk with steps of 0.5-1.5 ε, p = 0.1 and 0.2) and
rejected: re-showing a rollout when an answer reverses the previous one on the same
attribute costs more feedback (4.8 vs 4.4 at p = 0.2), and a Bayesian vote over all past
answers placed by dead reckoning gains < 3 %. Walker numbers for p = 0, 0.1, 0.2 are in
``benchmarks/results/walker_methods.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from rba.core.artifacts import load_model
from rba.core.methods import Method
from rba.data.library import SkillLibrary
from rba.interact.base import REJECT_MEMORY, Agent, Feedback
from rba.learn.common import Ragged
from rba.learn.embed import REPRESENTATIONS
from rba.learn.local_reward import LocalLibraryScorer
from rba.learn.training import LOCAL_PRESETS, LocalTrainConfig, train_local

if TYPE_CHECKING:
    from rba.learn.training import LabelSource, StageProgress


@dataclass
class LocalContext:
    """The loaded local reward and the serve library, shared by every local agent of a domain/rep."""

    domain: str
    rep: str
    attribute_names: tuple[str, ...]
    serve: SkillLibrary
    scorer: LocalLibraryScorer  # precomputed first layer and φ of every serve rollout
    near_copy_radius: float  # φ distance below which a rollout counts as a copy of the anchor
    start: int  # first rollout shown: the medoid of serve in φ space (a "typical" behaviour)
    model_version: str

    @classmethod
    def load(cls, domain: str, rep: str, data_root=None, models_root=None) -> LocalContext:
        art = load_model(domain, "local_reward", rep, models_root)
        serve = SkillLibrary.load(domain, "serve", data_root)
        scorer = LocalLibraryScorer(art.model, Ragged.from_numpy(serve.states, serve.state_offsets))
        names = tuple(a["name"] for a in art.card["attributes"])
        return cls(domain, rep, names, serve, scorer, float(art.card["near_copy_radius"]), medoid(scorer.phi),
                   art.card["weights_sha"])

    def edit(self, anchor: int, attr: int, direction: int, exclude: list[int] | None = None) -> int:
        """The serve rollout that best makes the minimal change (attr, direction) to rollout ``anchor``."""
        phi = self.scorer.phi[anchor]
        ret = self.scorer.returns(phi, attr, direction)
        banned = self.scorer.phi_distances(phi) < self.near_copy_radius
        banned[anchor] = True
        if exclude:
            banned[exclude] = True
        if banned.all():  # nothing left: fall back to the nearest non-anchor rollouts
            banned[:] = False
            banned[anchor] = True
        ret[banned] = -np.inf
        return int(np.argmax(ret))


def medoid(points: torch.Tensor, chunk: int = 1024) -> int:
    """Index of the point with the least total distance to all others."""
    totals = torch.cat([torch.cdist(points[i:i + chunk], points).sum(1) for i in range(0, len(points), chunk)])
    return int(totals.argmin())


class LocalAgent(Agent):
    method = "local"
    feedback_kind = "attribute"

    def __init__(self, ctx: LocalContext, shown: int | None = None, seen: list[int] | None = None) -> None:
        self.ctx = ctx
        self.shown = shown
        self.seen = list(seen or [])  # every rollout shown that got (non-satisfied) feedback

    def first_query(self) -> str:
        self.shown = self.ctx.start
        return self.ctx.serve.ids[self.shown]

    def update(self, feedback: Feedback) -> str:
        if self._is_satisfied(feedback, self.ctx.attribute_names):
            return self.ctx.serve.ids[self.shown]
        self.seen.append(self.shown)
        anchor = self.shown
        for fb in feedback:
            anchor = self.ctx.edit(anchor, self.ctx.attribute_names.index(fb.attribute), fb.direction,
                                   self.seen[-REJECT_MEMORY:])
        self.shown = anchor
        return self.ctx.serve.ids[anchor]

    def state_dict(self) -> dict:
        return {"method": self.method, "shown": self.shown, "seen": list(self.seen)}

    @classmethod
    def from_state(cls, state: dict, context: LocalContext) -> LocalAgent:
        return cls(context, state["shown"], state["seen"])


def train(domain: str, rep: str, preset: str, seed: int = 0, data_root: Path | None = None,
          models_root: Path | None = None, sources: list[LabelSource] | None = None,
          on_progress: StageProgress | None = None) -> dict:
    """Fit the local rθ at ``preset``."""
    return train_local(domain, rep, LocalTrainConfig.preset(preset, seed), data_root=data_root,
                       models_root=models_root, sources=sources, on_progress=on_progress)


METHOD = Method(agent=LocalAgent, label="RBA-Local", load_context=LocalContext.load, model_kinds=("local_reward",),
                trainer=train, presets=LOCAL_PRESETS, reps=REPRESENTATIONS,
                description="Takes each answer as a change to the clip on screen and shows the clip that makes "
                "that change (the paper's RBA-Local).")
