"""How precisely ζσ pins a behaviour down, against the high-precision ε: why AF stays above 10 there.

RBA-Global (with or without generation) converges in ζσ space; the user judges true proxies. Per domain
and attribute this reports the spread of the proxies among clips with the same ζσ (the residual of an
isotonic fit proxy ~ ζσ over ``serve``, on ``val`` rollouts) in units of ε, and, per ``val`` rollout as
the target, the share of ``serve`` clips whose ζσ is within the generation threshold of the target's ζσ
that are also within ε on every attribute: the chance that a clip at the right ζσ satisfies the user, so
1 / share is about the rounds spent once the belief has converged. ``--local N`` also asks whether a search
that stays near a shown clip could keep its residual (and so let bisection absorb it as an offset): N val
clips are re-simulated with their parameters moved a little (Gaussian steps in the unit parameter box, the
clip's own seed), and the report gives how much of the residual survives the move. ``--generated N`` asks
whether a clip *made* for a ζσ target satisfies as often as a library clip at that ζσ: for N val clips, the
search the generating agent runs (``rba.generate.cma.search`` from the nearest serve clips, ζσ distance, stopping
within the threshold) for the clip's own ζσ, and the share of the clips it made within the threshold that are
within ε of the val clip's proxies, against the serve clips within the threshold for the same targets (a search
optimises ζσ, so it may find where ζσ errs). ``--seeds N`` asks how noisy the skill itself is: N val clips
re-simulated at their own parameters with ``SEEDS`` other seeds, and the proxies' spread across those seeds in ε
(where it is near ε a search should choose among seeds too: ``Domain.noisy_skill``). A tuning measurement: never
on test. Writes ``benchmarks/results/zeta_residual.md`` and ``.json``; rows of domains a run does not
measure are kept from the report before (each row says which command measured it, and when).

    python benchmarks/zeta_residual.py --domains walker manipulator snake lane_change --local 40 --generated 40 \
        --seeds 10
"""

from __future__ import annotations

import argparse
import datetime as dt
import itertools
import json
import logging
from pathlib import Path

import numpy as np
from sklearn.isotonic import IsotonicRegression

from rba.core.artifacts import load_model
from rba.core.fileio import report_path, save_markdown, save_text
from rba.data.library import SkillLibrary
from rba.domains import domain_target, get_domain, load_domain
from rba.generate.cma import SearchConfig, ZetaDistance, search
from rba.interact import load_context
from rba.interact.generating_agent import STARTS, THRESHOLD

RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "zeta_residual.json", "zeta_residual.md",
)
STEPS = (0.01, 0.03, 0.1)  # std of the parameter moves, in units of each free parameter's range
SEEDS = 6  # other seeds per val clip (--seeds)
BANDS = (0.0, 0.01, 0.02, 0.03, 0.05, 0.08)  # ζσ distances (ranges scaled to 1) between a serve clip and a target


def measure(domain: str, rep: str, precisions: list[str], local: int = 0, seed: int = 0,
            generated: int = 0, seeds: int = 0) -> list[dict]:
    """One row per precision, from one load of the models and libraries (and ``local`` clips moved,
    ``generated`` searches, and ``seeds`` clips re-simulated with other seeds)."""
    ctx = load_context(domain, "global", rep)
    val = SkillLibrary.load(domain, "val")
    ranker = load_model(domain, "ranker", rep).model
    val_zeta = ranker.score_library(val)
    scale = np.maximum(ctx.bounds[1] - ctx.bounds[0], 1e-9)
    off = [np.max(np.abs(ctx.serve_zeta - z) / scale, axis=1) for z in val_zeta]  # per target, every serve clip
    near = [d <= THRESHOLD for d in off]
    fits = [IsotonicRegression(out_of_bounds="clip").fit(ctx.serve_zeta[:, a], ctx.serve.proxies[:, a])
            for a in range(len(ctx.attribute_names))]
    moved = _moved(domain, val, local, seed) if local else []
    made = _made(domain, ctx, ranker, val_zeta, scale, generated, seed) if generated else []
    reseeded = _reseeded(domain, val, seeds, seed) if seeds else None
    rows = []
    for p in precisions:
        eps = get_domain(domain).epsilons(ctx.serve.proxies, p)
        row = _row(domain, rep, p, ctx, val, val_zeta, near, fits, eps)
        row["bands"] = _bands(ctx, val, off, eps)
        if moved:
            row["local"] = _local(ctx, ranker, fits, eps, scale, moved)
        if made:
            row["generated"] = _generated(ctx, val, near, eps, made)
        if reseeded is not None:
            spread, names = reseeded / eps, ctx.attribute_names
            row["seeds"] = {"clips": len(spread), "seeds": SEEDS,
                            "median": dict(zip(names, np.median(spread, 0).round(2).tolist(), strict=True)),
                            "max": dict(zip(names, spread.max(0).round(2).tolist(), strict=True))}
        rows.append(row)
    return rows


def _residual(fits, zeta: np.ndarray, proxies: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """Proxy minus the isotonic fit's proxy at that ζσ, per attribute, in ε units."""
    return np.stack([proxies[:, a] - f.predict(zeta[:, a]) for a, f in enumerate(fits)], axis=1) / eps


def _moved(domain: str, val: SkillLibrary, clips: int, seed: int) -> list[tuple[list, list]]:
    """Per step size, ``clips`` val rollouts and the same rollouts re-simulated with moved parameters."""
    sim = load_domain(domain_target(domain))
    space, rng = sim.param_space(), np.random.default_rng(seed)
    picked = [val.rollout(int(i)) for i in rng.choice(len(val), min(clips, len(val)), replace=False)]
    out = []
    for step in STEPS:
        pairs = []
        for r in picked:
            unit = space.to_unit(r.params)
            moved = sim.rollout(space.from_unit(np.clip(unit + rng.normal(0, step, len(unit)), 0, 1), r.params), r.seed)
            if moved.success:
                pairs.append((r, moved))
        out.append(([a for a, _ in pairs], [b for _, b in pairs]))
    return out


def _reseeded(domain: str, val: SkillLibrary, clips: int, seed: int) -> np.ndarray:
    """float[clips, k]: per picked val clip, the proxies' std over ``SEEDS`` other seeds at its own parameters."""
    sim = load_domain(domain_target(domain))
    out = []
    for i in np.random.default_rng(seed + 2).choice(len(val), min(clips, len(val)), replace=False):
        r = val.rollout(int(i))
        others = [sim.rollout(r.params, 10_000 * (seed + 1) + n) for n in range(SEEDS)]
        out.append(np.std([[o.proxies[name] for name in val.attribute_names] for o in others], axis=0))
    return np.array(out)


def _hits(ctx, clips: np.ndarray, target: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """bool per serve clip picked by the mask ``clips``: within ε of ``target``'s proxies on every attribute."""
    return np.all(np.abs(ctx.serve.proxies[clips] - target) <= eps, axis=1)


def _hit_share(ctx, clips: np.ndarray, target: np.ndarray, eps: np.ndarray) -> float:
    """The share of the serve clips picked by the mask ``clips`` within ε of ``target``'s proxies everywhere."""
    return float(np.mean(_hits(ctx, clips, target, eps)))


def _bands(ctx, val, off: list[np.ndarray], eps: np.ndarray) -> list[dict]:
    """Per band of ζσ distance to a val target: the share of the serve clips in it within ε of the target (over
    every target and clip): how much nearer than a band's clips a made clip must be to satisfy more often."""
    out = []
    for lo, hi in itertools.pairwise(BANDS):
        hits = np.concatenate([_hits(ctx, (d > lo) & (d <= hi), p, eps) for d, p in zip(off, val.proxies, strict=True)])
        out.append({"band": [lo, hi], "clips": len(hits),
                    "hit_share": float(hits.mean()) if len(hits) else None})
    return out


def _made(domain: str, ctx, ranker, val_zeta: np.ndarray, scale: np.ndarray, n: int, seed: int) -> list[tuple]:
    """For ``n`` val clips: (index, ζσ distance reached, proxies) of the clip a search made for the clip's ζσ,
    started as the generating agent starts it (the ``STARTS`` serve clips nearest in ζσ); None if all failed."""
    names, serve = ctx.attribute_names, ctx.serve
    out = []
    for i in np.random.default_rng(seed + 1).choice(len(val_zeta), min(n, len(val_zeta)), replace=False):
        dist = ZetaDistance(ranker, val_zeta[i], scale)
        starts = [dict(zip(serve.param_names, map(float, serve.params[j]), strict=True))
                  for j in np.argsort(dist.distances(ctx.serve_zeta), kind="stable")[:STARTS]]
        found = search(domain, starts, dist, config=SearchConfig(seed=int(i), good_enough=THRESHOLD))
        r = found.rollout
        out.append((int(i), None if r is None else found.objective,
                    None if r is None else np.array([r.proxies[a] for a in names])))
    return out


def _generated(ctx, val, near, eps: np.ndarray, made: list[tuple]) -> dict:
    """Of the made clips within the threshold, the share within ε; the serve clips' share for the same targets."""
    hits, lib = [], []
    for i, reached, proxies in made:
        if reached is not None and reached <= THRESHOLD:
            hits.append(bool(np.all(np.abs(proxies - val.proxies[i]) <= eps)))
        if near[i].any():
            lib.append(_hit_share(ctx, near[i], val.proxies[i], eps))
    return {"searches": len(made), "reached": len(hits), "hit_share": float(np.mean(hits)) if hits else None,
            "library_targets": len(lib), "library_hit_share": float(np.mean(lib)) if lib else None}


def _local(ctx, ranker, fits, eps, scale, moved) -> list[dict]:
    """Per step: how far ζσ moved (range units), and the residual's change and correlation (ε units)."""
    score = ZetaDistance(ranker, np.zeros(len(eps)), scale).zeta
    out = []
    for step, (before, after) in zip(STEPS, moved, strict=True):
        names = ctx.attribute_names
        z0, z1 = score(before), score(after)
        r0 = _residual(fits, z0, np.array([[r.proxies[a] for a in names] for r in before]), eps)
        r1 = _residual(fits, z1, np.array([[r.proxies[a] for a in names] for r in after]), eps)
        out.append({"step": step, "clips": len(before),
                    "zeta_move": dict(zip(names, (np.abs(z1 - z0) / scale).mean(0).round(4).tolist(), strict=True)),
                    "residual_change": dict(zip(names, (r1 - r0).std(0).round(3).tolist(), strict=True)),
                    "residual_corr": {n: round(float(np.corrcoef(r0[:, a], r1[:, a])[0, 1]), 3)
                                      for a, n in enumerate(names)}})
    return out


def _row(domain, rep, precision, ctx, val, val_zeta, near, fits, eps) -> dict:
    res = _residual(fits, val_zeta, val.proxies, eps).std(0)
    residual = {name: float(res[a]) for a, name in enumerate(ctx.attribute_names)}
    shares = []
    for m, p in zip(near, val.proxies, strict=True):
        if m.any():
            shares.append(_hit_share(ctx, m, p, eps))
    share = float(np.mean(shares)) if shares else float("nan")
    row = {"domain": domain, "rep": rep, "precision": precision, "residual_over_epsilon": residual,
           "targets_with_near_clips": len(shares), "targets": len(val), "hit_share": share}
    logging.info("%s", row)
    return row


def report(rows: list[dict]) -> str:
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
    local = [r for r in rows if "local" in r and r["precision"] == "high"]
    if local:
        lines += ["", "## Residuals after a small parameter move (high-precision ε)", "",
                  "Val clips re-simulated with their parameters moved by a Gaussian step (std a share of each free "
                  "parameter's range, the clip's own seed): the mean ζσ move (range units; the generation threshold "
                  f"is {THRESHOLD}), the std of the residual's change in ε, and the residual's correlation before / "
                  "after. A change near the residual's own std means a nearby clip is a fresh draw: a search that "
                  "stays near a shown clip cannot keep what the user said about it.", "",
                  "| domain | step | clips | ζσ move | residual change / ε | residual correlation |",
                  "|---|---|---|---|---|---|"]
        fmt = lambda d: ", ".join(f"{k} {v:.3g}" for k, v in d.items())  # noqa: E731
        for r in local:
            for m in r["local"]:
                lines.append(f"| {r['domain']} | {m['step']} | {m['clips']} | {fmt(m['zeta_move'])} | "
                             f"{fmt(m['residual_change'])} | {fmt(m['residual_corr'])} |")
    banded = [r for r in rows if "bands" in r]
    if banded:
        heads = " | ".join(f"({b['band'][0]:g}, {b['band'][1]:g}]" for b in banded[0]["bands"])
        lines += ["", "## Hit share by ζσ distance to the target", "",
                  "Share of the serve clips whose ζσ is in a band of distance to a val target's ζσ (max over "
                  "attributes, ranges scaled to 1) that are within ε of the target on every attribute; in brackets "
                  "the pairs in the band. Where the share stays level beyond the generation threshold "
                  f"({THRESHOLD}), a clip made nearer satisfies no more often than the library's.", "",
                  f"| domain | precision | {heads} |", "|---|---|" + "---|" * len(banded[0]["bands"])]
        for r in banded:
            cells = " | ".join("–" if b["hit_share"] is None else f"{b['hit_share']:.3f} ({b['clips']})"
                               for b in r["bands"])
            lines.append(f"| {r['domain']} | {r['precision']} | {cells} |")
    made = [r for r in rows if "generated" in r]
    if made:
        lines += ["", "## Clips made for a ζσ target against library clips at it", "",
                  "For val clips as targets, the search the generating agent runs for the clip's ζσ (from the "
                  f"{STARTS} nearest serve clips, stopping within the threshold {THRESHOLD}, 48 simulations at most): "
                  "how many searches reached the threshold, and the share of those clips within ε of the target's "
                  "proxies on every attribute; against the share of serve clips within the threshold that are, "
                  "over the same targets that have such a clip. A made clip that satisfies less often than a "
                  "library clip at the same ζσ means the search finds where ζσ errs.", "",
                  "| domain | precision | searches reaching the threshold | made clips' hit share "
                  "| targets with a near serve clip | serve clips' hit share |", "|---|---|---|---|---|---|"]
        share = lambda v: "–" if v is None else f"{v:.3f}"  # noqa: E731
        for r in made:
            g = r["generated"]
            lines.append(f"| {r['domain']} | {r['precision']} | {g['reached']} / {g['searches']} | "
                         f"{share(g['hit_share'])} | {g['library_targets']} | {share(g['library_hit_share'])} |")
    seeded = [r for r in rows if "seeds" in r and r["precision"] == "high"]
    if seeded:
        lines += ["", "## The skill's own noise: other seeds at a clip's parameters (high-precision ε)", "",
                  f"Val clips re-simulated at their own parameters with {SEEDS} other seeds: the std of each proxy "
                  "across the seeds in ε, median and largest over the clips. Where it nears ε a clip's seed decides "
                  "whether it satisfies, and a search that simulates every candidate with one seed may not reach "
                  "a target at all (`Domain.noisy_skill`).", "",
                  "| domain | clips | median std / ε | largest std / ε |", "|---|---|---|---|"]
        fmt = lambda d: ", ".join(f"{k} {v:.2f}" for k, v in d.items())  # noqa: E731
        for r in seeded:
            s = r["seeds"]
            lines.append(f"| {r['domain']} | {s['clips']} | {fmt(s['median'])} | {fmt(s['max'])} |")
    runs: dict[str, list[str]] = {}  # each run's command and date -> the domains it measured
    for r in rows:
        runs.setdefault(r["measured"], []).append(r["domain"])
    lines += [""] + [f"Command: {run} ({', '.join(dict.fromkeys(domains))})." for run, domains in runs.items()]
    return "\n".join(lines) + "\n"


def merge_rows(rows: list[dict], earlier: Path) -> list[dict]:
    """``rows`` with the earlier report's rows of the domains they do not measure, in its domain order: one
    domain is re-measured after its library or models changed (each row keeps its ``measured``: command and date)."""
    path = report_path(earlier, ".json")
    old = json.loads(path.read_text()) if path.exists() else []
    measured = {r["domain"] for r in rows}
    order = list(dict.fromkeys([r["domain"] for r in old] + [r["domain"] for r in rows]))
    kept = [r for r in old if r["domain"] not in measured]
    return sorted(kept + rows, key=lambda r: order.index(r["domain"]))  # stable: a domain's rows keep their order


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--domains", nargs="+", default=["walker", "manipulator", "snake", "lane_change"])
    ap.add_argument("--rep", default="onehot")
    ap.add_argument("--precisions", nargs="+", default=["high", "normal"])
    ap.add_argument("--local", type=int, default=0, metavar="N",
                    help="also move the parameters of N val clips and measure how much residual survives")
    ap.add_argument("--generated", type=int, default=0, metavar="N",
                    help="also search for the ζσ of N val clips and measure how often the made clip satisfies")
    ap.add_argument("--seeds", type=int, default=0, metavar="N",
                    help="also re-simulate N val clips with other seeds and measure the proxies' spread")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    rows = [row for d in args.domains for row in measure(d, args.rep, args.precisions, args.local,
                                                         generated=args.generated, seeds=args.seeds)]
    command = " ".join(["python benchmarks/zeta_residual.py", "--domains", *args.domains, "--rep", args.rep,
                       "--precisions", *args.precisions, "--local", str(args.local), "--generated",
                       str(args.generated), "--seeds", str(args.seeds)])
    for row in rows:
        row["measured"] = f"`{command}`; {dt.date.today().isoformat()}"
    rows = merge_rows(rows, RESULTS / "zeta_residual")
    save_text(RESULTS / "zeta_residual.json", json.dumps(rows, indent=1) + "\n")
    save_markdown(RESULTS / "zeta_residual.md", report(rows))


if __name__ == "__main__":
    main()
