"""ζσ re-fitted near a session's target on the session's own answers.

Why: ζσ orders clips a few high-precision ε apart only by chance, and what bounds it there is the precision of
its labels, not the model (decision 0015). A session at high precision answers
dozens of clips near one target, and every pair of them where one was answered "more α" and the other "less α"
is a correctly ordered label exactly there: the first shows less α than the target, the second more. So after
each answer, each attribute's last layer of fσ (``AttributeRanker.with_heads``) is fitted again on the pairs
the session's answers make (Bradley-Terry), pulled towards the trained weights (``PULL``); everything the agent
reads in ζσ is then read under the new last layers.

Only named directions make pairs: a person who names one attribute says nothing about the others. The first fit
waits for ``REFIT_AFTER`` answers: the loss is the pairs' mean, so a pair or two move the last layer as far as
many do, further than they say.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit

from rba.learn.ranker import AttributeRanker

# weight of ‖(w, b) − trained‖² against the pairs' mean Bradley-Terry loss (decision 0011)
PULL = 0.1
# answers a session gives before the first fit: a session at normal precision ends within a few answers, and fits on
# their few pairs would cost it answers; one at high precision gives dozens (decision 0011)
REFIT_AFTER = 7
Answered = list[tuple[str, list[tuple[int, int]]]]  # per answer: the clip's id, (attribute, ±1) per named attribute
Features = Callable[[str], tuple[np.ndarray, float]]  # a clip's id -> its summed features float[k, H], its length


def ordered_pairs(sides: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (higher, lower) of clips known to be ordered: ``sides`` are the directions said about each,
    +1 "more" (the clip is below the target) or −1 "less" (above it)."""
    s = np.asarray(sides)
    higher, lower = np.nonzero(s[:, None] < s[None, :])
    return higher, lower


def fit_head(features: np.ndarray, lengths: np.ndarray, higher: np.ndarray, lower: np.ndarray,
             weight: np.ndarray, bias: float, clip: float, pull: float = PULL) -> tuple[np.ndarray, float]:
    """The last layer (w, b) minimising the mean Bradley-Terry loss of ζ = clip·tanh((φ·w + T b) / clip) over the
    pairs plus ``pull`` × its squared distance from (``weight``, ``bias``); L-BFGS from there."""
    x0 = np.append(weight, bias)
    design = np.column_stack([features, lengths])

    def loss(x: np.ndarray) -> tuple[float, np.ndarray]:
        t = np.tanh(design @ x / clip)
        margin = clip * (t[higher] - t[lower])
        dmargin = -expit(-margin) / len(higher)  # d mean softplus(−margin) / d margin
        dz = np.bincount(higher, dmargin, len(t)) - np.bincount(lower, dmargin, len(t))
        grad = design.T @ (dz * (1 - t * t)) + 2 * pull * (x - x0)
        return float(np.mean(np.logaddexp(0.0, -margin)) + pull * np.sum((x - x0) ** 2)), grad

    x = minimize(loss, x0, jac=True, method="L-BFGS-B").x
    return x[:-1], float(x[-1])


def refit_heads(ranker: AttributeRanker, answered: Answered, features: Features, pull: float = PULL
                ) -> tuple[np.ndarray, np.ndarray]:
    """Every attribute's last layer fitted on the pairs ``answered`` makes about it (the trained one where it
    makes none): float64[k, H], float64[k]."""
    weight, bias = ranker.trained_head()
    for a in range(ranker.num_attributes):
        about = [(rid, dict(asked)[a]) for rid, asked in answered if a in dict(asked)]
        higher, lower = ordered_pairs([side for _, side in about])
        if not len(higher):
            continue
        phi = [features(rid) for rid, _ in about]
        weight[a], bias[a] = fit_head(np.stack([f[a] for f, _ in phi]), np.array([t for _, t in phi]),
                                      higher, lower, weight[a], bias[a], ranker.clip, pull)
    return weight, bias

