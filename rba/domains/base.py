"""The Domain contract (ARCHITECTURE §4): a simulator, a scripted parameterised skill, and proxies.

A domain turns skill parameters into a physically simulated :class:`Rollout` whose
``states`` are what the learned models see and whose ``replay`` is what rendering needs.
Proxies are ground truth used only to make labels, simulate users and evaluate; agents
never read them.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np


@dataclass(frozen=True)
class Reading:
    """How a person reads a proxy whose sign only serves the rule "the proxy grows with its attribute".

    The page shows ``sign * proxy`` under ``label`` (walker softness is minus the landing speed: shown as
    the landing speed, with ``note`` "lower is softer").
    """

    label: str  # e.g. "landing speed"
    sign: int  # -1 or 1
    note: str  # which way is more of the attribute, e.g. "lower is softer"


@dataclass(frozen=True)
class AttributeSpec:
    """One relative behavioural attribute; its proxy grows with the attribute."""

    name: str  # snake_case id, e.g. "step_size"
    description: str  # one sentence; the source of the language embedding
    unit: str  # unit of the proxy, e.g. "m"
    epsilon: float  # success tolerance (splits the proxy range into 5-10 buckets)
    high_precision_epsilon: float  # 5-10x finer (the paper's Table 2)
    reading: Reading | None = None  # how the page shows the proxy, when not as it is

    @property
    def decimals(self) -> int:
        """Decimals that show a change of ``high_precision_epsilon`` (snake speed needs 3, not 2)."""
        return max(0, min(4, math.ceil(-math.log10(self.high_precision_epsilon))))


@dataclass(frozen=True)
class FeedbackPhrases:
    """How people say more or less of one attribute in their own words (``rba.interpret``'s anchors).

    ``more`` / ``less`` are short phrases that mean more / less of the attribute, written without
    direction words ("more", "less", "not", "too": the interpreter reads those itself); words found on
    one side only (after stemming) are that side's cue words, so write the two sides with the same
    nouns ("land gently" / "land heavily"). ``names`` are ways to name the attribute itself
    ("stride length"); the attribute's own name is always one.
    """

    more: tuple[str, ...]
    less: tuple[str, ...]
    names: tuple[str, ...] = ()


@dataclass
class Rollout:
    """One simulated behaviour clip."""

    id: str
    domain: str
    params: dict[str, float]
    seed: int
    states: np.ndarray  # float32[T, state_dim]: what models see
    replay: np.ndarray  # float[F, R]: per rendered frame, what render() needs (e.g. qpos)
    proxies: dict[str, float]  # attribute name -> measured proxy value
    success: bool
    info: dict[str, float] = field(default_factory=dict)  # extra diagnostics (not a contract)


class Domain(ABC):
    """A simulator plus a scripted skill; subclasses are registered in ``rba.domains``."""

    name: str
    attributes: tuple[AttributeSpec, ...]
    state_dim: int
    param_names: tuple[str, ...]  # keys of sample_params(), in a fixed order
    frame_rate: float  # frames per second of ``replay`` (and of rendered clips)
    serve_size: int = 1200  # rollouts in ``serve`` by default: denser where high-precision targets need it
    ranker_steps: int | None = None  # ζσ gradient steps of `rba train` where RankerConfig's default underfits
    # (kind, rep) of a learned model the states come from (models/<name>/<kind>-<rep>.pt): loaded, never trained
    # here; `rba build` makes it when missing (rba.training.prepare_states)
    state_encoder: tuple[str, str] | None = None
    # attribute name -> FeedbackPhrases: free-text feedback's anchors (an attribute without any is matched by name)
    feedback_phrases: Mapping[str, FeedbackPhrases] = MappingProxyType({})

    @abstractmethod
    def sample_params(self, rng: np.random.Generator) -> dict[str, float]:
        """Draw skill parameters that cover the attribute space."""

    @abstractmethod
    def rollout(self, params: dict[str, float], seed: int) -> Rollout:
        """Simulate the skill; equal (params, seed) give equal rollouts. ``id`` is left ''."""

    @abstractmethod
    def render(self, rollout: Rollout, width: int, height: int) -> Iterator[np.ndarray]:
        """Yield HxWx3 uint8 frames off-screen, deterministically, from ``rollout.replay``."""

    @property
    def attribute_names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.attributes)

    def attribute(self, name: str) -> AttributeSpec:
        for spec in self.attributes:
            if spec.name == name:
                return spec
        raise KeyError(f"unknown attribute {name!r} for domain {self.name!r}; valid: {', '.join(self.attribute_names)}")

    def epsilons(self, precision: str = "normal") -> np.ndarray:
        """Per-attribute success tolerance, float64[k]."""
        if precision not in ("normal", "high"):
            raise ValueError(f"unknown precision {precision!r}; valid: normal, high")
        attr = "epsilon" if precision == "normal" else "high_precision_epsilon"
        return np.array([getattr(a, attr) for a in self.attributes])
