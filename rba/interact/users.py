"""Simulated users: they look at the true proxies of what they are shown (agents never do).

``SimulatedUser`` is the paper's user; the other kinds are B-Pref's teachers (Lee et al. 2021) adapted to
attribute feedback, each with one strength parameter and a default (``USER_KINDS``). A spec ``KIND[:param]``
(``rba eval --user``) is parsed in one place, ``parse_user``. Every kind is satisfied, and the trial ends, when
it perceives every attribute within ε of its (current) target; the trial *succeeds* when the clip's true
proxies are within ε of that target (``succeeded``), so a user who perceives wrongly can stop on a miss.

- ``mistake:p`` (0.1) flips each direction with probability p.
- ``skip:p`` (0.2) gives no answer this round with probability p (``SKIP``: the agent is not updated).
- ``equal:k`` (2) comments only on attributes more than k·ε off; when all are within k·ε (but not ε) it
  names just the worst one. Its silence no longer means "this attribute is right".
- ``myopic:w`` (0.5) judges a clip by (1 − w) × its proxies + w × its proxies as the clip's last quarter shows
  them. Proxies are clip-level: the domains measure one value per attribute over the whole simulation (peak
  yaw rate, touchdown speeds, ...), so no proxy of a clip's last part exists. It is approximated by what the
  last quarter tells a viewer about the attribute (``last_part_proxies``): a ridge least-squares map, fitted
  over the serve library, from what the last quarter of the replay shows (the rendered frames' simulator
  positions: their mean, spread and mean speed) to the proxies. Where the end of a clip says little about
  an attribute the map regresses to the mean, and the user misjudges. The replay, not ``states``: the user
  is the same whatever state view the agents learn from.
- ``boundary:s`` (0.5) says "more" with probability σ((target − value) / (s·ε)) about each attribute it
  comments on (those outside ε): answers near the target are coin flips, far ones are sure.
- ``inconsistent:s`` (0.1) moves its target after every round by a normal step of s·ε per attribute, pulled
  back towards where it started (``DRIFT_KEEP`` of the offset is kept a round): a person's wish wanders a
  little around what it is (a spread of about 3·s·ε), it does not walk away.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Literal

import numpy as np

from rba.interact.base import SATISFIED, AttributeFeedback, Feedback

if TYPE_CHECKING:
    from rba.data.library import SkillLibrary

DRIFT_KEEP = 0.95  # inconsistent: share of the target's offset from its start kept a round (mean reversion)
SKIP: Literal["skip"] = "skip"  # a user's "no answer this round": the agent is not updated, the clip shown again
Answer = Feedback | Literal["skip"]


class SimulatedUser:
    """The paper's user: per attribute +1 below target − ε, −1 above target + ε, else nothing.

    ``noise`` is the probability of flipping each non-zero answer (B-Pref's "mistake" teacher).
    """

    kind: ClassVar[str] = "paper"
    judges_generated: ClassVar[bool] = True  # can judge clips made during a trial (``add_clip``)

    def __init__(self, target: np.ndarray, epsilon: np.ndarray, attribute_names: tuple[str, ...],
                 proxies: np.ndarray, noise: float = 0.0, seed: int = 0) -> None:
        if not 0.0 <= noise < 0.5:
            raise ValueError(f"noise must be in [0, 0.5), got {noise}")
        self.target = np.array(target, dtype=np.float64)
        self.epsilon = np.asarray(epsilon, dtype=np.float64)
        self.attribute_names = attribute_names
        self.proxies = proxies  # float[N, k] of the library the agent shows from
        self.noise = noise
        self.rng = np.random.default_rng(seed)

    @classmethod
    def from_library(cls, strength: float | None, target: np.ndarray, epsilon: np.ndarray, serve: SkillLibrary,
                     seed: int) -> SimulatedUser:
        """The user of this kind at ``strength`` for a target, judging clips of ``serve``."""
        return cls(target, epsilon, serve.attribute_names, serve.proxies, seed=seed)

    def add_clip(self, proxies: np.ndarray) -> int:
        """One more clip to judge, beyond the library (a generated one, measured by its simulation): its index."""
        self.proxies = np.vstack([self.proxies, np.asarray(proxies, np.float64)])
        return len(self.proxies) - 1

    def signs(self, shown: np.ndarray) -> np.ndarray:
        """Noise-free answer per attribute: +1, −1 or 0."""
        diff = self.target - shown
        return np.where(diff > self.epsilon, 1, np.where(diff < -self.epsilon, -1, 0))

    def perceived(self, rollout_index: int) -> np.ndarray:
        """The proxies as this user sees them (the true ones unless the user misjudges)."""
        return self.proxies[rollout_index]

    def satisfied_with(self, rollout_index: int) -> bool:
        return not self.signs(self.perceived(rollout_index)).any()

    def succeeded(self, rollout_index: int) -> bool:
        """The protocol's success: the true proxies within ε of the user's target now."""
        return not self.signs(self.proxies[rollout_index]).any()

    def comments(self, shown: np.ndarray) -> np.ndarray:
        """Which attributes the user speaks about, with the right direction (0: silent)."""
        return self.signs(shown)

    def direction(self, attribute: int, sign: int, shown: np.ndarray) -> int:
        """The direction said for an attribute whose right direction is ``sign``."""
        if self.noise and self.rng.random() < self.noise:
            return -sign
        return sign

    def respond(self, rollout_index: int) -> Answer:
        shown = self.perceived(rollout_index)
        if not self.signs(shown).any():
            return SATISFIED
        return [AttributeFeedback(name, int(self.direction(a, int(s), shown)))
                for a, (name, s) in enumerate(zip(self.attribute_names, self.comments(shown), strict=True)) if s]


class _KindUser(SimulatedUser):
    """A teacher kind with one strength parameter (its meaning is the subclass's)."""

    def __init__(self, target: np.ndarray, epsilon: np.ndarray, attribute_names: tuple[str, ...],
                 proxies: np.ndarray, strength: float, seed: int = 0) -> None:
        super().__init__(target, epsilon, attribute_names, proxies, seed=seed)
        self.strength = strength

    @classmethod
    def from_library(cls, strength, target, epsilon, serve, seed):
        return cls(target, epsilon, serve.attribute_names, serve.proxies, strength, seed)


class MistakeUser(_KindUser):
    """Flips each direction with probability ``strength`` (the paper's ``noise``)."""

    kind = "mistake"

    def __init__(self, target, epsilon, attribute_names, proxies, strength: float, seed: int = 0) -> None:
        SimulatedUser.__init__(self, target, epsilon, attribute_names, proxies, noise=strength, seed=seed)
        self.strength = strength


class SkipUser(_KindUser):
    """Hesitates: no answer at all this round with probability ``strength``."""

    kind = "skip"

    def respond(self, rollout_index: int) -> Answer:
        if self.rng.random() < self.strength:
            return SKIP
        return super().respond(rollout_index)


class EqualUser(_KindUser):
    """Silent about attributes within ``strength``·ε; names only the worst one when all are that close."""

    kind = "equal"

    def comments(self, shown: np.ndarray) -> np.ndarray:
        signs = self.signs(shown)
        off = np.abs(self.target - shown) / self.epsilon
        far = off > self.strength
        if far.any():
            return np.where(far, signs, 0)
        worst = int(np.argmax(np.where(signs != 0, off, -np.inf)))
        return np.where(np.arange(len(signs)) == worst, signs, 0)


class BoundaryUser(_KindUser):
    """Says "more" with probability σ((target − value) / (``strength``·ε)) for each attribute outside ε."""

    kind = "boundary"

    def direction(self, attribute: int, sign: int, shown: np.ndarray) -> int:
        z = (self.target[attribute] - shown[attribute]) / (self.strength * self.epsilon[attribute])
        return 1 if self.rng.random() < 1.0 / (1.0 + np.exp(-z)) else -1


class InconsistentUser(_KindUser):
    """Its target wanders: after every round, offset ← ``DRIFT_KEEP`` × offset + N(0, (``strength``·ε)²)."""

    kind = "inconsistent"

    def __init__(self, target, epsilon, attribute_names, proxies, strength: float, seed: int = 0) -> None:
        super().__init__(target, epsilon, attribute_names, proxies, strength, seed)
        self.start = self.target.copy()

    def respond(self, rollout_index: int) -> Answer:
        answer = super().respond(rollout_index)
        if answer != SATISFIED:
            offset = DRIFT_KEEP * (self.target - self.start) + self.rng.normal(0.0, self.strength * self.epsilon)
            self.target = self.start + offset
        return answer


class MyopicUser(_KindUser):
    """Judges mostly the end: (1 − ``strength``) × the proxies + ``strength`` × the last quarter's proxies."""

    kind = "myopic"
    judges_generated = False  # its clip ends come from a map fitted over the library (``last_part_proxies``)

    def __init__(self, target, epsilon, attribute_names, proxies, strength: float, seed: int = 0,
                 end_proxies: np.ndarray | None = None) -> None:
        super().__init__(target, epsilon, attribute_names, proxies, strength, seed)
        end = proxies if end_proxies is None else end_proxies
        self.seen = (1.0 - strength) * np.asarray(proxies, dtype=np.float64) + strength * end

    @classmethod
    def from_library(cls, strength, target, epsilon, serve, seed):
        end = last_part_proxies(serve.replay, serve.replay_offsets, serve.proxies)
        return cls(target, epsilon, serve.attribute_names, serve.proxies, strength, seed, end)

    def perceived(self, rollout_index: int) -> np.ndarray:
        return self.seen[rollout_index]


def _segment_features(frames: np.ndarray) -> np.ndarray:
    """What a person sees of a run of frames: the mean and spread of each coordinate, and its mean speed."""
    speed = np.abs(np.diff(frames, axis=0)).mean(0) if len(frames) > 1 else np.zeros(frames.shape[1])
    return np.concatenate([frames.mean(0), frames.std(0), speed])


def last_part_proxies(frames: np.ndarray, offsets: np.ndarray, proxies: np.ndarray, part: float = 0.25,
                      ridge: float = 1e-3) -> np.ndarray:
    """Each clip's proxies as its last ``part`` shows them, float64[N, k] (see the module docstring).

    ``frames``/``offsets``: the library's replay. Features of the last ``part`` of each clip (at least two
    frames), standardised over the library; a ridge least-squares map to the proxies, fitted on the same library.
    """
    rows = []
    for start, end in itertools.pairwise(offsets):
        clip = np.asarray(frames[start:end], dtype=np.float64)
        rows.append(_segment_features(clip[min(int(len(clip) * (1 - part)), len(clip) - 2):]))
    x = np.array(rows)
    x = (x - x.mean(0)) / np.maximum(x.std(0), 1e-9)
    y = np.asarray(proxies, np.float64)
    w = np.linalg.solve(x.T @ x + ridge * len(x) * np.eye(x.shape[1]), x.T @ (y - y.mean(0)))
    return y.mean(0) + x @ w


@dataclass(frozen=True)
class UserKind:
    """A teacher kind: its class, its default strength and what strengths are valid."""

    cls: type[SimulatedUser]
    default: float | None  # None: the kind takes no parameter
    valid: Callable[[float], bool]
    valid_text: str


USER_KINDS: dict[str, UserKind] = {
    "paper": UserKind(SimulatedUser, None, lambda _: False, "no parameter"),
    "mistake": UserKind(MistakeUser, 0.1, lambda p: 0 <= p < 0.5, "a flip probability in [0, 0.5)"),
    "skip": UserKind(SkipUser, 0.2, lambda p: 0 <= p < 1, "a skip probability in [0, 1)"),
    "equal": UserKind(EqualUser, 2.0, lambda k: k >= 1, "k >= 1 (silent within k·ε)"),
    "myopic": UserKind(MyopicUser, 0.5, lambda w: 0 <= w <= 1, "a weight of the clip's end in [0, 1]"),
    "boundary": UserKind(BoundaryUser, 0.5, lambda s: s > 0, "a logistic width in ε, > 0"),
    "inconsistent": UserKind(InconsistentUser, 0.1, lambda s: s >= 0, "a drift step in ε per round, >= 0"),
}


@dataclass(frozen=True)
class UserSpec:
    """A parsed ``KIND[:param]``: which simulated user, at what strength."""

    kind: str
    strength: float | None

    def __str__(self) -> str:
        return self.kind if self.strength is None else f"{self.kind}:{self.strength:g}"

    def build(self, target: np.ndarray, epsilon: np.ndarray, serve: SkillLibrary, seed: int) -> SimulatedUser:
        return USER_KINDS[self.kind].cls.from_library(self.strength, target, epsilon, serve, seed)


def parse_user(spec: str | UserSpec) -> UserSpec:
    """``KIND[:param]`` → ``UserSpec`` (the kind's default strength without a param); ValueError naming the valid."""
    if isinstance(spec, UserSpec):
        return spec
    kind, sep, param = spec.strip().partition(":")
    if kind not in USER_KINDS:
        raise ValueError(f"unknown user kind {kind!r}; valid: {', '.join(USER_KINDS)} (as KIND or KIND:param)")
    info = USER_KINDS[kind]
    if not sep:
        return UserSpec(kind, info.default)
    if info.default is None:
        raise ValueError(f"user kind {kind!r} takes no parameter, got {param!r}")
    try:
        value = float(param)
    except ValueError:
        raise ValueError(f"user kind {kind!r} takes a number ({info.valid_text}), got {param!r}") from None
    if not np.isfinite(value) or not info.valid(value):
        raise ValueError(f"user kind {kind!r} takes {info.valid_text}, got {param}")
    return UserSpec(kind, value)


class PreferenceTeacher(SimulatedUser):
    """The PbRL teacher: of two rollouts it prefers the one closer to the target.

    Closeness is the Euclidean distance of the proxies after dividing each attribute by its ε,
    so every attribute counts in units of the user's tolerance. Equal distances give 0.5
    ("equally good"); otherwise ``noise`` flips the answer (as for attribute feedback).
    Of the teacher kinds it is only ``paper`` or ``mistake`` (``for_spec``).
    """

    @classmethod
    def for_spec(cls, spec: UserSpec, target: np.ndarray, epsilon: np.ndarray, serve: SkillLibrary,
                 seed: int) -> PreferenceTeacher:
        if spec.kind not in ("paper", "mistake"):
            raise ValueError(f"A/B answers (PbRL) come from a paper or mistake[:p] teacher, not {spec.kind!r}")
        return cls(target, epsilon, serve.attribute_names, serve.proxies, spec.strength or 0.0, seed)

    def distance(self, rollout_index: int) -> float:
        return float(np.linalg.norm((self.proxies[rollout_index] - self.target) / self.epsilon))

    def prefer(self, a: int, b: int) -> float:
        """P[a ≻ b] as the teacher answers it: 1.0 (a), 0.0 (b) or 0.5 (equal)."""
        da, db = self.distance(a), self.distance(b)
        if da == db:
            return 0.5
        label = 1.0 if da < db else 0.0
        if self.noise and self.rng.random() < self.noise:
            label = 1.0 - label
        return label
