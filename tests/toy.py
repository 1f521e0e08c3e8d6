"""A cheap synthetic domain for fast pipeline tests: a dot oscillating left-right.

Attributes: ``amplitude`` (how far it swings) and ``pace`` (oscillations per second).
Each state shows both quantities with noise, so a per-state sum can rank them.
"""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from rba.domains.base import AttributeSpec, Domain, FeedbackPhrases, ParamSpace, Rollout, SkillPolicy, SkillSim

T = 24  # states per rollout
PARAM_RANGES = {"amplitude": (0.2, 2.0), "pace": (0.5, 3.0)}


# free-text feedback's anchors (rba.interact.free_text): both sides written with the same nouns
FEEDBACK_PHRASES = MappingProxyType({
    "amplitude": FeedbackPhrases(
        more=("wide swings", "swing far", "big movements", "large sway", "go far out to the sides", "broad arc"),
        less=("narrow swings", "small movements", "stay near the middle", "tiny sway", "short arc",
              "barely move to the sides"),
        names=("swing width", "how far it swings")),
    "pace": FeedbackPhrases(
        more=("fast oscillation", "quick rhythm", "rapid back and forth", "hurry", "brisk", "frantic",
              "quick swings"),
        less=("slow oscillation", "relaxed rhythm", "lazy back and forth", "calm", "leisurely", "sluggish",
              "slow swings"),
        names=("frequency", "tempo", "how often it swings")),
})


class Toy(Domain):
    name = "toy"
    description = "A dot swinging from side to side: a tiny domain for fast tests."
    attributes = (
        AttributeSpec("amplitude", "How far the dot swings from side to side.", "m"),
        AttributeSpec("pace", "How quickly the dot oscillates back and forth.", "Hz"),
    )
    state_dim = 4
    param_names = ("amplitude", "pace")
    frame_rate = 12.0
    feedback_phrases = FEEDBACK_PHRASES

    def sample_params(self, rng: np.random.Generator) -> dict[str, float]:
        return {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in PARAM_RANGES.items()}

    def param_space(self) -> ParamSpace:
        return ParamSpace.box(PARAM_RANGES)

    def rollout(self, params: dict[str, float], seed: int) -> Rollout:
        rng = np.random.default_rng(seed)
        a, f = params["amplitude"], params["pace"]
        t = np.arange(T) / self.frame_rate
        x = a * np.sin(2 * np.pi * f * t)
        states = np.stack([a + 0.05 * rng.standard_normal(T), f + 0.05 * rng.standard_normal(T), x,
                           np.cos(2 * np.pi * f * t)], 1).astype(np.float32)
        return Rollout("", self.name, dict(params), seed, states, x[:, None].astype(np.float64),
                       {"amplitude": float(a), "pace": float(f)}, success=True)

    def simulator(self) -> SkillSim:
        return ToySim()

    def skill_policy(self, params: dict[str, float], seed: int) -> SkillPolicy:
        return ToyPolicy(params)

    def observed_proxies(self, observations: np.ndarray) -> dict[str, float]:
        """The amplitude and pace the stepped dot showed: their means over its states (with the sensor noise)."""
        shown = np.asarray(observations, dtype=np.float64)[1:]  # the reset's observation is the dot at rest
        return {"amplitude": float(shown[:, 0].mean()), "pace": float(shown[:, 1].mean())}

    def render(self, rollout: Rollout, width: int, height: int, frames: slice = slice(None)):
        for (x,) in rollout.replay[frames]:
            frame = np.full((height, width, 3), 255, np.uint8)
            cx = int((x / 4 + 0.5) * (width - 1))
            frame[height // 2 - 4 : height // 2 + 4, max(cx - 4, 0) : cx + 4] = (200, 30, 30)
            yield frame


class ToySim:
    """The dot stepped by actions (amplitude, pace): each step shows where it is, then its phase moves on.

    The reset observation (the dot at rest) is not a recorded state; the T after each step are, with the
    seed's sensor noise on the amplitude and pace they show, as in ``Toy.rollout``.
    """

    action_low = np.array([0.0, 0.0])
    action_high = np.array([4.0, 6.0])
    max_steps = T

    def reset(self, params: dict[str, float], seed: int) -> tuple[np.ndarray, bool]:
        rng = np.random.default_rng(seed)
        self._noise = 0.05 * rng.standard_normal(T), 0.05 * rng.standard_normal(T)
        self._k = 0
        return np.array([0.0, 0.0, 0.0, 1.0]), False

    def step(self, action: np.ndarray) -> tuple[np.ndarray, bool]:
        a, f = (float(x) for x in action)
        phase = 2 * np.pi * f * (self._k / Toy.frame_rate)
        obs = np.array([a + self._noise[0][self._k], f + self._noise[1][self._k], a * np.sin(phase), np.cos(phase)])
        self._k += 1
        return obs, True


class ToyPolicy:
    """Open loop: the same (amplitude, pace) every step; the time is the simulator's."""

    done = False

    def __init__(self, params: dict[str, float]) -> None:
        self._action = np.array([params["amplitude"], params["pace"]])

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self._action.copy()

    def measured(self) -> dict[str, float]:
        return {"amplitude": float(self._action[0]), "pace": float(self._action[1])}
