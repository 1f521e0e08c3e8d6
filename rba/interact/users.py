"""Simulated users: they look at the true proxies of what they are shown (agents never do)."""

from __future__ import annotations

import numpy as np

from rba.interact.base import SATISFIED, AttributeFeedback, Feedback


class SimulatedUser:
    """The paper's user: per attribute +1 below target − ε, −1 above target + ε, else nothing.

    ``noise`` is the probability of flipping each non-zero answer (B-Pref's "mistake" teacher).
    """

    def __init__(self, target: np.ndarray, epsilon: np.ndarray, attribute_names: tuple[str, ...],
                 proxies: np.ndarray, noise: float = 0.0, seed: int = 0) -> None:
        if not 0.0 <= noise < 0.5:
            raise ValueError(f"noise must be in [0, 0.5), got {noise}")
        self.target = np.asarray(target, dtype=np.float64)
        self.epsilon = np.asarray(epsilon, dtype=np.float64)
        self.attribute_names = attribute_names
        self.proxies = proxies  # float[N, k] of the library the agent shows from
        self.noise = noise
        self.rng = np.random.default_rng(seed)

    def signs(self, shown: np.ndarray) -> np.ndarray:
        """Noise-free answer per attribute: +1, −1 or 0."""
        diff = self.target - shown
        return np.where(diff > self.epsilon, 1, np.where(diff < -self.epsilon, -1, 0))

    def satisfied_with(self, rollout_index: int) -> bool:
        return not self.signs(self.proxies[rollout_index]).any()

    def respond(self, rollout_index: int) -> Feedback:
        signs = self.signs(self.proxies[rollout_index])
        if not signs.any():
            return SATISFIED
        out = []
        for name, s in zip(self.attribute_names, signs, strict=True):
            if s:
                if self.noise and self.rng.random() < self.noise:
                    s = -s
                out.append(AttributeFeedback(name, int(s)))
        return out


class PreferenceTeacher(SimulatedUser):
    """The PbRL teacher: of two rollouts it prefers the one closer to the target.

    Closeness is the Euclidean distance of the proxies after dividing each attribute by its ε,
    so every attribute counts in units of the user's tolerance. Equal distances give 0.5
    ("equally good"); otherwise ``noise`` flips the answer (as for attribute feedback).
    """

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
