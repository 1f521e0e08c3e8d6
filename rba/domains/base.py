"""The Domain contract (docs/architecture.md §4): a simulator, a scripted parameterised skill, and proxies.

A domain turns skill parameters into a physically simulated :class:`Rollout` whose
``states`` are what the learned models see and whose ``replay`` is what rendering needs.
Proxies are ground truth used only to make labels, simulate users and evaluate; agents
never read them.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Protocol

import numpy as np

ALL_FRAMES = slice(None)  # Domain.render's default: every replay row


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
    reading: Reading | None = None  # how the page shows the proxy, when not as it is


# what the models see under each ``Domain.states_view``: a research view shows the same scene as its base domain
STATES_VIEWS = MappingProxyType({
    "features": "",
    "raw": "Research view: the models see the simulator's raw positions and velocities, not the domain's features.",
    "image": "Research view: the models see the rendered frames through a learned image encoder (a VAE).",
})

# ε per precision, as a fraction of a proxy's robust range over the serve library (its 1st to 99th percentile):
# "normal" splits the range into 7 buckets, "high" (the paper's Table 2) is 6x finer. Robust quantiles, because a
# few outlying clips stretch the raw range (snake's doubled its ε).
EPSILON_FRACTIONS = {"normal": 1 / 7, "high": 1 / 42}
ROBUST_QUANTILES = (1.0, 99.0)  # percentiles of the serve library's proxies that bound the range ε divides


@dataclass(frozen=True)
class FeedbackPhrases:
    """How people say more or less of one attribute in their own words (``rba.interact.free_text``'s anchors).

    ``more`` / ``less`` are short phrases that mean more / less of the attribute, written without
    direction words ("more", "less", "not", "too": the interpreter reads those itself); words found on
    one side only (after stemming) are that side's cue words, so write the two sides with the same
    nouns ("land gently" / "land heavily"). ``names`` are ways to name the attribute itself
    ("stride length"); the attribute's own name is always one.
    """

    more: tuple[str, ...]
    less: tuple[str, ...]
    names: tuple[str, ...] = ()


@dataclass(frozen=True)
class ParamSpace:
    """Where a search over the skill may go: bounds per parameter, and those it must leave as they are.

    ``low`` / ``high`` are the honest range of ``sample_params`` (the conformance test draws inside it);
    a ``fixed`` parameter is kept at the starting clip's value (e.g. a discrete one a continuous search
    would only round). ``rba.generate.cma`` searches the free ones, scaled to [0, 1].
    """

    low: Mapping[str, float]
    high: Mapping[str, float]
    fixed: frozenset[str] = frozenset()

    @classmethod
    def box(cls, ranges: Mapping[str, tuple[float, float]], fixed: frozenset[str] = frozenset()) -> ParamSpace:
        """The space of a domain whose ``sample_params`` draws each parameter uniformly in ``ranges``."""
        return cls({k: float(lo) for k, (lo, _) in ranges.items()}, {k: float(hi) for k, (_, hi) in ranges.items()},
                   fixed)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.low)

    @property
    def free(self) -> tuple[str, ...]:
        return tuple(k for k in self.low if k not in self.fixed)

    def contains(self, params: Mapping[str, float]) -> bool:
        return set(params) == set(self.low) and not self.outside(params)

    def outside(self, params: Mapping[str, float]) -> list[str]:
        """The names of ``params`` (this space's names) whose values lie outside their range; NaN is outside."""
        return [k for k in self.low if not self.low[k] <= params[k] <= self.high[k]]

    def to_unit(self, params: Mapping[str, float]) -> np.ndarray:
        """The free parameters of ``params`` scaled to [0, 1], float64[len(free)]."""
        return np.array([(params[k] - self.low[k]) / (self.high[k] - self.low[k]) for k in self.free])

    def from_unit(self, unit: np.ndarray, start: Mapping[str, float]) -> dict[str, float]:
        """Parameters with the free ones at ``unit`` (clipped into the box) and the fixed ones from ``start``."""
        out = {k: float(start[k]) for k in self.low}
        for k, u in zip(self.free, np.clip(unit, 0.0, 1.0), strict=True):
            out[k] = float(self.low[k] + u * (self.high[k] - self.low[k]))
        return out


@dataclass(frozen=True)
class Marker:
    """A point an overlay shows from ``frame`` on, with a short text (e.g. a footprint and its stride length)."""

    frame: int
    pos: tuple[float, float, float]  # the scene's coordinates (MuJoCo's, or the road's x, y and 0)
    text: str


@dataclass(frozen=True)
class Overlay:
    """What one attribute measures, drawn over a clip (the page shows it on request): markers and a polyline."""

    attribute: str
    label: str
    markers: tuple[Marker, ...] = ()
    path: tuple[tuple[float, float, float], ...] | None = None


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


class SkillSim(Protocol):
    """A domain's simulator, stepped by its scripted skill's actions (``rba.gym`` wraps it as a Gymnasium env).

    Observations are the domain's state vector (``Rollout.states`` rows, in float64 before they are stored
    as float32); ``recorded`` says whether an observation is one the rollout keeps as a state (a domain may
    step faster than it records). Equal params, seed and actions give equal observations.
    """

    action_low: np.ndarray  # float64[A]
    action_high: np.ndarray
    max_steps: int  # the episode is cut here (the rollout's own time limit)

    def reset(self, params: dict[str, float], seed: int) -> tuple[np.ndarray, bool]:
        """Start an episode where ``rollout(params, seed)`` starts; the first observation and ``recorded``."""

    def step(self, action: np.ndarray) -> tuple[np.ndarray, bool]:
        """Apply one action; the next observation and ``recorded``."""


class SkillPolicy(Protocol):
    """The scripted skill with fixed parameters, acting on observations alone: ``policy(obs) -> action``.

    Made fresh for each episode, with the episode's seed (the skill's own randomness, e.g. the manipulator's
    tremor, is drawn from it); it keeps the skill's phase and its own clock: one call per step. ``done`` turns
    True when the skill has finished (the rollout ends there); ``measured()`` gives the attribute proxies of the
    episode so far, measured from the observations it was called with.
    """

    done: bool

    def __call__(self, obs: np.ndarray) -> np.ndarray: ...

    def measured(self) -> dict[str, float]: ...


def run_skill(sim: SkillSim, policy: SkillPolicy, params: dict[str, float], seed: int) -> list[np.ndarray]:
    """The rollout loop: reset, then the policy's actions stepped until it is done (or ``max_steps``); the
    recorded observations. ``Domain.rollout`` runs it on its own simulator, so the rollout and ``rba.gym``'s
    step interface are one code path. The policy sees every observation, the last one included."""
    obs, recorded = sim.reset(params, seed)
    states = []
    for step in range(sim.max_steps + 1):
        if recorded:
            states.append(obs)
        action = policy(obs)
        if policy.done or step == sim.max_steps:
            break
        obs, recorded = sim.step(action)
    return states


def stack_samples(samples: list | np.ndarray, per_state: int) -> np.ndarray:
    """float32[T, per_state * D]: consecutive groups of ``per_state`` raw samples [N, D], one group a state.

    A frame stack (a trailing partial group is dropped): the states keep the fast motion that their own rate
    would alias away, without anything being computed from the samples.
    """
    samples = np.asarray(samples, dtype=np.float64)
    n = len(samples) // per_state
    return samples[: n * per_state].reshape(n, per_state * samples.shape[1]).astype(np.float32)


class Domain(ABC):
    """A simulator plus a scripted skill; subclasses are registered in ``rba.domains``."""

    name: str
    description: str = ""  # one line on the scene and its skill, for people picking a domain (the API lists it)
    attributes: tuple[AttributeSpec, ...]
    state_dim: int
    param_names: tuple[str, ...]  # keys of sample_params(), in a fixed order
    # name -> (low, high): the skill's box; a domain that sets it gets sample_params() and param_space() from it
    param_ranges: Mapping[str, tuple[float, float]] = MappingProxyType({})
    frame_rate: float  # frames per second of ``replay`` (and of rendered clips)
    serve_size: int = 1200  # rollouts in ``serve``: the generating agent makes what it lacks (the image view: 2,400)
    ranker_steps: int | None = None  # ζσ gradient steps of `rba train` where RankerConfig's default underfits
    # the generating agent's soft step for answers, a share of ζσ's train range (rba.interact.bisection): about how
    # far ζσ can put a clip from where a person would; 0: the hard step. Decision 0006
    zeta_noise: float = 0.0
    # the generating agent's belief starts where the serve library's clips lie in ζσ (a kernel of this share of ζσ's
    # train range, ``GlobalContext.prior_width``) rather than uniform over it (0): targets are behaviours of the
    # same skill. Decision 0010
    belief_prior: float = 0.0
    # neighbours of the ζσ surface over the skill's parameters (rba.generate.surface) the generating agent reads clips
    # on and makes them from: where the proxies move smoothly with the parameters it orders nearby clips better than ζσ
    # of their states. 0: each clip's own ζσ. Decision 0008
    zeta_surface: int = 0
    # the generating agent re-fits ζσ's last layers near the target on the session's answers (rba.interact.refit):
    # where ζσ's labels leave it least precise. Not with a surface. Decision 0011
    session_refit: bool = False
    # the generating agent searches only where the library clip misses its target by more than this share of the
    # belief's half interquartile range (and the threshold): while it is unsure where the target is, a library clip
    # there asks as well as a made one, at once (0: by the threshold alone). Decisions 0003 and 0008
    generate_spread: float = 1.0
    # the app's time bound of a search (s; ``SearchConfig.seconds``): the longest whose made clips a person sees within
    # 2 s (p95) on 2 cores while val SR holds; ``RBA_GENERATE_SECONDS`` overrides it for every domain. A domain not
    # measured keeps this one. Decision 0005
    generate_seconds: float = 2.0
    # the skill's outcome depends on its seed beyond the parameters (the manipulator's tremor is drawn from it): a
    # search then simulates each candidate with a seed of its own (``rba.generate.cma.search``), so the noise is part of
    # what it chooses among, as the library's seeds are. Decision 0007
    noisy_skill: bool = False
    # an export re-fits its global reward's last layer for the chosen v* (``rba.data.export_zip``; False: the trained
    # weights). Decision 0012
    export_refit: bool = True
    # (kind, rep) of a learned model the states come from (models/<name>/<kind>-<rep>.pt): loaded, never trained
    # here; `rba build` makes it when missing (rba.learn.training.prepare_states)
    state_encoder: tuple[str, str] | None = None
    # the raw view (`<domain>_raw`, `--states raw`): states are the simulator's own positions and velocities,
    # sampled at the domain's raw rate and stacked (``stack_samples``); nothing computed from them. The
    # skill, params, seeds, proxies and replay are the base domain's: only ``states`` differ
    raw_states: bool = False
    # attribute name -> FeedbackPhrases: free-text feedback's anchors (an attribute without any is matched by name)
    feedback_phrases: Mapping[str, FeedbackPhrases] = MappingProxyType({})

    @property
    def summary(self) -> str:
        """``description``, and for a research view what its models see: the line the page's picker shows."""
        note = STATES_VIEWS[self.states_view]
        return f"{self.description} {note}" if note else self.description

    @property
    def states_view(self) -> str:
        """What the models see as states: "features" (the domain's own), "raw" (``raw_states``) or "image" (a
        model of its rendered frames, ``state_encoder``); the last two are research views of the same scene."""
        return "raw" if self.raw_states else "image" if self.state_encoder else "features"

    def sample_params(self, rng: np.random.Generator) -> dict[str, float]:
        """Draw skill parameters that cover the attribute space: uniform over ``param_ranges`` unless overridden."""
        if not self.param_ranges:
            raise NotImplementedError(f"domain {self.name!r} declares no param_ranges: define sample_params()")
        return {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in self.param_ranges.items()}

    @abstractmethod
    def rollout(self, params: dict[str, float], seed: int) -> Rollout:
        """Simulate the skill; equal (params, seed) give equal rollouts. ``id`` is left ''."""

    @abstractmethod
    def render(self, rollout: Rollout, width: int, height: int, frames: slice = ALL_FRAMES) -> Iterator[np.ndarray]:
        """Yield HxWx3 uint8 frames off-screen, deterministically: one per row of ``rollout.replay``, those
        ``frames`` selects. A frame is the same whether its clip is rendered whole or in parts (the compute
        layer renders a clip's parts on several workers), so a frame may read other rows (a camera set by
        the first) but never depend on which frames were drawn before it."""

    def clip_view(self, rollout: Rollout | None = None) -> object | None:
        """What the page draws this domain's clips from instead of their MP4s (``rba.media.clip_data``): a
        ``rba.domains.mujoco_render.MujocoView`` or a ``rba.domains.lane_change.RoadView``, for ``rollout`` (None: the
        scene every clip shares). None (the default): the page shows the MP4."""
        return None

    @property
    def draws_clips(self) -> bool:
        """Whether the page can draw this domain's clips from data (the domain defines ``clip_view``)."""
        return type(self).clip_view is not Domain.clip_view

    def clip_overlays(self, rollout: Rollout, track: Mapping[str, np.ndarray]) -> list[Overlay]:
        """Per attribute, what it measures drawn over the clip. ``track``: each named visual geom's centre per
        frame, float[F, 3] (MuJoCo domains; empty otherwise). Default: none."""
        return []

    def simulator(self) -> SkillSim:
        """A new simulator stepped by the skill's actions (``rba.gym``); domains without one raise."""
        raise NotImplementedError(f"domain {self.name!r} has no step interface for rba.gym yet")

    def skill_policy(self, params: dict[str, float], seed: int) -> SkillPolicy:
        """The scripted skill with ``params`` as a policy over ``simulator()``'s observations (``seed``: the
        episode's, for the skill's own randomness)."""
        raise NotImplementedError(f"domain {self.name!r} has no step interface for rba.gym yet")

    def observed_proxies(self, observations: np.ndarray) -> dict[str, float]:
        """The attributes' proxies of an episode of *any* policy in ``simulator()``, from its observations alone
        (float64[N, state_dim]: every step's, the reset's first): what a policy trained on an exported reward
        reached (``rba.gym.Episode.proxies``). The skill's own episode measures as its rollout; domains that
        measure only through their skill raise."""
        raise NotImplementedError(f"domain {self.name!r} measures its attributes only through its scripted skill")

    def param_space(self) -> ParamSpace:
        """The skill's parameter space (bounds, what is fixed): what ``rba.generate.cma`` may search."""
        if self.param_ranges:
            return ParamSpace.box(self.param_ranges)
        raise NotImplementedError(f"domain {self.name!r} declares no parameter space: behaviours cannot be "
                                  "generated for it (define param_space())")

    @property
    def attribute_names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.attributes)

    def attribute(self, name: str) -> AttributeSpec:
        for spec in self.attributes:
            if spec.name == name:
                return spec
        raise KeyError(f"unknown attribute {name!r} for domain {self.name!r}; valid: {', '.join(self.attribute_names)}")

    def epsilons(self, serve_proxies: np.ndarray, precision: str = "normal") -> np.ndarray:
        """Per-attribute success tolerance, float64[k]: ``EPSILON_FRACTIONS[precision]`` × the robust range.

        The one definition of ε (evaluation, simulated users, local labels): from the serve library's
        proxies (float[N, k], columns in ``attributes`` order), so it follows the clips agents show.
        """
        if precision not in EPSILON_FRACTIONS:
            raise ValueError(f"unknown precision {precision!r}; valid: {', '.join(EPSILON_FRACTIONS)}")
        proxies = np.asarray(serve_proxies, dtype=np.float64)
        if proxies.ndim != 2 or proxies.shape[1] != len(self.attributes) or len(proxies) < 2:
            raise ValueError(f"ε needs the serve library's proxies as float[N >= 2, {len(self.attributes)}], "
                             f"got shape {proxies.shape}")
        low, high = np.percentile(proxies, ROBUST_QUANTILES, axis=0)
        return EPSILON_FRACTIONS[precision] * (high - low)
