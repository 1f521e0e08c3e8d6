"""Probabilistic bisection (Horstein's): a belief over a grid of one attribute's values, answer by answer.

"More" about a shown value z multiplies the belief above z by (1 − p) and below z by p, where p is the
assumed error rate; the estimate is the belief's median. With a small p this moves almost exactly like
bisection, and a wrong answer is outvoted by the next right ones instead of excluding the target for good.
RBA-Global runs it in ζσ space, the oracle reference agent on the true proxies.

With a ``width`` the step is soft: P("more" | target g) = p + (1 − 2p) Φ((g − z) / width). The value shown
is then itself uncertain by about ``width``: ζσ orders clips a few high-precision ε apart only by chance
(``benchmarks/results/zeta_residual.md``), so an answer about a clip whose ζσ is near the target is weak
evidence of which side the target lies, and two such answers that contradict each other in ζσ leave the
belief one bump between them instead of splitting it in two.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from scipy.special import log_ndtr


def posterior(grid: np.ndarray, log_prior: np.ndarray, answers: Iterable[tuple[float, int]],
              error_rate: float, width: float = 0.0) -> np.ndarray:
    """The belief over ``grid`` (normalised) after answers ``(shown value, ±1)`` about one attribute; a step
    of ``width`` (0: the hard step) around each shown value."""
    log_p = log_prior
    right, wrong = np.log(1 - error_rate), np.log(error_rate)
    for z, h in answers:
        if width > 0:
            log_p = log_p + np.logaddexp(wrong, np.log1p(-2 * error_rate) + log_ndtr(h * (grid - z) / width))
        else:
            log_p = log_p + np.where(h * (grid - z) > 0, right, wrong)
    p = np.exp(log_p - log_p.max())
    return p / p.sum()


def quantile(grid: np.ndarray, belief: np.ndarray, q: float) -> float:
    """The ``q`` quantile of a belief over ``grid``."""
    return float(np.interp(q, np.cumsum(belief), grid))


def kernel_prior(grid: np.ndarray, values: np.ndarray, width: float, floor: float,
                 base: np.ndarray | None = None) -> np.ndarray:
    """A log prior over ``grid`` where ``values`` lie (a Gaussian kernel estimate of ``width``), with a ``floor``
    share of ``base`` (a density over the grid; None: uniform), so that no value is ruled out before an answer."""
    near = np.exp(-0.5 * ((grid[:, None] - np.asarray(values)[None, :]) / width) ** 2).sum(1)
    base = np.ones(len(grid)) if base is None else np.asarray(base, dtype=np.float64)
    return np.log((1 - floor) * near / near.sum() + floor * base / base.sum())
