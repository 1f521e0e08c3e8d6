"""What ζσ loses when its labels are what a person can give: noisy pairs instead of a perfect ordering.

For each domain, ζσ (one-hot) is trained on a simulated annotator's answers (``rba.data.labels.
annotator_labels``: at most 200 train clips, N pairs, a share of the answers flipped, 10 %
"can't tell" dropped) for every label noise × number of pairs, and once on the perfect ordering
of the same 200 clips (every one of their 19,900 pairs). The score is the held-out pairwise
accuracy on ``val``: over every pair of val rollouts, ordered by their true proxies
(``ranking_metrics``), averaged over the domain's attributes.

The ranker is the default preset's (``--steps`` can shorten it on a busy machine). Runs go
domain by domain, the perfect ordering and the 1,000-pair runs first, and the report is rewritten
after every run, so an interrupted run still reports what it measured. ``--trained`` names models
folders whose ``ranker-onehot`` cards (the full ``pairwise`` preset; the first folder with one wins) are
listed beside the grid.
Writes ``benchmarks/results/label_noise.{json,md,png}``.

    python benchmarks/label_noise.py --domains manipulator lane_change walker snake --trained models /tmp/pairs_models
"""

from __future__ import annotations

import argparse
import datetime as dt
import logging
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from rba.core.fileio import load_json, report_path, save_report
from rba.data.labels import GlobalLabelConfig, annotator_labels, proxy_labels
from rba.data.library import SkillLibrary
from rba.domains import get_domain
from rba.learn.common import Ragged
from rba.learn.embed import attribute_embeddings
from rba.learn.ranker import RankerConfig, ranking_metrics, train_ranker

RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "label_noise.json", "label_noise.md", "label_noise.png",
)
log = logging.getLogger("label_noise")


def run_one(domain: str, labels_cfg: GlobalLabelConfig, steps: int | None, seed: int) -> dict:
    """Train ζσ on ``labels_cfg``'s labels of ``domain``'s train clips; its val accuracy and label counts."""
    spec = get_domain(domain)
    train, val = SkillLibrary.load(domain, "train"), SkillLibrary.load(domain, "val")  # tuning: never test
    cfg = RankerConfig(seed=seed, labels=labels_cfg)
    cfg = replace(cfg, steps=steps or spec.ranker_steps or cfg.steps)
    if labels_cfg.mode == "ordering":
        labels, made = proxy_labels(train, cfg.max_labelled, seed), {}
    else:
        labels, made = annotator_labels(train, cfg.max_labelled, labels_cfg, seed)
    embed = attribute_embeddings([a.description for a in spec.attributes], "onehot")
    start = time.perf_counter()
    model, _ = train_ranker(Ragged.from_numpy(train.states, train.state_offsets), labels, embed, cfg)
    metrics = ranking_metrics(model.score_library(val), val.proxies, spec.attribute_names)
    acc = {name: m["pairwise_accuracy"] for name, m in metrics.items()}
    row = {"domain": domain, "mode": labels_cfg.mode, "noise": labels_cfg.noise if made else 0.0,
           "pairs": made.get("pairs_shown", labels[0].num_pairs), "answered": [lab.num_pairs for lab in labels],
           "flipped": [a["flipped"] for a in made.get("per_attribute", [])],
           "steps": cfg.steps, "val_pairwise_accuracy": acc, "mean_accuracy": round(sum(acc.values()) / len(acc), 4),
           "seconds": round(time.perf_counter() - start, 1)}
    log.info("%s", row)
    return row


def trained_rows(models_dirs: list[Path], domains: list[str]) -> list[dict]:
    """The full-preset pairwise ζσ cards in ``models_dirs`` (val accuracy, how their labels were made).

    Per domain, the first folder that holds a pairwise card wins (e.g. the shipped models, then a trial folder).
    """
    rows = []
    for d in domains:
        cards = (load_json(p) for m in models_dirs if (p := m / d / "ranker-onehot.json").exists())
        card = next((c for c in cards if c["training"].get("labels", {}).get("mode") == "pairwise"), None)
        if card is None:
            continue
        acc = {n: card["held_out"][n]["pairwise_accuracy"] for n in get_domain(d).attribute_names}
        rows.append({"domain": d, "labels": card["training"].get("labels", {}), "steps": card["training"]["config"]
                     ["steps"], "val_pairwise_accuracy": acc, "mean_accuracy": round(sum(acc.values()) / len(acc), 4)})
    return rows


def plot(report: dict, out: Path) -> None:
    measured = {r["domain"] for r in report["runs"] + report["trained"]}
    domains = [d for d in report["args"]["domains"] if d in measured]  # an interrupted run: only what it measured
    fig, axes = plt.subplots(1, len(domains), figsize=(3.6 * len(domains), 3.3), squeeze=False)
    for ax, d in zip(axes[0], domains, strict=True):
        rows = [r for r in report["runs"] if r["domain"] == d]
        for noise in report["args"]["noises"]:
            pts = sorted((r["pairs"], r["mean_accuracy"]) for r in rows if r["mode"] == "pairwise"
                         and r["noise"] == noise)
            if pts:
                ax.plot(*zip(*pts, strict=True), marker="o", label=f"{noise:.0%} flipped")
        for r in rows:
            if r["mode"] == "ordering":
                ax.axhline(r["mean_accuracy"], color="k", ls="--", lw=1, label="perfect ordering (19,900 pairs)")
        for r in report["trained"]:
            if r["domain"] == d:
                ax.plot(r["labels"]["max_pairs"], r["mean_accuracy"], "r*", ms=10,
                        label=f"{r['labels']['noise']:.0%} flipped, `rba train --preset pairwise`")
        ax.set_title(d, fontsize=10)
        ax.set_xlabel("pairs answered by the annotator")
        ax.set_xscale("log")
        ax.set_xticks(report["args"]["pairs"], [str(p) for p in report["args"]["pairs"]])
    axes[0][0].set_ylabel("ζσ pairwise accuracy on val")
    axes[0][0].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def markdown(report: dict) -> str:
    a = report["args"]
    steps = sorted({r["steps"] for r in report["runs"]})
    lines = [f"# ζσ from noisy pairwise labels vs a perfect ordering ({'/'.join(map(str, steps))} ranker steps)", "",
             f"{report['date']} UTC, `{report['command']}`, {report['machine']}. Annotator: at most 200 train "
             f"clips, N pairs, each answered for every attribute; {a['cant_tell']:.0%} \"can't tell\" (the pairs "
             "closest by proxy) dropped; P(i > j) = sigmoid((p_i − p_j)/T), T per attribute so that the asked "
             "share of the answers is flipped. Score: pairwise accuracy of ζσ over every pair of `val` rollouts "
             "ordered by the true proxy, mean over attributes (per attribute in the JSON).", "",
             "| domain | labels | noise | pairs | answered / attribute | flipped / attribute | val accuracy (mean) "
             "| per attribute | s |", "|---|---|---|---|---|---|---|---|---|"]
    for r in report["runs"]:
        per = ", ".join(f"{k} {v:.3f}" for k, v in r["val_pairwise_accuracy"].items())
        lines.append(f"| {r['domain']} | {r['mode']} | {r['noise']:.0%} | {r['pairs']} | "
                     f"{'/'.join(map(str, r['answered']))} | {'/'.join(map(str, r['flipped'])) or '–'} | "
                     f"{r['mean_accuracy']:.3f} | {per} | {r['seconds']:.0f} |")
    expected = len(a["domains"]) * (1 + len(a["noises"]) * len(a["pairs"]))
    if len(report["runs"]) < expected:
        lines += ["", f"Interrupted after {len(report['runs'])} of {expected} runs (see the JSON's `runs`)."]
    if report["trained"]:
        lines += ["", f"Full training (`rba train D --method global --rep onehot --preset pairwise`, default steps; "
                  f"cards in {', '.join(f'`{p}`' for p in a['trained'])}):", "",
                  "| domain | labels | steps | val accuracy (mean) | per attribute |", "|---|---|---|---|---|"]
        for r in report["trained"]:
            lab = r["labels"]
            per = ", ".join(f"{k} {v:.3f}" for k, v in r["val_pairwise_accuracy"].items())
            lines.append(f"| {r['domain']} | {lab.get('mode')} {lab.get('max_pairs')} pairs, {lab.get('noise', 0):.0%} "
                         f"noise | {r['steps']} | {r['mean_accuracy']:.3f} | {per} |")
    return "\n".join(lines) + "\n\n![accuracy vs pairs](label_noise.png)\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--domains", nargs="+", default=["walker", "manipulator", "lane_change", "snake"])
    ap.add_argument("--noises", nargs="+", type=float, default=[0.0, 0.1, 0.2])
    ap.add_argument("--pairs", nargs="+", type=int, default=[250, 500, 1000])
    ap.add_argument("--cant-tell", type=float, default=GlobalLabelConfig.cant_tell)
    ap.add_argument("--steps", type=int, help="ζσ gradient steps (default: the default preset's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trained", type=Path, nargs="+", default=[],
                    help="models folders whose full-preset pairwise ζσ cards are listed (first folder wins)")
    ap.add_argument("--out", type=Path, default=RESULTS / "label_noise")
    ap.add_argument("--replot", action="store_true", help="only redraw the figure and table from <out>.json")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    if args.replot:  # e.g. after an interrupted run: its JSON holds every finished run
        report = load_json(report_path(args.out, ".json"))
        report["trained"] = trained_rows(args.trained, report["args"]["domains"]) if args.trained else []
        plot(report, report_path(args.out, ".png"))
        save_report(args.out, report, markdown(report))
        return 0
    report = {"command": "python benchmarks/label_noise.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "date": f"{dt.datetime.now(dt.UTC):%Y-%m-%d %H:%M}",
              "machine": f"{os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}",
              "args": {**{k: v for k, v in vars(args).items() if k not in ("trained", "out")},
                       "trained": [str(p) for p in args.trained]}, "runs": [], "trained": []}
    cfgs = [GlobalLabelConfig("ordering")] + [GlobalLabelConfig("pairwise", n, noise, args.cant_tell)
                                              for n in sorted(args.pairs, reverse=True) for noise in args.noises]
    for d in args.domains:
        for cfg in cfgs:
            report["runs"].append(run_one(d, cfg, args.steps, args.seed))
            save_report(args.out, report, markdown(report))  # partial results survive an interruption
    report["trained"] = trained_rows(args.trained, args.domains) if args.trained else []
    plot(report, report_path(args.out, ".png"))
    save_report(args.out, report, markdown(report))
    log.info("wrote %s.{json,md,png}", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
