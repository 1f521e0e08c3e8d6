"""How few answers an agent needs at best: bisection on the true proxies that shows exactly what it estimates.

The tables' Oracle (``rba.interact.reference``) knows the true proxies of every serve clip, runs probabilistic
bisection on them with the user's answers and shows the serve clip nearest its estimate. Here the same bisection
shows a clip with exactly the proxies it estimates, as if a generator could make any behaviour on demand and the
agent read every clip perfectly, from a uniform belief or from where the serve library's behaviours lie (the
prior). An agent that reads clips through ζσ and makes them by simulation has neither, so this measures what an AF
goal asks (bisection is near the fewest answers ternary feedback allows, not proven the fewest). Same targets
(``rba.evaluate.held_out_targets``), ε and user as ``rba eval``; nothing is simulated, so it takes seconds. Writes
``benchmarks/results/ideal_oracle.md`` and ``.json``.

    python benchmarks/ideal_oracle.py                       # every domain, both precisions, 20 test targets, seed 0
    python benchmarks/ideal_oracle.py --targets 120 --domains snake
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

from rba.domains import domain_names, get_domain
from rba.evaluate import MAX_FEEDBACK, af_cell, evaluate, held_out_targets, success_summary
from rba.interact.bisection import kernel_prior, posterior, quantile
from rba.interact.reference import ERROR_RATE, ReferenceContext
from rba.interact.users import SimulatedUser
from rba.library import HELD_OUT, SkillLibrary
from rba.storage import machine, save_report

log = logging.getLogger("ideal_oracle")
RESULTS = Path(__file__).resolve().parent / "results"
DOMAINS = ("walker", "manipulator", "snake", "lane_change")
PURE = 1e-9  # the error rate of plain bisection: the paper's user never errs
PRIOR_BANDWIDTH = 0.05  # the library prior's kernel width, a share of each proxy's 1st-99th percentile range
PRIOR_FLOOR = 0.01  # share of the prior spread evenly over the grid: no target is ruled out before an answer


def ideal_trial(user: SimulatedUser, grids: np.ndarray, error_rate: float, priors: np.ndarray | None = None,
                budget: int = MAX_FEEDBACK) -> tuple[bool, int]:
    """(success, attribute feedbacks) of bisection on each proxy (from ``priors``, log densities over ``grids``;
    None: uniform) that shows its estimate itself; an attribute the user is silent about keeps the value just
    shown, as the Oracle does."""
    priors = np.zeros(grids.shape) if priors is None else priors
    answers: list[list[tuple[float, int]]] = [[] for _ in grids]

    def median(a: int) -> float:
        return quantile(grids[a], posterior(grids[a], priors[a], answers[a], error_rate), 0.5)

    shown = np.array([median(a) for a in range(len(grids))])
    feedbacks = 0
    while feedbacks < budget:
        signs = user.signs(shown)
        if not signs.any():
            return True, feedbacks
        feedbacks += int(np.count_nonzero(signs))
        for a in np.flatnonzero(signs):
            answers[a].append((float(shown[a]), int(signs[a])))
            shown[a] = median(a)
    return False, feedbacks


def measure(domain: str, precision: str, args: argparse.Namespace) -> dict:
    """One row: the ideal bisection (the Oracle's error rate and plain) and the tables' Oracle, same targets."""
    serve = SkillLibrary.load(domain, "serve")
    eps = get_domain(domain).epsilons(serve.proxies, precision)
    ref = ReferenceContext.from_library(serve)
    priors = np.stack([kernel_prior(g, serve.proxies[:, a], PRIOR_BANDWIDTH * ref.scale[a], PRIOR_FLOOR)
                       for a, g in enumerate(ref.grids)])
    targets = held_out_targets(SkillLibrary.load(domain, args.split), args.targets, args.seed)
    row = {"domain": domain, "precision": precision, "targets": len(targets)}
    for name, rate, prior in (("ideal", ERROR_RATE, None), ("ideal_pure", PURE, None),
                              ("ideal_prior", ERROR_RATE, priors), ("ideal_prior_pure", PURE, priors)):
        users = [SimulatedUser(t, eps, serve.attribute_names, np.empty((0, len(eps)))) for t in targets]
        row[name] = success_summary([ideal_trial(u, ref.grids, rate, prior) for u in users])
    oracle = evaluate(domain, "oracle", targets=args.targets, seed=args.seed, precision=precision, split=args.split)
    row["oracle_library"] = {"success_rate": oracle.success_rate, "avg_feedback": oracle.avg_feedback,
                             "std_feedback": oracle.std_feedback}
    log.info("%s", row)
    return row


def _cell(r: dict) -> str:
    return f"{r['success_rate']:.2f} / {af_cell(r['avg_feedback'], r['std_feedback'])}"


def markdown(report: dict) -> str:
    lines = ["# The ideal oracle: the fewest answers bisection on the true proxies needs", "",
             f"{report['targets']} `{report['split']}` targets (seed {report['seed']}), the paper's user, "
             "SR / AF (std), AF over successful trials. *ideal*: the Oracle's probabilistic bisection (error rate "
             f"{ERROR_RATE}) from a uniform belief, showing a clip with exactly its estimate; *plain*: the same with "
             "plain bisection (the paper's user never errs); *prior*: the belief starts from where the serve "
             f"library's behaviours lie (a kernel estimate of each proxy, width {PRIOR_BANDWIDTH} of its range); "
             "*Oracle (library)*: the tables' row, the serve clip nearest the uniform belief's estimate. An agent "
             "that reads clips through ζσ and makes them by simulation does worse than these, which show exactly "
             "what they mean; bisection itself is not proven the fewest answers.", "",
             "| domain | precision | ideal | ideal, plain | ideal, prior | ideal, prior, plain | Oracle (library) |",
             "|---|---|---|---|---|---|---|"]
    for r in report["rows"]:
        cells = " | ".join(_cell(r[k]) for k in ("ideal", "ideal_pure", "ideal_prior", "ideal_prior_pure",
                                                  "oracle_library"))
        lines.append(f"| {r['domain']} | {r['precision']} | {cells} |")
    lines += ["", f"Command: `{report['command']}` ({report['machine']}, {report['date']})."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--domains", nargs="+", choices=domain_names(), default=list(DOMAINS))
    ap.add_argument("--precisions", nargs="+", choices=("high", "normal"), default=["high", "normal"])
    ap.add_argument("--targets", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--split", choices=HELD_OUT, default="test")
    ap.add_argument("--out", type=Path, default=RESULTS / "ideal_oracle", help="writes <out>.json and <out>.md")
    args = ap.parse_args(argv)
    if args.targets < 1:
        ap.error(f"--targets must be at least 1, got {args.targets}")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    report = {"targets": args.targets, "seed": args.seed, "split": args.split, "date": time.strftime("%Y-%m-%d"),
              "command": "python benchmarks/ideal_oracle.py " + " ".join(argv or sys.argv[1:]), "machine": machine(),
              "rows": [measure(d, p, args) for p in args.precisions for d in args.domains]}
    save_report(args.out, report, markdown(report))
    print(markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
