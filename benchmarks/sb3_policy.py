"""A policy from the tuned reward: how close does a Stable-Baselines3 policy trained on an export's rθ come to the
profile's attributes, in a time budget on this machine?

Each run is ``examples/sb3_policy/train.py`` on one held-out behaviour: a ``test`` library rollout exported as the
chosen behaviour with the shipped models (rθ conditioned on its ζσ), then SB3 trains on that reward alone from the
profile's start until ``--steps`` or ``--seconds``, whichever comes first. The learned policy's attributes are
measured from its episode's observations (``Domain.observed_proxies``) and reported as distance to the profile per
attribute, in normal-precision ε, beside the same network untrained, random actions and the scripted skill at the
profile's params. Writes ``benchmarks/results/sb3_policy.md`` and ``.json``.

    python benchmarks/sb3_policy.py --runs lane_change:test-00007:PPO walker:test-00007:PPO --seconds 330
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import os
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType
from typing import Any

import torch

from rba.core.fileio import machine, save_report
from rba.core.settings import REPO_ROOT

log = logging.getLogger("sb3_policy")
RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "sb3_policy.json", "sb3_policy.md",
)
EXAMPLE = REPO_ROOT / "examples" / "sb3_policy" / "train.py"
REFERENCES = ("trained", "untrained", "random", "skill")


def example() -> ModuleType:
    """``examples/sb3_policy/train.py`` as a module (the examples are scripts, not a package)."""
    spec = importlib.util.spec_from_file_location("sb3_policy_train", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def run_one(train: ModuleType, run: str, steps: int, seconds: float, every: int, seed: int,
            folder: Path) -> dict[str, Any]:
    """``domain:rollout:ALGO``: export the rollout, train, measure; the example's report."""
    domain, rollout, algo = run.split(":")
    out = folder / run.replace(":", "_")
    out.mkdir(parents=True)
    export = train.export_library_rollout(domain, rollout, out / "export.zip")
    log.info("%s: training for %d steps or %g s", run, steps, seconds)
    report = train.train(export, algo, steps, seed, out, seconds, every)
    log.info("%s\n%s", run, train.summary(report))
    return report


def markdown(report: dict[str, Any]) -> str:
    lines = ["# A policy from the tuned reward (Stable-Baselines3)", "",
             f"`{report['command']}`  ", f"{report['date']} · {report['machine']} · load average (1 min) "
             f"{report['load_average_before']:g} → {report['load_average_after']:g}", "",
             "Each run trains on one exported reward alone (a `test` rollout exported as the chosen behaviour with "
             "the shipped models), from the profile's start, for as many steps as the time budget allows. "
             "Distance to the profile per attribute in normal-precision ε (≤ 1: within, as the paper's users "
             "judge); the untrained network, random actions (mean of 3 episodes) and the scripted skill at the "
             "profile's params are the references. Σ rθ is the return under the export's reward (what training "
             "raises; the skill's is the profile's own).", "",
             "| run | steps | wall (s) | steps/s | policy | " + "distance per attribute (ε) | within ε | Σ rθ |",
             "|---|---:|---:|---:|---|---|:---:|---:|"]
    for r in report["runs"]:
        head = (f"{r['domain']} {r['rollout_id']} {r['algorithm']}", f"{r['steps']}", f"{r['wall_seconds']:g}",
                f"{r['steps_per_second']:g}")
        for i, name in enumerate(REFERENCES):
            m = r[name]
            dist = ", ".join(f"{a} {m['in_epsilon'][a]:.2f}" for a in r["epsilon"])
            within = m["within"] if isinstance(m["within"], bool) else f"{m['within']:.0%}"
            cells = head if i == 0 else ("", "", "", "")
            lines.append(f"| {' | '.join(cells)} | {name} | {dist} | {within} | {m['reward']:.4g} |")
    lines += ["", "## Distance during training", "",
              f"The deterministic policy measured every {report['args']['every']} steps (distance per attribute in ε; "
              "Σ rθ). Measuring is not counted as training time.", ""]
    for r in report["runs"]:
        lines += [f"**{r['domain']} {r['rollout_id']} {r['algorithm']}**", "",
                  "| steps | s | distance (ε) | within | Σ rθ |", "|---:|---:|---|:---:|---:|"]
        lines += [f"| {c['steps']} | {c['seconds']:g} | "
                  + ", ".join(f"{a} {c['in_epsilon'][a]:.2f}" for a in r["epsilon"])
                  + f" | {c['within']} | {c['reward']:.4g} |" for c in r["curve"]]
        lines.append("")
    lines += ["Per run, the profile's attributes, ε and each policy's measured attributes are in `sb3_policy.json`.",
              ""]
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", nargs="+", default=["lane_change:test-00007:PPO", "walker:test-00007:PPO"],
                   help="domain:rollout:ALGO per run (ALGO: PPO or SAC)")
    p.add_argument("--steps", type=int, default=1_000_000, help="env steps per run at most")
    p.add_argument("--seconds", type=float, default=360.0, help="training time per run at most")
    p.add_argument("--every", type=int, default=8192, help="measure the policy every this many steps")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=RESULTS / "sb3_policy", help="writes <out>.json and <out>.md")
    args = p.parse_args(argv)
    for run in args.runs:
        parts = run.split(":")
        if len(parts) != 3 or parts[2] not in ("PPO", "SAC"):
            p.error(f"a run is domain:rollout:ALGO with ALGO PPO or SAC (e.g. walker:test-00007:PPO), got {run!r}")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(1)  # small networks on a shared machine
    train = example()
    report: dict[str, Any] = {
        "command": "python benchmarks/sb3_policy.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "date": time.strftime("%Y-%m-%d %H:%M"), "machine": machine(),
        "load_average_before": round(os.getloadavg()[0], 2), "args": {**vars(args), "out": str(args.out)}}
    with tempfile.TemporaryDirectory(prefix="rba-sb3-") as folder:
        report["runs"] = [run_one(train, run, args.steps, args.seconds, args.every, args.seed, Path(folder))
                          for run in args.runs]
    report["load_average_after"] = round(os.getloadavg()[0], 2)
    save_report(args.out, report, markdown(report))
    log.info("wrote %s.json and %s.md", args.out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
