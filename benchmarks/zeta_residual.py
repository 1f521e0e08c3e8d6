"""How precisely ζσ pins a behaviour down, against the high-precision ε: why AF stays above 10 there.

RBA-Global (with or without generation) converges in ζσ space; the user judges true proxies. Per domain
and attribute this reports the spread of the proxies among clips with the same ζσ (the residual of an
isotonic fit proxy ~ ζσ over ``serve``, on ``val`` rollouts) in units of ε, and, per ``val`` rollout as
the target, the share of ``serve`` clips whose ζσ is within the generation threshold of the target's ζσ
that are also within ε on every attribute: the chance that a clip at the right ζσ satisfies the user, so
1 / share is about the rounds spent once the belief has converged. A tuning measurement: never on test.
Writes ``benchmarks/results/zeta_residual.md`` and ``.json``.

    python benchmarks/zeta_residual.py --domains walker manipulator snake lane_change
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import logging
from pathlib import Path

import numpy as np
from sklearn.isotonic import IsotonicRegression

from rba.artifacts import load_model
from rba.domains import get_domain
from rba.interact import load_context
from rba.interact.generating import THRESHOLD
from rba.library import SkillLibrary
from rba.storage import save_text

RESULTS = Path(__file__).resolve().parent / "results"


def measure(domain: str, rep: str, precisions: list[str]) -> list[dict]:
    """One row per precision, from one load of the models and libraries."""
    ctx = load_context(domain, "global", rep)
    val = SkillLibrary.load(domain, "val")
    val_zeta = load_model(domain, "ranker", rep).model.score_library(val)
    scale = np.maximum(ctx.bounds[1] - ctx.bounds[0], 1e-9)
    near = [np.max(np.abs(ctx.serve_zeta - z) / scale, axis=1) <= THRESHOLD for z in val_zeta]
    return [_row(domain, rep, p, ctx, val, val_zeta, near) for p in precisions]


def _row(domain, rep, precision, ctx, val, val_zeta, near) -> dict:
    eps = get_domain(domain).epsilons(ctx.serve.proxies, precision)
    residual = {}
    for a, name in enumerate(ctx.attribute_names):
        fit = IsotonicRegression(out_of_bounds="clip").fit(ctx.serve_zeta[:, a], ctx.serve.proxies[:, a])
        residual[name] = float(np.std(val.proxies[:, a] - fit.predict(val_zeta[:, a])) / eps[a])
    shares = []
    for m, p in zip(near, val.proxies, strict=True):
        if m.any():
            shares.append(float(np.mean(np.all(np.abs(ctx.serve.proxies[m] - p) <= eps, axis=1))))
    share = float(np.mean(shares)) if shares else float("nan")
    row = {"domain": domain, "rep": rep, "precision": precision, "residual_over_epsilon": residual,
           "targets_with_near_clips": len(shares), "targets": len(val), "hit_share": share}
    logging.info("%s", row)
    return row


def report(rows: list[dict], command: str) -> str:
    lines = ["# ζσ precision against ε (val)", "",
             "Proxy spread among clips of equal ζσ (isotonic residual std, in ε), and the share of serve clips "
             f"within the generation threshold ({THRESHOLD}) of a val target's ζσ that are within ε of it on "
             "every attribute (1 / share ≈ rounds once the belief has converged).", "",
             "| domain | rep | precision | residual std / ε per attribute | val targets with a near clip "
             "| hit share | ≈ rounds |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        res = ", ".join(f"{k} {v:.2f}" for k, v in r["residual_over_epsilon"].items())
        rounds = f"{1 / r['hit_share']:.1f}" if r["hit_share"] > 0 else "∞"
        covered = f"{r['targets_with_near_clips']} / {r['targets']}"
        lines.append(f"| {r['domain']} | {r['rep']} | {r['precision']} | {res} | {covered} | {r['hit_share']:.3f} "
                     f"| {rounds} |")
    lines += ["", f"Command: `{command}`; {dt.date.today().isoformat()}."]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--domains", nargs="+", default=["walker", "manipulator", "snake", "lane_change"])
    ap.add_argument("--rep", default="onehot")
    ap.add_argument("--precisions", nargs="+", default=["high", "normal"])
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    rows = [row for d in args.domains for row in measure(d, args.rep, args.precisions)]
    command = " ".join(["python benchmarks/zeta_residual.py", "--domains", *args.domains, "--rep", args.rep,
                       "--precisions", *args.precisions])
    save_text(RESULTS / "zeta_residual.json", json.dumps(rows, indent=1) + "\n")
    save_text(RESULTS / "zeta_residual.md", report(rows, command))


if __name__ == "__main__":
    main()
