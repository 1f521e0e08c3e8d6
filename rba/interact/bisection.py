"""Probabilistic bisection (Horstein's): a belief over a grid of one attribute's values, answer by answer.

"More" about a shown value z multiplies the belief above z by (1 − p) and below z by p, where p is the
assumed error rate; the estimate is the belief's median. With a small p this moves almost exactly like
bisection, and a wrong answer is outvoted by the next right ones instead of excluding the target for good.
RBA-Global runs it in ζσ space, the oracle reference agent on the true proxies.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np


def posterior(grid: np.ndarray, log_prior: np.ndarray, answers: Iterable[tuple[float, int]],
              error_rate: float) -> np.ndarray:
    """The belief over ``grid`` (normalised) after answers ``(shown value, ±1)`` about one attribute."""
    log_p = log_prior
    right, wrong = np.log(1 - error_rate), np.log(error_rate)
    for z, h in answers:
        log_p = log_p + np.where(h * (grid - z) > 0, right, wrong)
    p = np.exp(log_p - log_p.max())
    return p / p.sum()


def quantile(grid: np.ndarray, belief: np.ndarray, q: float) -> float:
    """The ``q`` quantile of a belief over ``grid``."""
    return float(np.interp(q, np.cumsum(belief), grid))
