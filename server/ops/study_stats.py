"""A study's statistics, from its tidy tables alone (the export's CSVs parsed, or the same rows read from the
database), so the results page and ``results_from_export`` run one computation (docs/studies.md).

- SR (and SR@k) with the Wilson score interval (Wilson 1927);
- AF (attribute feedbacks over the successful trials, the paper's unit), median time per answer's and the
  questionnaire scores' means with percentile bootstrap intervals (Efron 1979), seeded by the study's seed;
- the System Usability Scale (Brooke 1996) scored 0-100; a 3-item satisfaction scale (1-7) scored as its mean;
- conditions compared in pairs per participant (their SR@k difference) by the Wilcoxon signed-rank test
  (Wilcoxon 1945; scipy.stats.wilcoxon, two-sided), or the exact sign test when every non-zero difference has the
  same size (then the ranks say nothing more than the signs).
"""

from __future__ import annotations

import math
from collections import defaultdict
from typing import Any

import numpy as np

from server.common.errors import invalid

Z95 = 1.959963984540054  # the normal's 97.5 % quantile
BOOTSTRAP = 2000  # resamples per interval
SR_AT = (5, 10, 20)  # SR@k's k, up to the answer budget
PAIRED_K = 10  # the paired comparison's SR@k (SR@budget when the budget is smaller)

AGREE = {"low": "strongly disagree", "high": "strongly agree"}
SATISFACTION = (
    "I am satisfied with the behaviours I ended up with.",
    "It was easy to tell the agents what I wanted.",
    "The agents changed the way I asked them to.",
)
SUS = (  # Brooke (1996), the System Usability Scale's ten items, in order
    "I think that I would like to use this system frequently.",
    "I found the system unnecessarily complex.",
    "I thought the system was easy to use.",
    "I think that I would need the support of a technical person to be able to use this system.",
    "I found the various functions in this system were well integrated.",
    "I thought there was too much inconsistency in this system.",
    "I would imagine that most people would learn to use this system very quickly.",
    "I found the system very cumbersome to use.",
    "I felt very confident using the system.",
    "I needed to learn a lot of things before I could get going with this system.",
)


def questionnaire_items() -> dict[str, list[dict[str, Any]]]:
    return {"satisfaction": [{"id": f"sat_{i + 1}", "text": t, "min": 1, "max": 7, **AGREE}
                             for i, t in enumerate(SATISFACTION)],
            "usability": [{"id": f"sus_{i + 1}", "text": t, "min": 1, "max": 5, **AGREE} for i, t in enumerate(SUS)]}


def check_questionnaire(satisfaction: list[int], usability: list[int]) -> None:
    if len(satisfaction) != len(SATISFACTION) or len(usability) != len(SUS):
        raise invalid(f"give {len(SATISFACTION)} satisfaction answers (1-7) and {len(SUS)} usability answers (1-5, "
                      f"the System Usability Scale's items in order); got {len(satisfaction)} and {len(usability)}")


def sus_score(items: list[int]) -> float:
    """Brooke (1996): odd items score (x - 1), even items (5 - x); the sum times 2.5, 0-100."""
    return 2.5 * sum((x - 1) if i % 2 == 0 else (5 - x) for i, x in enumerate(items))


def satisfaction_score(items: list[int]) -> float:
    return float(np.mean(items))


def wilson(successes: int, n: int) -> dict[str, float | None]:
    """The share and its 95 % Wilson score interval (Wilson 1927); None when n is 0."""
    if n == 0:
        return {"value": None, "low": None, "high": None}
    p = successes / n
    centre = (p + Z95**2 / (2 * n)) / (1 + Z95**2 / n)
    half = Z95 * math.sqrt(p * (1 - p) / n + Z95**2 / (4 * n * n)) / (1 + Z95**2 / n)
    return {"value": p, "low": max(0.0, centre - half), "high": min(1.0, centre + half)}


def bootstrap(values: list[float], seed: int, statistic=np.mean) -> dict[str, float | None]:
    """The statistic and its 95 % percentile bootstrap interval (Efron 1979), ``BOOTSTRAP`` resamples."""
    x = np.asarray(values, dtype=np.float64)
    if len(x) == 0:
        return {"value": None, "low": None, "high": None}
    rng = np.random.default_rng(seed)
    draws = statistic(x[rng.integers(0, len(x), size=(BOOTSTRAP, len(x)))], axis=1)
    low, high = np.percentile(draws, [2.5, 97.5])
    return {"value": float(statistic(x)), "low": float(low), "high": float(high)}


def sr_ks(budget: int) -> list[int]:
    return [k for k in SR_AT if k <= budget] or [budget]


def paired_test(differences: list[float]) -> dict[str, Any]:
    """Two-sided test that the per-participant differences centre on 0 (module docstring says which test)."""
    d = np.asarray(differences, dtype=np.float64)
    nonzero = d[d != 0]
    out = {"n": len(d), "median_difference": float(np.median(d)) if len(d) else None}
    from scipy import stats  # here, not at import: scipy.stats costs the server's start-up ~0.4 s

    if len(nonzero) == 0:
        return {**out, "test": "none: every difference is zero (or no participant finished both)",
                "statistic": None, "p_value": 1.0 if len(d) else None}
    if np.all(np.abs(nonzero) == np.abs(nonzero[0])):
        positive = int((nonzero > 0).sum())
        result = stats.binomtest(positive, len(nonzero), 0.5, alternative="two-sided")
        return {**out, "test": "exact sign test (scipy.stats.binomtest, two-sided, zero differences dropped)",
                "statistic": float(positive), "p_value": float(result.pvalue)}
    result = stats.wilcoxon(nonzero, zero_method="wilcox", alternative="two-sided")
    return {**out, "test": "Wilcoxon signed-rank test (scipy.stats.wilcoxon, two-sided, zero differences dropped)",
            "statistic": float(result.statistic), "p_value": float(result.pvalue)}


def _condition(index: int, cond: dict, trials: list[dict], ms: list[int], ks: list[int], seed: int) -> dict:
    done = [t for t in trials if t["ended"]]
    wins = [t for t in done if t["success"]]
    return {"condition": index, "method": cond["method"], "rep": cond["rep"], "trials": len(done),
            "successes": len(wins), "sr": wilson(len(wins), len(done)),
            "af": bootstrap([t["feedbacks"] for t in wins], seed),
            "sr_at": {str(k): wilson(sum(t["answers"] <= k for t in wins), len(done)) for k in ks},
            "answers": len(ms), "median_ms_per_answer": float(np.median(ms)) if ms else None}


def _sr_at_by_participant(trials: list[dict], k: int) -> dict[tuple[str, int], float]:
    """(participant, condition) -> SR@k over that participant's finished trials of it (only when all finished)."""
    groups: dict[tuple[str, int], list[dict]] = defaultdict(list)
    for t in trials:
        groups[(t["participant_id"], t["condition"])].append(t)
    return {key: float(np.mean([bool(t["success"]) and t["answers"] <= k for t in ts]))
            for key, ts in groups.items() if all(t["ended"] for t in ts)}


def comparisons(config: dict, trials: list[dict]) -> dict[str, Any]:
    k = min(PAIRED_K, config["answer_budget"])
    sr = _sr_at_by_participant(trials, k)
    people = sorted({p for p, _ in sr})
    pairs = []
    n = len(config["conditions"])
    for a in range(n):
        for b in range(a + 1, n):
            d = [sr[(p, a)] - sr[(p, b)] for p in people if (p, a) in sr and (p, b) in sr]
            pairs.append({"a": a, "b": b, **paired_test(d)})
    return {"measure": f"SR@{k}", "k": k, "difference": "condition a minus condition b, per participant",
            "pairs": pairs}


def _questionnaires(rows: list[dict], seed: int) -> dict[str, Any]:
    sat = [satisfaction_score([r[f"sat_{i + 1}"] for i in range(len(SATISFACTION))]) for r in rows]
    sus = [sus_score([r[f"sus_{i + 1}"] for i in range(len(SUS))]) for r in rows]
    return {"n": len(rows), "satisfaction": {"scale": "mean of 3 items, 1-7", **bootstrap(sat, seed)},
            "usability": {"scale": "System Usability Scale (Brooke 1996), 0-100", **bootstrap(sus, seed + 1)}}


def results(config: dict, tables: dict[str, list[dict]]) -> dict[str, Any]:
    """Everything the results page shows, from the study's configuration and its four tables (rows as the CSVs
    hold them, typed): per condition, the paired comparisons, the questionnaires and each participant's
    progress."""
    seed, ks = config["seed"], sr_ks(config["answer_budget"])
    condition_of = {t["trial_id"]: t["condition"] for t in tables["trials"]}
    ms: dict[int, list[int]] = defaultdict(list)
    for a in tables["answers"]:
        ms[condition_of[a["trial_id"]]].append(a["ms"])
    conditions = [_condition(i, c, [t for t in tables["trials"] if t["condition"] == i], ms[i], ks, seed + 10 + i)
                  for i, c in enumerate(config["conditions"])]
    progress = [{k: p[k] for k in ("participant_id", "number", "consented", "trials_done", "trials_total",
                                    "finished")} for p in tables["participants"]]
    return {"participants": len(tables["participants"]), "sr_at_k": ks, "conditions": conditions,
            "comparison": comparisons(config, tables["trials"]),
            "questionnaires": _questionnaires(tables["questionnaires"], seed), "progress": progress,
            "intervals": "95 %: Wilson score for shares; percentile bootstrap (2000 resamples, seeded by the "
                         "study's seed) for means"}
