"""The paper's tables for every domain and method: high precision (the headline) and normal precision.

For each registered domain with a library and trained models: every registered method with each
representation it runs with (RBA-Global, RBA-Global-L, RBA-Local, RBA-Local-L, PbRL), between two
reference rows, Random (the floor: random serve clips) and Oracle (the ceiling the library allows:
bisection on the true proxies), 20 held-out targets each (ARCHITECTURE §5), beside the paper's numbers.
ε is a fraction of each proxy's robust range over the serve library (``Domain.epsilons``). Writes
``benchmarks/results/paper_tables.md`` (and ``.json``).

    python benchmarks/paper_tables.py                         # every domain, both precisions
    python benchmarks/paper_tables.py --domains lane_change --precisions normal --targets 5
    python benchmarks/paper_tables.py --domains snake --merge benchmarks/results/paper_tables.json
                                                    # re-measure one domain, keep the others' rows
    python benchmarks/paper_tables.py --report-only --merge a.json b.json   # combine parallel runs
    python benchmarks/paper_tables.py --domains walker --check benchmarks/results/paper_tables.json
                                                    # re-measure, compare with the report (exit 1 if a row differs)
"""

from __future__ import annotations

import argparse
import datetime as dt
import logging
import platform
import sys
from pathlib import Path

from rba.artifacts import ModelNotFoundError
from rba.domains import domain_names
from rba.evaluate import EvalResult, evaluate
from rba.interact import load_context
from rba.library import LibraryNotFoundError
from rba.methods import methods
from rba.storage import load_json, save_json, save_text

log = logging.getLogger("paper_tables")
RESULTS = Path(__file__).resolve().parent / "results"
# The rows: the random floor, every registered method with each representation it runs with, the oracle
# ceiling, as (method, rep, label).
_ORDER = {"floor": 0, None: 1, "ceiling": 2}
_ROWS = sorted(methods(include_reference=True), key=lambda m: _ORDER[m.reference])
METHODS = [(m.name, rep, m.label_for(rep)) for m in _ROWS for rep in m.run_reps]
LABELS = [label for _, _, label in METHODS]  # the tables' row order
# The paper's Tables 1 and 2: (SR, AF, std of AF) per row of PAPER_LABELS; AF None where the paper has N/A.
PAPER_LABELS = ("RBA-Global", "RBA-Global-L", "RBA-Local", "RBA-Local-L", "PbRL")
PAPER = {
    "normal": {
        "lane_change": [(0.95, 3.95, 2.43), (1.0, 3.05, 2.06), (0.7, 7.07, 3.49), (0.9, 5.78, 4.04), (1.0, 162.3, 184)],
        "manipulator": [(1.0, 2.8, 1.21), (1.0, 2.5, 1.32), (0.7, 12.23, 5.75), (0.8, 10.75, 6.35),
                        (0.6, 159.5, 188.87)],
        "snake": [(0.85, 4.17, 1.85), (0.8, 6.38, 5.03), (0.55, 6.45, 3.82), (0.6, 4.17, 2.11), (0.05, None, None)],
        "walker": [(1.0, 3.75, 1.47), (0.95, 3.78, 2.25), (0.95, 5.47, 3.52), (0.9, 5.16, 3.08), (1.0, 84.6, 79.87)],
    },
    "high": {
        "lane_change": [(0.6, 6.75, 2.98), (0.7, 6.79, 1.66), (0.25, 5.0, 0.63), (0.4, 8.63, 2.45),
                        (0.35, 286.22, 167.49)],
        "manipulator": [(0.8, 7.0, 2.45), (0.75, 5.47, 3.2), (0.45, 19.44, 5.57), (0.3, 10.5, 5.5),
                        (0.15, 81.33, 66.97)],
        "snake": [(0.55, 8.0, 3.67), (0.25, 10.4, 6.02), (0.3, 8.16, 3.18), (0.5, 7.2, 4.621), (0.05, None, None)],
        "walker": [(0.7, 7.29, 2.63), (0.75, 6.0, 3.59), (0.4, 9.37, 4.15), (0.4, 6.25, 2.48), (0.35, 288.0, 143.45)],
    },
}

PAPER_ROW = {"lane_change_image": "lane_change"}  # the paper's lane change observes images
PRECISIONS = ("high", "normal")  # the tables' order: high precision is the headline
TITLES = {"high": "Table 1 — high precision (the headline; the paper's Table 2)",
          "normal": "Table 2 — normal precision (the paper's Table 1)"}


def _cell(sr: float, af: float | None, sd: float | None) -> str:
    return f"{sr:.2f} / " + ("–" if af is None else f"{af:.2f} ({sd:.2f})")


def run(domains: list[str], precisions: list[str], targets: int, seed: int,
        labels: list[str], on_row=None) -> list[tuple[str, str, EvalResult]]:
    """Evaluate every requested domain × method × precision; ``on_row(rows so far)`` after each."""
    out = []
    for domain in domains:
        for method, rep, label in METHODS:
            if label not in labels:
                continue
            try:
                ctx = load_context(domain, method, rep)
            except (ModelNotFoundError, LibraryNotFoundError) as exc:
                log.warning("%s %s: not measured (%s)", domain, label, exc)
                continue
            for precision in precisions:
                r = evaluate(domain, method, rep, targets, seed, precision=precision, context=ctx)
                log.info("%s %s %s: SR %.2f AF %s (%.0f s)", domain, label, precision, r.success_rate,
                         r.avg_feedback, r.seconds)
                out.append((domain, label, r))
                if on_row:
                    on_row(out)
    return out


def merged(rows, paths: list[Path]) -> list:
    """Rows of earlier runs' JSON (a later file's row replaces an earlier one's), then this run's rows."""
    kept: dict[tuple[str, str, str], tuple] = {}
    for path in paths:
        for row in map(_with_user, load_json(path)):
            result = EvalResult(**{**{k: v for k, v in row.items() if k != "label"}, "trials": []})
            kept[(result.domain, row["label"], result.precision)] = (result.domain, row["label"], result)
    for domain, label, result in rows:
        kept[(domain, label, result.precision)] = (domain, label, result)
    return sorted(kept.values(), key=lambda x: (x[0], LABELS.index(x[1])))


def _with_user(row: dict) -> dict:
    """A stored row with its user spec: reports written before teacher kinds have ``noise`` (mistake's p)."""
    if "noise" not in row:
        return row
    noise = row.pop("noise")
    return {**row, "user": f"mistake:{noise:g}" if noise else "paper"}


RESULT_FIELDS = ("success_rate", "avg_feedback", "std_feedback")


def check(rows, stored: Path) -> tuple[str, bool]:
    """This run's rows beside ``stored``'s (same domain, label, precision): (a Markdown table, all equal?).

    Evaluation is seeded, so the same models and libraries must give exactly the same SR / AF.
    """
    kept = {(row["domain"], row["label"], row["precision"]): row for row in load_json(stored)}
    lines = ["| domain | method | precision | stored | measured | same |", "|---|---|---|---|---|---|"]
    same_all = True
    for domain, label, r in rows:
        old = kept.get((domain, label, r.precision))
        same = old is not None and all(old[k] == getattr(r, k) for k in RESULT_FIELDS)
        same_all &= same
        was = "missing" if old is None else _cell(*(old[k] for k in RESULT_FIELDS))
        lines.append(f"| {domain} | {label} | {r.precision} | {was} | "
                     f"{_cell(*(getattr(r, k) for k in RESULT_FIELDS))} | {'yes' if same else 'NO'} |")
    return "\n".join(lines), same_all


def json_rows(rows) -> list[dict]:
    """The report's JSON: one object per row, its label and result without the per-trial detail."""
    return [{"label": label, **{k: v for k, v in r.to_json().items() if k != "trials"}} for _, label, r in rows]


def markdown(rows, domains: list[str], precisions: list[str], targets: int, seed: int, seconds: float) -> str:
    lines = ["# The paper's tables, measured", "",
             f"{targets} held-out targets per domain and method (seed {seed}), 500-feedback budget; AF over "
             "successful trials (PbRL: binary labels). Ours beside the paper's (SR / AF (std)). Random (the floor: "
             "random serve clips) and Oracle (the ceiling the library allows: bisection on the true proxies) frame "
             "the methods. ε is 1/7 (normal) or 1/42 (high) of each proxy's 1st–99th percentile range over serve.",
             ""]
    for precision in sorted(precisions, key=PRECISIONS.index):
        lines += [f"## {TITLES[precision]}", "", "| domain | method | ours | paper |", "|---|---|---|---|"]
        for domain, label, r in rows:
            if r.precision != precision:
                continue
            paper = PAPER[precision].get(PAPER_ROW.get(domain, domain))
            paper_cell = _cell(*paper[PAPER_LABELS.index(label)]) if paper and label in PAPER_LABELS else "–"
            lines.append(f"| {domain} | {label} | {_cell(r.success_rate, r.avg_feedback, r.std_feedback)} | "
                         f"{paper_cell} |")
        lines.append("")
    methods = " ".join(sorted({label for _, label, _ in rows}, key=LABELS.index))
    command = (f"python benchmarks/paper_tables.py --domains {' '.join(domains)} --precisions {' '.join(precisions)} "
               f"--methods {methods} --targets {targets} --seed {seed}")
    lines += [f"Command: `{command}`; {seconds / 60:.1f} min of evaluation; {dt.date.today().isoformat()}, "
              f"Python {platform.python_version()}, CPU only.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--domains", nargs="+", default=list(domain_names()), choices=domain_names())
    ap.add_argument("--precisions", nargs="+", default=list(PRECISIONS), choices=PRECISIONS)
    ap.add_argument("--methods", nargs="+", default=LABELS, choices=LABELS)
    ap.add_argument("--targets", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=RESULTS / "paper_tables.md")
    ap.add_argument("--merge", type=Path, nargs="+", default=[],
                    help="earlier runs' .json (later files win): keep their rows for what this run does not measure")
    ap.add_argument("--report-only", action="store_true",
                    help="measure nothing: write the report from the --merge files (runs made in parallel)")
    ap.add_argument("--check", type=Path, metavar="REPORT_JSON",
                    help="re-measure and compare with this report instead of writing one; exit 1 if a row differs")
    args = ap.parse_args(argv)
    if args.report_only and not args.merge:
        ap.error("--report-only needs --merge: the .json files of the runs to report")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")

    def write(rows) -> str:  # after every row: a long run stopped early still leaves its measured rows
        rows = merged(rows, args.merge)
        seconds = sum(r.seconds for *_, r in rows)  # evaluation time of every row in the report
        shown = [p for p in PRECISIONS if p in args.precisions or any(r.precision == p for *_, r in rows)]
        text = markdown(rows, sorted({d for d, *_ in rows}), shown, args.targets, args.seed, seconds)
        save_text(args.out, text)
        save_json(args.out.with_suffix(".json"), json_rows(rows))
        return text

    if args.check:
        text, same = check(run(args.domains, args.precisions, args.targets, args.seed, args.methods), args.check)
        print(text)
        sys.exit(0 if same else 1)
    rows = [] if args.report_only else run(args.domains, args.precisions, args.targets, args.seed, args.methods,
                                           on_row=write)
    print(write(rows))


if __name__ == "__main__":
    main()
