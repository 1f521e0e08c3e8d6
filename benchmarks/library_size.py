"""How small a serve library generation needs: SR / AF of RBA-Global over the library's first N clips, alone and
generating.

The goal: no domain needs a library larger than 1,200 serve rollouts (decision 0020). Each row is ``rba eval --domain D
--method global --precision P --split test --targets T --seed S --serve-size N [--no-generate]``: the agent
chooses among the serve library's first N clips (a random sample: the library's parameters come from one seeded
stream); ε, the targets and the users are the whole library's, whatever N. Rows of an earlier run in the same
setting (precision, split, seed, targets) in ``--out``'s .json are kept for (domain, size, mode) this run does not
measure, so domains can run in parallel and be combined.
Writes ``benchmarks/results/library_size.md`` and ``.json``.

    python benchmarks/library_size.py --domains walker manipulator lane_change --sizes 300 600 1200
    python benchmarks/library_size.py --domains snake --sizes 600 --modes gen   # one row, the others kept
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

from rba.compute import simulation_pool
from rba.core.fileio import report_to_extend, save_report
from rba.domains import domain_names
from rba.generate.cma import Simulate
from rba.interact import load_context
from rba.interact.evaluate import EvalResult, af_cell, evaluate, searches_cell
from rba.interact.global_agent import GlobalContext

log = logging.getLogger("library_size")
RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "library_size.json", "library_size.md",
)
DOMAINS = ("walker", "manipulator", "snake", "lane_change")  # the report's row order
MODES = {"library": False, "gen": True}  # a row's mode -> whether the agent generates
MISS = 500  # answers a failed trial counts in a row's *answers in all*: the evaluation's feedback budget


def measure(context: GlobalContext, size: int, mode: str, args: argparse.Namespace, simulate: Simulate | None
            ) -> dict:
    """One row: RBA-Global one-hot over the first ``size`` clips of ``context``'s serve library, generating or not."""
    generate, domain = MODES[mode], context.domain
    r: EvalResult = evaluate(domain, "global", "onehot", args.targets, args.seed, args.precision, "paper",
                             context=context, split=args.split,
                             generate=generate, serve_size=size, simulator=simulate)
    answers = sum(t.feedback_count if t.success else MISS for t in r.trials)
    row = {"domain": domain, "size": size, "mode": mode, "targets": len(r.trials), "success_rate": r.success_rate,
           "avg_feedback": r.avg_feedback, "std_feedback": r.std_feedback, "answers": answers,
           "longest": max((t.feedback_count for t in r.trials if t.success), default=None),
           "generation": r.generation, "seconds": round(r.seconds, 1), "date": time.strftime("%Y-%m-%d %H:%M")}
    log.info("%s", row)
    return row


def _key(row: dict) -> tuple:
    return row["domain"], row["size"], row["mode"]


def markdown(report: dict) -> str:
    lines = ["# How small a serve library generation needs", "",
             f"RBA-Global one-hot, the paper's user, {report['precision']}-precision ε, {report['targets']} "
             f"{report['split']} targets (seed {report['seed']}). *size*: the agent chooses among the serve "
             "library's first N clips (ε, targets and users are the whole library's). *library*: those clips "
             "only; *gen*: the agent also makes clips when none is near its target (`rba eval`'s default). "
             "SR / AF (std): AF over successful trials, 500-answer budget; *answers in all*: every trial's "
             f"answers, a failure counting {MISS}.", "",
             "| domain | size | mode | targets | SR / AF (std) | answers in all | longest success | searches (shown) | "
             "simulations | seconds | measured |", "|---|---:|---|---:|---|---:|---:|---:|---:|---:|---|"]
    for r in sorted(report["rows"], key=lambda r: (DOMAINS.index(r["domain"]) if r["domain"] in DOMAINS else 99,
                                                     r["size"], r["mode"] != "library")):
        af, searches = af_cell(r["avg_feedback"], r["std_feedback"]), searches_cell(r["generation"])
        g = r["generation"] or {}
        lines.append(f"| {r['domain']} | {r['size']:,} | {r['mode']} | {r['targets']} | {r['success_rate']:.2f} / "
                     f"{af} | {r['answers']:,} | {r['longest'] if r['longest'] is not None else '–'} | {searches} | "
                     f"{g.get('simulations', '–')} | {r['seconds']:.0f} | {r['date']} |")
    lines += ["", f"Command: `{report['command']}` ({report['machine']}); rows measured by other runs of the same "
              "script keep their date."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--domains", nargs="+", choices=domain_names(), default=list(DOMAINS))
    ap.add_argument("--sizes", nargs="+", type=int, default=[300, 600, 1200], help="first N serve clips, per row")
    ap.add_argument("--modes", nargs="+", choices=list(MODES), default=list(MODES))
    ap.add_argument("--precision", choices=("normal", "high"), default="high")
    ap.add_argument("--split", choices=("val", "test"), default="test")
    ap.add_argument("--targets", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--gen-workers", type=int, default=1, help="local processes simulating a search's candidates "
                    "(1: this process); the rows do not depend on it")
    ap.add_argument("--out", type=Path, default=RESULTS / "library_size", help="writes <out>.json and <out>.md")
    args = ap.parse_args(argv)
    if args.gen_workers < 1:
        ap.error(f"--gen-workers must be at least 1, got {args.gen_workers}")
    if min(args.sizes) < 2:
        ap.error(f"--sizes are numbers of serve clips (at least 2), got {min(args.sizes)}")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    setting = {"precision": args.precision, "split": args.split, "seed": args.seed, "targets": args.targets}
    report = report_to_extend(args.out, setting, "python benchmarks/library_size.py " + " ".join(argv or sys.argv[1:]))
    with simulation_pool(args.gen_workers) as simulate:
        for domain in args.domains:
            context = load_context(domain, "global", "onehot")  # each row reads a copy: ``GlobalContext.first``
            for size in args.sizes:
                for mode in args.modes:
                    row = measure(context, size, mode, args, simulate)
                    report["rows"] = [r for r in report["rows"] if _key(r) != _key(row)] + [row]
                    save_report(args.out, report, markdown(report))  # after every row: a stopped run keeps its rows
    return 0


if __name__ == "__main__":
    sys.exit(main())
