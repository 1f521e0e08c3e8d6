"""Targets outside the serve library's range: SR / AF of RBA-Global with and without generation.

Targets are the proxies of rollouts the skill made up to ``--share`` of each proxy's serve range beyond it
(``rba.interact.evaluate.beyond_targets``: seeded, their own stream, so neither val nor test); the paper's user,
``--precision`` ε. Each domain is measured over the library alone and with generation (``rba eval``'s
default, candidates simulated in this process or on ``--gen-workers`` local workers), the same targets for
both. Rows of earlier runs in ``--out``'s .json are kept for domains this run does not measure (runs of one
domain at a time can run in parallel and be combined). Writes ``benchmarks/results/beyond_range.md`` and ``.json``.

    python benchmarks/beyond_range.py --domains walker manipulator snake lane_change
    python benchmarks/beyond_range.py --domains snake --modes gen --gen-workers 2   # re-measure one row, keep the rest
    python benchmarks/beyond_range.py --domains snake --modes gen --gen-seconds 2   # searches bounded as the app's
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

from rba.cli import seconds_arg
from rba.compute import simulation_pool
from rba.core.fileio import report_to_extend, save_report
from rba.domains import domain_names
from rba.generate.cma import Simulate
from rba.generate.config import GenerationConfig
from rba.interact import load_context
from rba.interact.evaluate import EvalResult, af_cell, evaluate, searches_cell

log = logging.getLogger("beyond_range")
RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "beyond_range.json", "beyond_range.md",
)
DOMAINS = ("walker", "manipulator", "snake", "lane_change")  # the default, and the report's row order
MODES = {"library": False, "gen": True}  # a row's mode -> whether the agent generates


def measure(domain: str, mode: str, args: argparse.Namespace, simulate: Simulate | None = None) -> dict:
    """One row: RBA-Global one-hot on ``args.targets`` targets beyond the range, generating or not; ``simulate``:
    where a generating row simulates its candidates (``Compute.simulate``; None: this process)."""
    ctx = load_context(domain, "global", "onehot")
    generate = MODES[mode]
    r: EvalResult = evaluate(domain, "global", "onehot", args.targets, args.seed, args.precision, "paper",
                             context=ctx, generate=generate, beyond=args.share,
                             gen_config=GenerationConfig(seconds=args.gen_seconds) if generate else None,
                             simulator=simulate)
    row = {"domain": domain, "mode": mode, "share": args.share, "precision": args.precision, "seed": args.seed,
           "targets": len(r.trials), "success_rate": r.success_rate, "avg_feedback": r.avg_feedback,
           "std_feedback": r.std_feedback, "seconds": round(r.seconds, 1), "generation": r.generation,
           "bound_s": args.gen_seconds if generate else None,
           "date": time.strftime("%Y-%m-%d %H:%M")}
    log.info("%s", row)
    return row


def _key(row: dict) -> tuple:
    """A row's identity within one setting: a bounded search's row does not replace the unbounded one."""
    return row["domain"], row["mode"], row.get("bound_s")


def markdown(report: dict) -> str:
    lines = ["# Targets beyond the serve range", "",
             f"RBA-Global one-hot, the paper's user, {report['precision']}-precision ε, targets up to "
             f"{report['share']:.0%} of each proxy's serve range beyond it (rollouts the skill made: "
             "`rba.interact.evaluate.beyond_targets`, seed "
             f"{report['seed']}). *library*: serve clips only; *gen*: the agent also makes clips when none is near "
             "its target (`rba eval`'s default). SR / AF (std), AF over successful trials, 500-feedback budget.", "",
             "*search bound*: `--gen-seconds` (`GenerationConfig.seconds`, as the app's `RBA_GENERATE_SECONDS`); "
             "–: the 48-simulation budget alone.", "",
             "| domain | mode | targets | SR / AF (std) | searches (shown) | simulations | search bound | seconds | "
             "measured |", "|---|---|---:|---|---:|---:|---|---:|---|"]
    for r in sorted(report["rows"], key=lambda r: (DOMAINS.index(r["domain"]) if r["domain"] in DOMAINS else 99,
                                                     r["mode"] != "library", r.get("bound_s") or 0.0)):
        af, searches = af_cell(r["avg_feedback"], r["std_feedback"]), searches_cell(r["generation"])
        g = r["generation"] or {}
        bound = "–" if r.get("bound_s") is None else f"{r['bound_s']:g} s"
        lines.append(f"| {r['domain']} | {r['mode']} | {r['targets']} | {r['success_rate']:.2f} / {af} | {searches} "
                     f"| {g.get('simulations', '–')} | {bound} | {r['seconds']:.0f} | {r['date']} |")
    lines += ["", f"Command: `{report['command']}` ({report['machine']}); rows of other domains come from earlier "
              "runs of the same script (their date)."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--domains", nargs="+", choices=domain_names(), default=list(DOMAINS))
    ap.add_argument("--modes", nargs="+", choices=list(MODES), default=list(MODES))
    ap.add_argument("--share", type=float, default=0.1, help="how far beyond the serve range, a share of it")
    ap.add_argument("--precision", choices=("normal", "high"), default="normal")
    ap.add_argument("--targets", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--gen-seconds", type=seconds_arg, default=None, help="bound each search in time as the app does "
                    "(GenerationConfig.seconds); default: the simulation budget alone")
    ap.add_argument("--gen-workers", type=int, default=1, help="local processes simulating a search's candidates "
                    "(1: this process); an unbounded row does not depend on it")
    ap.add_argument("--out", type=Path, default=RESULTS / "beyond_range", help="writes <out>.json and <out>.md")
    args = ap.parse_args(argv)
    if args.gen_workers < 1:
        ap.error(f"--gen-workers must be at least 1, got {args.gen_workers}")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    setting = {"share": args.share, "precision": args.precision, "seed": args.seed}
    report = report_to_extend(args.out, setting, "python benchmarks/beyond_range.py " + " ".join(argv or sys.argv[1:]))
    with simulation_pool(args.gen_workers) as simulate:
        for domain in args.domains:
            for mode in args.modes:
                row = measure(domain, mode, args, simulate)
                report["rows"] = [r for r in report["rows"] if _key(r) != _key(row)] + [row]
                save_report(args.out, report, markdown(report))  # after every row: a stopped run keeps what it has
    return 0


if __name__ == "__main__":
    sys.exit(main())
