"""The paper's figures as PNGs in ``benchmarks/results/``.

- ``zeta_vs_proxy.png``: ζσ against the proxy on ``test`` for every attribute of every domain
  (the paper's appendix figure), from the shipped one-hot rankers.
- ``sample_efficiency.png``: held-out accuracy against the number of labelled samples, for ζσ
  (pairwise ordering accuracy on ``test``, averaged over attributes; ``max_labelled`` clips)
  and RBA-Local (target-above-negative accuracy on ``test`` pairs; ``max_pairs`` pairs).

    python benchmarks/paper_figures.py                     # every domain, 25/50/100/200 labels
    python benchmarks/paper_figures.py --domains walker --sizes 25 200
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import matplotlib.ticker
import numpy as np

from rba.core.artifacts import ModelNotFoundError, load_model
from rba.core.fileio import save_json
from rba.data.library import LibraryNotFoundError, SkillLibrary
from rba.domains import domain_names, get_domain
from rba.learn.ranker import RankerConfig
from rba.learn.training import GlobalTrainConfig, LocalTrainConfig, train_global, train_local

log = logging.getLogger("paper_figures")
RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "sample_efficiency.json", "sample_efficiency.png", "zeta_vs_proxy.png",
)


def zeta_vs_proxy(domains: list[str], out: Path) -> None:
    panels = []
    for d in domains:
        try:
            ranker = load_model(d, "ranker", "onehot").model
            test = SkillLibrary.load(d, "test")
        except (ModelNotFoundError, LibraryNotFoundError) as exc:
            log.warning("%s: no ζσ figure (%s)", d, exc)
            continue
        zeta = ranker.score_library(test)
        panels += [(d, spec, zeta[:, a], test.proxies[:, a]) for a, spec in enumerate(get_domain(d).attributes)]
    if not panels:
        return
    cols = min(len(panels), 3)
    rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3.2 * rows), squeeze=False)
    for ax, (d, spec, z, p) in zip(axes.flat, panels, strict=False):
        ax.scatter(p, z, s=8, alpha=0.7)
        ax.set_xlabel(f"{spec.name} proxy ({spec.unit})")
        ax.set_ylabel("ζσ")
        ax.set_title(f"{d}: {spec.name}", fontsize=10)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def sample_efficiency(domains: list[str], sizes: list[int], ranker_steps: int, local_steps: int,
                      out: Path) -> dict:
    curves: dict[str, dict[str, list[float]]] = {}
    for d in domains:
        try:
            SkillLibrary.load(d, "train")
        except LibraryNotFoundError as exc:
            log.warning("%s: no sample-efficiency curve (%s)", d, exc)
            continue
        curves[d] = {"zeta": [], "local": []}
        for n in sizes:
            with tempfile.TemporaryDirectory() as tmp:
                g = GlobalTrainConfig()
                g = replace(g, ranker=replace(g.ranker, max_labelled=n, steps=ranker_steps),
                            reward=replace(g.reward, steps=1))
                metrics = train_global(d, "onehot", g, models_root=Path(tmp))
                curves[d]["zeta"].append(float(np.mean([m["pairwise_accuracy"] for m in metrics["ranker"].values()])))
                loc = LocalTrainConfig()
                loc = replace(loc, labels=replace(loc.labels, max_pairs=n),
                              reward=replace(loc.reward, steps=local_steps))
                lm = train_local(d, "onehot", loc, models_root=Path(tmp))
                curves[d]["local"].append(lm["local_reward"]["target_vs_negative"])
            log.info("%s n=%d: ζσ %.3f, local %.3f", d, n, curves[d]["zeta"][-1], curves[d]["local"][-1])
    if curves:
        plot_sample_efficiency(curves, sizes, ranker_steps, local_steps, out)
    return curves


def plot_sample_efficiency(curves: dict, sizes: list[int], ranker_steps: int, local_steps: int, out: Path) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for d, c in curves.items():
        axes[0].plot(sizes, c["zeta"], marker="o", label=d)
        axes[1].plot(sizes, c["local"], marker="o", label=d)
    axes[0].set_title(f"ζσ: pairwise accuracy on test ({ranker_steps} steps)", fontsize=10)
    axes[0].set_xlabel("labelled clips")
    axes[1].set_title(f"RBA-Local: target above negative on test ({local_steps} steps)", fontsize=10)
    axes[1].set_xlabel("labelled local-change pairs")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xticks(sizes, [str(s) for s in sizes])
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--domains", nargs="+", default=list(domain_names()), choices=domain_names())
    ap.add_argument("--sizes", nargs="+", type=int, default=[25, 50, 100, 200])
    ap.add_argument("--ranker-steps", type=int, default=RankerConfig().steps, help="ζσ gradient steps per curve point")
    ap.add_argument("--local-steps", type=int, default=LocalTrainConfig().reward.steps,
                    help="RBA-Local gradient steps per curve point (fewer: a cheaper, rougher curve)")
    ap.add_argument("--skip-curves", action="store_true", help="only the ζσ-vs-proxy figure (no training)")
    ap.add_argument("--skip-zeta", action="store_true", help="only the sample-efficiency curves")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    start = time.perf_counter()
    if not args.skip_zeta:
        zeta_vs_proxy(args.domains, RESULTS / "zeta_vs_proxy.png")
    if not args.skip_curves:
        curves = sample_efficiency(args.domains, args.sizes, args.ranker_steps, args.local_steps,
                                   RESULTS / "sample_efficiency.png")
        save_json(RESULTS / "sample_efficiency.json", {"sizes": args.sizes, "ranker_steps": args.ranker_steps,
                                                       "local_steps": args.local_steps,
                                                       "curves": curves,
                                                       "seconds": round(time.perf_counter() - start)})


if __name__ == "__main__":
    main()
