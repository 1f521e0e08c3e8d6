"""RBA-Global query cost and precision: rθ over the whole serve library vs over a ζσ shortlist.

For every ``val`` rollout as target, the query is argmax Σ rθ(·|ζσ(target)) over ``serve`` (the
paper), or over the K serve rollouts nearest the target in ζσ space. Reports, per K, the share
of queries within ε of the target on every attribute, how often the two agree, and the time per
query (all measured in one run, so the ratios hold on a noisy machine).
Writes ``benchmarks/results/shortlist.md``.

    python benchmarks/shortlist.py --domain walker --ks 16 32 64 128 256
"""

from __future__ import annotations

import argparse
import datetime as dt
import logging
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from rba.core.artifacts import load_model
from rba.core.fileio import save_markdown
from rba.data.library import SkillLibrary
from rba.domains import get_domain
from rba.interact import load_context

RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = ("shortlist.md",)  # what this script writes into benchmarks/results/ (tests/test_results_files.py)


def measure(domain: str, rep: str, ks: list[int | None]) -> list[dict]:
    ctx = load_context(domain, "global", rep)
    val = SkillLibrary.load(domain, "val")  # a tuning measurement: never on test
    val_zeta = load_model(domain, "ranker", rep).model.score_library(val)
    eps = {p: get_domain(domain).epsilons(ctx.serve.proxies, p) for p in ("normal", "high")}
    none = np.zeros(len(ctx.serve), dtype=bool)
    full = None
    rows = []
    for k in ks:
        c = replace(ctx, shortlist=k)
        start = time.perf_counter()
        picks = np.array([c.scorer.argmax(z, none, c.candidates(z, none)) for z in val_zeta])
        seconds = (time.perf_counter() - start) / len(val_zeta)
        if full is None:
            full = picks
        row = {"rep": rep, "k": "all" if k is None else k, "ms_per_query": 1000 * seconds,
               "same_as_full": float(np.mean(picks == full))}
        for p, e in eps.items():
            row[p] = float(np.mean(np.all(np.abs(ctx.serve.proxies[picks] - val.proxies) <= e, axis=1)))
        rows.append(row)
        logging.info("%s", row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--domain", default="walker")
    ap.add_argument("--reps", nargs="+", default=["onehot", "language"])
    ap.add_argument("--ks", nargs="+", type=int, default=[16, 32, 64, 128, 256])
    ap.add_argument("--out", type=Path, default=RESULTS / "shortlist.md")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    start = time.perf_counter()
    rows = [r for rep in args.reps for r in measure(args.domain, rep, [None, *args.ks])]
    lines = [f"# {args.domain}: rθ query over the whole serve library vs a ζσ shortlist", "",
             f"{dt.datetime.now(dt.UTC):%Y-%m-%d %H:%M} UTC, `python benchmarks/shortlist.py --domain {args.domain} "
             f"--ks {' '.join(map(str, args.ks))}`, {time.perf_counter() - start:.0f} s. Targets: every `val` "
             "rollout; a query is within ε when the chosen serve rollout is within ε of the target on every "
             "attribute.", "",
             "| rep | K | within ε | within high-precision ε | same pick as K=all | ms / query |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {r['rep']} | {r['k']} | {r['normal']:.3f} | {r['high']:.3f} | {r['same_as_full']:.3f} | "
              f"{r['ms_per_query']:.1f} |" for r in rows]
    save_markdown(args.out, "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
