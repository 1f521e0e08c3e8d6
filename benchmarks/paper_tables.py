"""The paper's tables for every domain and method: high precision (the headline) and normal precision.

For each registered domain with a library and trained models: every registered method with each
representation it runs with (RBA-Global, RBA-Global-L, RBA-Local, RBA-Local-L, PbRL), between two
reference rows, Random (the floor: random serve clips) and Oracle (the ceiling the library allows:
bisection on the true proxies), 20 targets of the ``test`` split each (docs/architecture.md §5), beside the paper's
numbers, with the paper's user; ``RBA-Global+gen`` is RBA-Global making clips beyond the library
(``rba.interact.generating_agent``). ``--users KIND ...`` adds one table per teacher kind (RBA-Global and RBA-Local,
one-hot, normal precision, over the four hand-made domains); raw state views (``<domain>_raw``, just more
``--domains``) are shown beside their hand-made view; the label-noise report is linked when it exists.
ε is a fraction of each proxy's robust range over the serve library (``Domain.epsilons``). Writes
``benchmarks/results/paper_tables.md`` (and ``.json``: one object per row, with its ``user``, ``split``, ``epsilon``).

    python benchmarks/paper_tables.py                         # every domain, both precisions
    python benchmarks/paper_tables.py --users mistake skip equal myopic boundary inconsistent
                                                    # ... and one table per teacher kind
    python benchmarks/paper_tables.py --domains lane_change --precisions normal --targets 5
    python benchmarks/paper_tables.py --domains snake --merge benchmarks/results/paper_tables.json
                                                    # re-measure one domain, keep the others' rows
    python benchmarks/paper_tables.py --report-only --merge a.json b.json   # combine parallel runs
    python benchmarks/paper_tables.py --domains walker --check benchmarks/results/paper_tables.json
                                                    # re-measure, compare with the report (exit 1 if a row differs)

Merged rows must carry ``split: "test"`` and the current ε (``epsilon_definition``): rows of an older report
(measured on the old test split, or with another ε) are refused, never reused.
"""

from __future__ import annotations

import argparse
import datetime as dt
import logging
import os
import platform
import sys
from pathlib import Path

from rba.compute import simulation_pool
from rba.core.artifacts import ModelNotFoundError
from rba.core.fileio import load_json, report_path, save_json, save_markdown
from rba.core.methods import methods
from rba.data.library import LibraryNotFoundError
from rba.domains import domain_names
from rba.domains.base import EPSILON_FRACTIONS, ROBUST_QUANTILES
from rba.generate.cma import Simulate
from rba.interact import load_context
from rba.interact.evaluate import EvalResult, evaluate
from rba.interact.users import USER_KINDS, UserSpec, parse_user

log = logging.getLogger("paper_tables")
RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "paper_tables.json", "paper_tables.md",
)
LABEL_NOISE = RESULTS / "label_noise.md"  # the ζσ label-noise report (its own benchmark); linked when it exists
SPLIT = "test"  # every reported row's targets: `test` is touched only by `rba eval` and these tables
PAPER_USER = "paper"  # the user of the paper's tables
# The rows: the random floor, every registered method with each representation it runs with, the oracle
# ceiling, as (method, rep, label).
_ORDER = {"floor": 0, None: 1, "ceiling": 2}
_ROWS = sorted(methods(include_reference=True), key=lambda m: _ORDER[m.reference])
GENERATING = "RBA-Global+gen"  # RBA-Global one-hot making clips beyond the serve library (rba eval's default)
METHODS = [(m.name, rep, m.label_for(rep), False) for m in _ROWS for rep in m.run_reps]
METHODS.insert(METHODS.index(("global", "onehot", "RBA-Global", False)) + 1, ("global", "onehot", GENERATING, True))
LABELS = [label for _, _, label, _ in METHODS]  # the tables' row order
# The teacher-kind tables: these rows (one-hot), normal precision, the hand-made views of the paper's domains.
USER_LABELS = ("Random", "RBA-Global", "RBA-Local", "Oracle")  # the floor and the ceiling with the same user
USER_DOMAINS = ("walker", "manipulator", "lane_change", "snake")
USER_PRECISION = "normal"
RAW_SUFFIX = "_raw"  # a domain's raw state view (the simulator's positions and velocities) is "<domain>_raw"
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
TITLES = {"high": "Table 2 — high precision (the headline)", "normal": "Table 1 — normal precision"}

Row = tuple[str, str, EvalResult]  # (domain, label, result)
# The ε of rows stored with a split but no "epsilon" (reports written before rows carried it): the robust ε came
# before the split field, so those rows were measured with this one; they merge while it is still the current ε.
EPSILON_BEFORE_STORED = {"normal": "0.142857 x (p1-p99 of serve proxies)",
                         "high": "0.0238095 x (p1-p99 of serve proxies)"}


def epsilon_definition(precision: str) -> str:
    """What ε is at ``precision`` (stored with every row: a row measured with another ε is not merged)."""
    lo, hi = ROBUST_QUANTILES
    return f"{EPSILON_FRACTIONS[precision]:.6g} x (p{lo:g}-p{hi:g} of serve proxies)"


def _cell(sr: float, af: float | None, sd: float | None) -> str:
    return f"{sr:.2f} / " + ("–" if af is None else f"{af:.2f} ({sd:.2f})")


def _result_cell(r: EvalResult | None) -> str:
    return "–" if r is None else _cell(r.success_rate, r.avg_feedback, r.std_feedback)


def _jobs(domain: str, label: str, precisions: list[str], labels: list[str],
          users: list[UserSpec]) -> list[tuple[str, str]]:
    """(user, precision) to measure for one domain and row: the paper's user, then each teacher kind."""
    if label not in labels:
        return []
    jobs = [(PAPER_USER, p) for p in precisions]
    if domain in USER_DOMAINS and label in USER_LABELS:
        jobs += [(str(u), USER_PRECISION) for u in users if (str(u), USER_PRECISION) not in jobs]
    return jobs


def run(domains: list[str], precisions: list[str], targets: int, seed: int, labels: list[str],
        on_row=None, users: list[UserSpec] = (), simulate: Simulate | None = None) -> list[Row]:
    """Evaluate every requested domain × method × precision (and teacher kind); ``on_row(rows so far)`` after each.

    ``simulate``: where generating rows simulate their candidates (``Compute.simulate``); None: this process.
    Either way the same rollouts, so the same rows."""
    out = []
    for domain in domains:
        for method, rep, label, generate in METHODS:
            jobs = _jobs(domain, label, precisions, labels, list(users))
            if not jobs:
                continue
            try:
                ctx = load_context(domain, method, rep)
            except (ModelNotFoundError, LibraryNotFoundError) as exc:
                log.warning("%s %s: not measured (%s)", domain, label, exc)
                continue
            for user, precision in jobs:
                r = evaluate(domain, method, rep, targets, seed, precision=precision, user=user, context=ctx,
                             split=SPLIT, generate=generate, simulator=simulate)
                log.info("%s %s %s %s: SR %.2f AF %s (%.0f s)", domain, label, precision, user, r.success_rate,
                         r.avg_feedback, r.seconds)
                out.append((domain, label, r))
                if on_row:
                    on_row(out)
    return out


class StaleRowError(ValueError):
    """A stored row that may not be merged: no split, another split or another ε."""


def _stored_result(row: dict, path: Path) -> EvalResult:
    """A stored row as an ``EvalResult``, if it was measured the way these tables measure; else StaleRowError."""
    what = f"{path}: row {row.get('domain')} {row.get('label')} {row.get('precision')} {row.get('user', '?')}"
    if "split" not in row:
        raise StaleRowError(f"{what} has no split (measured before the val/test split, on the old test "
                            f"targets): re-measure it, do not merge it")
    if row["split"] != SPLIT:
        raise StaleRowError(f"{what} was measured on split {row['split']!r}; the tables report {SPLIT!r} only")
    epsilon = row.get("epsilon", EPSILON_BEFORE_STORED.get(row["precision"]))
    if epsilon != epsilon_definition(row["precision"]):
        raise StaleRowError(f"{what} was measured with ε {epsilon!r}; the tables use "
                            f"{epsilon_definition(row['precision'])!r}")
    return EvalResult(**{**{k: v for k, v in row.items() if k not in ("label", "epsilon")}, "trials": []})


def _key(domain: str, label: str, r: EvalResult) -> tuple[str, str, str, str]:
    return domain, label, r.precision, r.user


def merged(rows: list[Row], paths: list[Path]) -> list[Row]:
    """Rows of earlier runs' JSON (a later file's row replaces an earlier one's), then this run's rows.

    A stored row without ``split: "test"`` and the current ε is refused (StaleRowError), never reused.
    """
    kept: dict[tuple[str, str, str, str], Row] = {}
    for path in paths:
        for row in load_json(path):
            result = _stored_result(row, path)
            kept[_key(result.domain, row["label"], result)] = (result.domain, row["label"], result)
    for domain, label, result in rows:
        kept[_key(domain, label, result)] = (domain, label, result)
    return sorted(kept.values(), key=lambda x: (x[0], LABELS.index(x[1]), x[2].user))


RESULT_FIELDS = ("success_rate", "avg_feedback", "std_feedback")


def check(rows: list[Row], stored: Path) -> tuple[str, bool]:
    """This run's rows beside ``stored``'s (same domain, label, precision, user): (a Markdown table, all equal?).

    Evaluation is seeded, so the same models and libraries must give exactly the same SR / AF.
    """
    kept = {(row["domain"], row["label"], row["precision"], row.get("user", PAPER_USER)): row
            for row in load_json(stored)}
    lines = ["| domain | method | precision | user | stored | measured | same |", "|---|---|---|---|---|---|---|"]
    same_all = True
    for domain, label, r in rows:
        old = kept.get(_key(domain, label, r))
        same = old is not None and all(old[k] == getattr(r, k) for k in RESULT_FIELDS)
        same_all &= same
        was = "missing" if old is None else _cell(*(old[k] for k in RESULT_FIELDS))
        lines.append(f"| {domain} | {label} | {r.precision} | {r.user} | {was} | {_result_cell(r)} | "
                     f"{'yes' if same else 'NO'} |")
    return "\n".join(lines), same_all


def json_rows(rows: list[Row]) -> list[dict]:
    """The report's JSON: one object per row, its label, result and ε definition, without the per-trial detail."""
    return [{"label": label, **{k: v for k, v in r.to_json().items() if k != "trials"},
             "epsilon": epsilon_definition(r.precision)} for _, label, r in rows]


def _main_table(rows: list[Row], precision: str) -> list[str]:
    lines = [f"## {TITLES[precision]}", "", f"User: `{PAPER_USER}` (the paper's: more/less beyond ε, never wrong). "
             f"ε = {epsilon_definition(precision)}.", "", "| domain | method | ours | paper |", "|---|---|---|---|"]
    for domain, label, r in rows:
        if r.precision != precision or r.user != PAPER_USER:
            continue
        paper = PAPER[precision].get(PAPER_ROW.get(domain, domain.removesuffix(RAW_SUFFIX)))
        paper_cell = _cell(*paper[PAPER_LABELS.index(label)]) if paper and label in PAPER_LABELS else "–"
        lines.append(f"| {domain} | {label} | {_result_cell(r)} | {paper_cell} |")
    return [*lines, ""]


def _state_views(rows: list[Row]) -> list[str]:
    """Each raw-view row beside the hand-made view's (the paper's user); nothing if no raw view was measured."""
    found = {(d, label, r.precision): r for d, label, r in rows if r.user == PAPER_USER}
    raw = [(d, label, p) for d, label, p in found if d.endswith(RAW_SUFFIX)]
    if not raw:
        return []
    lines = ["## State views", "", "The hand-made view's states carry features close to the proxies; the raw view "
             "(`<domain>_raw`) gives the models the simulator's own positions and velocities, nothing derived from "
             f"the proxies: the honest number. User `{PAPER_USER}`.", "",
             "| domain | method | precision | hand-made | raw |", "|---|---|---|---|---|"]
    for d, label, p in sorted(raw, key=lambda k: (k[0], LABELS.index(k[1]), PRECISIONS.index(k[2]))):
        base = d.removesuffix(RAW_SUFFIX)
        lines.append(f"| {base} | {label} | {p} | {_result_cell(found.get((base, label, p)))} | "
                     f"{_result_cell(found[(d, label, p)])} |")
    return [*lines, ""]


def _user_tables(rows: list[Row]) -> list[str]:
    """One table per teacher kind measured (other than the paper's user): domains × Random, RBA-Global,
    RBA-Local and Oracle, all with that user."""
    by_user: dict[str, dict[tuple[str, str], EvalResult]] = {}
    for d, label, r in rows:
        if r.user != PAPER_USER and r.precision == USER_PRECISION and label in USER_LABELS:
            by_user.setdefault(r.user, {})[(d, label)] = r
    if not by_user:
        return []
    lines = ["## Teacher kinds", "", "B-Pref's teachers adapted to attribute feedback (`rba/interact/users.py`), "
             f"each at its default strength; one-hot, {USER_PRECISION} precision (ε = "
             f"{epsilon_definition(USER_PRECISION)}). A trial succeeds if the true proxies of the clip the user "
             "stops at are within ε of its (current) target. Random (the floor) and Oracle (the ceiling: bisection "
             "on the true proxies) answer to the same user, so a user who stops on a miss caps even the Oracle.", ""]
    for user in sorted(by_user, key=lambda u: (list(USER_KINDS).index(parse_user(u).kind), u)):
        cells = by_user[user]
        domains = sorted({d for d, _ in cells}, key=lambda d: (d not in USER_DOMAINS, d))
        lines += [f"### User `{user}`", "", "| domain | " + " | ".join(USER_LABELS) + " |",
                  "|---|" + "---|" * len(USER_LABELS)]
        lines += [f"| {d} | " + " | ".join(_result_cell(cells.get((d, lab))) for lab in USER_LABELS) + " |"
                  for d in domains]
        lines.append("")
    return lines


def _labels_section(out: Path, label_report: Path) -> list[str]:
    """A link to the ζσ label-noise report (pairwise labels with noise and "can't tell"), when it exists."""
    if not label_report.exists():
        return []
    link = os.path.relpath(label_report, out.parent)
    return ["## Labels", "", "ζσ trained from what people can give (pairwise comparisons with Bradley–Terry noise "
            f"and \"can't tell\" answers) against the perfect order: [{label_report.name}]({link}).", ""]


def markdown(rows: list[Row], domains: list[str], precisions: list[str], targets: int, seed: int, seconds: float,
             users: list[str] = (), out: Path = RESULTS / "paper_tables.md",
             label_report: Path = LABEL_NOISE) -> str:
    lines = ["# The paper's tables, measured", "",
             f"{targets} targets per domain and method from the `{SPLIT}` split (seed {seed}; settings were tuned "
             "on `val`, never on `test`), 500-feedback budget; AF over successful trials (PbRL: binary labels). Ours "
             "beside the paper's (SR / AF (std)). Random (the floor: random serve clips) and Oracle (the ceiling the "
             "library allows: bisection on the true proxies) frame the methods; they, and every other row, show serve "
             f"clips only. {GENERATING} is RBA-Global one-hot that also makes clips beyond the serve library when "
             "none is near its target (CMA-ES over the skill's parameters, `rba eval`'s default; the user judges a "
             "made clip by its own simulation), so the Oracle is not its ceiling. ε is 1/7 (normal) or 1/42 (high) "
             "of each proxy's robust range over the serve library: its 1st to 99th percentile.", ""]
    for precision in sorted(precisions, key=PRECISIONS.index):
        lines += _main_table(rows, precision)
    lines += _state_views(rows) + _user_tables(rows) + _labels_section(out, label_report)
    methods_ = " ".join(sorted({label for _, label, _ in rows}, key=LABELS.index))
    command = (f"python benchmarks/paper_tables.py --domains {' '.join(domains)} --precisions {' '.join(precisions)} "
               f"--methods {methods_} --targets {targets} --seed {seed}")
    command += f" --users {' '.join(users)}" if users else ""
    lines += [f"Command: `{command}`; {seconds / 60:.1f} min of evaluation; {dt.date.today().isoformat()}, "
              f"Python {platform.python_version()}, CPU only.", ""]
    return "\n".join(lines)


def _user_spec(text: str) -> UserSpec:
    """argparse type of ``--users``: a teacher kind ``KIND[:param]``; the message names the valid kinds."""
    try:
        return parse_user(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--domains", nargs="+", default=list(domain_names()), choices=domain_names())
    ap.add_argument("--precisions", nargs="+", default=list(PRECISIONS), choices=PRECISIONS)
    ap.add_argument("--methods", nargs="+", default=LABELS, choices=LABELS)
    ap.add_argument("--users", nargs="+", type=_user_spec, default=[], metavar="KIND[:param]",
                    help=f"one table per teacher kind ({', '.join(USER_KINDS)}): {', '.join(USER_LABELS)} one-hot "
                         f"(those of --methods), {USER_PRECISION} precision, on {', '.join(USER_DOMAINS)} "
                         "(of --domains)")
    ap.add_argument("--targets", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=RESULTS / "paper_tables.md")
    ap.add_argument("--merge", type=Path, nargs="+", default=[],
                    help="earlier runs' .json (later files win): keep their rows for what this run does not measure; "
                         f"only rows of split {SPLIT!r} with the current ε")
    ap.add_argument("--report-only", action="store_true",
                    help="measure nothing: write the report from the --merge files (runs made in parallel)")
    ap.add_argument("--gen-workers", type=int, default=1,
                    help=f"local processes simulating {GENERATING}'s candidates (1: this process); the rows do "
                         "not depend on it")
    ap.add_argument("--check", type=Path, metavar="REPORT_JSON",
                    help="re-measure and compare with this report instead of writing one; exit 1 if a row differs")
    return ap


def main(argv: list[str] | None = None) -> None:
    ap = _parser()
    args = ap.parse_args(argv)
    if args.report_only and not args.merge:
        ap.error("--report-only needs --merge: the .json files of the runs to report")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    try:
        merged([], args.merge)  # refuse stale rows before measuring anything
    except StaleRowError as exc:
        ap.exit(2, f"{ap.prog}: error: {exc}\n")

    def write(rows) -> str:  # after every row: a long run stopped early still leaves its measured rows
        rows = merged(rows, args.merge)
        seconds = sum(r.seconds for *_, r in rows)  # evaluation time of every row in the report
        shown = [p for p in PRECISIONS if p in args.precisions or any(r.precision == p for *_, r in rows)]
        users = sorted({r.user for *_, r in rows} - {PAPER_USER})
        text = markdown(rows, sorted({d for d, *_ in rows}), shown, args.targets, args.seed, seconds, users,
                        args.out)
        save_markdown(args.out, text)
        save_json(report_path(args.out, ".json"), json_rows(rows))
        return text

    with simulation_pool(1 if args.report_only else args.gen_workers) as simulate:
        measure = dict(targets=args.targets, seed=args.seed, labels=args.methods, users=args.users, simulate=simulate)
        if args.check:
            text, same = check(run(args.domains, args.precisions, **measure), args.check)
            print(text)
            sys.exit(0 if same else 1)
        rows = [] if args.report_only else run(args.domains, args.precisions, **measure, on_row=write)
    print(write(rows))


if __name__ == "__main__":
    main()
