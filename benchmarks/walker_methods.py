"""Walker: SR / AF of every method and representation beside the paper's Table 1, plus noisy users.

Writes ``benchmarks/results/walker_methods.md`` (and a ``.json`` summary beside it). Needs the
walker libraries and trained models (``rba build walker``; ``rba train walker``).

    python benchmarks/walker_methods.py                 # 20 targets, seed 0, noise rows 0.1 and 0.2
    python benchmarks/walker_methods.py --targets 5     # a quick look
    python benchmarks/walker_methods.py --widths 512    # also retrain RBA-Local at the paper's MLP width
"""

from __future__ import annotations

import argparse
import datetime as dt
import logging
import platform
import sys
import tempfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from paper_tables import PAPER as PAPER_TABLES  # a sibling script, on sys.path when run as one
from paper_tables import PAPER_LABELS

from rba.core.artifacts import ModelNotFoundError, load_model
from rba.core.fileio import report_path, save_json, save_markdown
from rba.core.methods import get_method, method_names, methods
from rba.interact import load_context
from rba.interact.evaluate import EvalResult, af_cell, evaluate
from rba.learn.pbrl import PbRLConfig
from rba.learn.training import LocalTrainConfig, train_local

log = logging.getLogger("walker_methods")

RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "walker_methods.json", "walker_methods.md",
)
# Paper Table 1, walker column, by row label: (SR, AF, std of AF); paper_tables keeps every table of the paper
PAPER = dict(zip(PAPER_LABELS, PAPER_TABLES["normal"]["walker"], strict=True))
LABELS = {(m.name, rep): m.label_for(rep) for m in methods(include_reference=True) for rep in m.run_reps}


def _paper(label: str, user: str) -> tuple[str, str]:
    if user != "paper" or label not in PAPER:
        return "", ""
    sr, af, sd = PAPER[label]
    return f"{sr:.2f}", f"{af:.2f} ({sd:.2f})"


def _local_card(rep: str) -> str:
    card = load_model("walker", "local_reward", rep).card
    h = card["held_out"]
    return (f"local_reward-{rep}: target above negative {h['target_vs_negative']:.3f}, above anchor "
            f"{h['target_vs_anchor']:.3f} ({h['pairs']} {h['split']} pairs); argmax over serve is a useful edit "
            f"{h['argmax_over_serve']['useful_edit_rate']:.2f} of the time; trained in "
            f"{card['training']['seconds']:.0f} s")


def _global_card(rep: str) -> str:
    card = load_model("walker", "global_reward", rep).card
    h = card["held_out"]
    return f"global_reward-{rep}: argmax within ε of a {h['split']} target {h['argmax_within_epsilon']:.2f}"


def _pbrl_config(_rep: str) -> str:
    cfg = PbRLConfig()
    return (f"pbrl (online, no pretrained model): ensemble of {cfg.members} MLPs of width {cfg.hidden}, "
            f"state stride {cfg.state_stride}, {cfg.steps_per_label} warm-started steps per label, pairs by "
            f"{cfg.query} among the {cfg.candidates} best")


NOTES: dict[str, Callable[[str], str]] = {"local": _local_card, "global": _global_card, "pbrl": _pbrl_config}


def _held_out(method: str, rep: str) -> str:
    """One line from the model card: what the model measured on held-out data ("" for other methods)."""
    try:
        return NOTES[method](rep) if method in NOTES else ""
    except FileNotFoundError:
        return ""  # reported as "not measured"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--targets", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--noise", type=float, nargs="*", default=[0.1, 0.2], help="extra noise levels")
    p.add_argument("--noise-methods", nargs="*", default=[m.name for m in methods() if m.feedback_kind == "attribute"],
                   help="methods that also get the noisy-user rows (default: the attribute-feedback ones)")
    p.add_argument("--methods", nargs="*", default=list(method_names()), choices=method_names())
    p.add_argument("--widths", type=int, nargs="*", default=[],
                   help="also train RBA-Local with these MLP widths (in a temporary folder) and evaluate them")
    p.add_argument("--note", action="append", default=[], help="an extra line for the report's notes")
    p.add_argument("--out", type=Path, default=RESULTS / "walker_methods.md")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")

    runs = [(m, r) for m in args.methods for r in get_method(m).run_reps]
    rows: list[tuple[str, EvalResult]] = []
    missing = []
    for method, rep in runs:
        try:
            ctx = load_context("walker", method, rep)
        except ModelNotFoundError as exc:
            log.warning("skipping %s %s: %s", method, rep, exc)
            missing.append(f"{LABELS[(method, rep)]}: not measured ({exc})")
            continue
        for noise in [0.0, *(args.noise if method in args.noise_methods else [])]:
            user = f"mistake:{noise:g}" if noise else "paper"
            r = evaluate("walker", method, rep, args.targets, args.seed, user=user, context=ctx)
            log.info("%s %s noise %.2f: SR %.2f AF %s in %.0f s", method, rep, noise, r.success_rate,
                     af_cell(r.avg_feedback, r.std_feedback), r.seconds)
            rows.append((LABELS[(method, rep)], r))
    width_notes = []
    for width in args.widths:
        for rep in ("onehot", "language"):
            with tempfile.TemporaryDirectory() as tmp:
                cfg = LocalTrainConfig()
                cfg = replace(cfg, reward=replace(cfg.reward, hidden=width))
                metrics = train_local("walker", rep, cfg, models_root=Path(tmp))
                ctx = load_context("walker", "local", rep, None, Path(tmp))
                r = evaluate("walker", "local", rep, args.targets, args.seed, context=ctx)
            rows.append((f"{LABELS[('local', rep)]} (MLP {width})", r))
            width_notes.append(f"local_reward-{rep} with MLP width {width}: target above negative "
                               f"{metrics['local_reward']['target_vs_negative']:.3f}, useful edit "
                               f"{metrics['argmax_over_serve']['useful_edit_rate']:.2f}; trained in "
                               f"{metrics['seconds']['local_reward']:.0f} s")

    lines = [
        "# Walker: every method beside the paper's Table 1",
        "",
        f"{args.targets} held-out targets from `test` (seed {args.seed}), ε = the domain's normal precision, "
        "500-feedback budget. AF is averaged over successful trials; PbRL counts binary A/B labels, the "
        "others attribute-level feedbacks. User mistake:p: each non-zero answer (or A/B label) is flipped "
        "with probability p.",
        "",
        "| method | rep | user | SR | AF (std) | paper SR | paper AF (std) | seconds |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for label, r in rows:
        psr, paf = _paper(label, r.user)
        rep = r.rep if get_method(r.method).reps else "–"
        af = af_cell(r.avg_feedback, r.std_feedback)
        lines.append(f"| {label} | {rep} | {r.user} | {r.success_rate:.2f} | {af} | {psr} | {paf} | {r.seconds:.0f} |")
    notes = [n for n in (_held_out(m, r) for m, r in runs) if n] + width_notes + missing + args.note
    given = sys.argv[1:] if argv is None else argv
    shown = [a for i, a in enumerate(given) if a != "--note" and (i == 0 or given[i - 1] != "--note")]
    command = " ".join(["python benchmarks/walker_methods.py", *shown, *(["--note …"] if args.note else [])])
    lines += ["", "Models (from their cards):", "", *[f"- {n}" for n in notes], "",
              f"Command: `{command}`; "
              f"{dt.date.today().isoformat()}, Python {platform.python_version()}, CPU only.", ""]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_markdown(args.out, "\n".join(lines))
    save_json(report_path(args.out, ".json"),
              [{"label": label} | {k: v for k, v in r.to_json().items() if k != "trials"}
               | {"feedback_counts": [t.feedback_count if t.success else None for t in r.trials]}
               for label, r in rows])
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
