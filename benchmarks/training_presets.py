"""How long each training preset takes on this machine, by phase: what the admin page's time estimate starts from.

A training job runs in phases: setup (loading the libraries, making the labels), then per model kind its
gradient steps and, after its last step, its measuring (held-out numbers on val, saving the model). For every
trainable method and preset this runs the real trainer on one domain with each kind's steps capped at
``--steps`` and times the phases from the trainer's own progress reports:

* ``setup``: from the call to the first step's report;
* ``step``: seconds per gradient step, from a stage's second report (step 51) to its last: its first steps are
  slower (a kind's lazy start-up), and what they took beyond that rate counts as setup;
* ``measure``: from a stage's last step to the next stage's first report, or to the trainer's return.

A preset's typical duration is ``setup + Σ (steps × step + measure)`` with its full step counts. Each row runs in
a process of its own, timed by the wall clock and by the process's CPU time (which other work on a shared machine
hardly changes; with 2 torch threads an idle machine's wall clock is at most that). The CPU numbers are recorded
in ``rba.learn.training`` (``Preset.typical``), where the estimate of a job's time left
(``server.ops.training_jobs.eta_seconds``) takes them for the phases it has not measured yet. Writes
``benchmarks/results/training_presets.md`` and ``.json`` with the machine's load average.

    python benchmarks/training_presets.py                    # walker, every method and preset
    python benchmarks/training_presets.py --methods local --presets tiny --steps 60
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from rba.core.fileio import save_report
from rba.core.methods import get_method, trainable
from rba.learn.training import GlobalTrainConfig, LocalTrainConfig, plan_steps, train_global, train_local

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "training_presets.json", "training_presets.md",
)
log = logging.getLogger("training_presets")


def capped_run(method: str, domain: str, preset: str, steps: int, models: Path, on_progress=None) -> None:
    """The method's trainer at ``preset`` with every kind's steps capped at ``steps``."""
    if method == "local":
        cfg = LocalTrainConfig.preset(preset)
        train_local(domain, "onehot", replace(cfg, reward=replace(cfg.reward, steps=min(cfg.reward.steps, steps))),
                    models_root=models, on_progress=on_progress)
        return
    cfg = GlobalTrainConfig.preset(preset, domain=domain)
    cfg = replace(cfg, ranker=replace(cfg.ranker, steps=min(cfg.ranker.steps, steps)),
                  reward=replace(cfg.reward, steps=min(cfg.reward.steps, steps)))
    train_global(domain, "onehot", cfg, models_root=models, on_progress=on_progress)


def _phases(reports: list[tuple[str, int, float]], end: float, kinds: tuple[str, ...]) -> dict:
    """Setup, per kind its steady seconds per step and its measuring, from (stage, step, clock) reports.

    A kind's first steps are slower (lazy start-up): its rate is taken from its second report on, and what its
    first steps took beyond that rate counts as setup, a fixed cost of the job like loading.
    """
    out: dict = {"setup": reports[0][2], "step": {}, "measure": {}}
    for kind in kinds:
        mine = [r for r in reports if r[0].startswith(f"{kind}[")]
        (_, s0, t0), (_, s1, t1), (_, s2, t2) = mine[0], mine[1], mine[-1]
        rate = (t2 - t1) / max(1, s2 - s1)
        out["step"][kind] = round(rate, 4)
        out["setup"] += max(0.0, (t1 - t0) - (s1 - s0) * rate)
        later = [r[2] for r in reports if r[2] > t2 and not r[0].startswith(f"{kind}[")]
        out["measure"][kind] = round((later[0] if later else end) - t2, 2)
    out["setup"] = round(out["setup"], 2)
    return out


def measure_one(method: str, domain: str, preset: str, steps: int) -> dict:
    """In this process: the phases by wall clock and by this process's CPU time (which the machine's load hardly
    changes), and the full run's typical seconds by each."""
    reports: dict[str, list] = {"wall": [], "cpu": []}
    clocks = {"wall": time.perf_counter, "cpu": time.process_time}
    start = {name: clock() for name, clock in clocks.items()}

    def report(stage: str, step: int, total: int, loss: float) -> None:
        for name, clock in clocks.items():
            reports[name].append((stage, step, clock() - start[name]))

    with tempfile.TemporaryDirectory() as models:
        capped_run(method, domain, preset, steps, Path(models), report)
    kinds = get_method(method).model_kinds
    full = plan_steps(preset, kinds, domain)
    out: dict = {"steps": full}
    for name, clock in clocks.items():
        phases = _phases(reports[name], clock() - start[name], kinds)
        phases["typical_seconds"] = round(phases["setup"] + sum(
            full[k] * phases["step"][k] + phases["measure"][k] for k in kinds), 1)
        out[name] = phases
    return out


def measure(method: str, domain: str, preset: str, steps: int) -> dict:
    """``measure_one`` in a fresh process: nothing loaded or warmed up by an earlier row."""
    done = subprocess.run([sys.executable, __file__, "--one", method, preset, "--domain", domain,
                           "--steps", str(steps)], check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def _both(wall: dict, cpu: dict, key: str) -> str:
    return ", ".join(f"{k} {wall[key][k]} / {cpu[key][k]}" for k in wall[key])


def markdown(report: dict) -> str:
    lines = [f"# Training presets: phases and typical durations ({report['domain']})", "",
             f"Each kind's steps capped at {report['steps_measured']}; load average {report['load_average_before']} "
             f"before, {report['load_average_after']} after, on {report['cpus']} CPU cores. `python "
             "benchmarks/training_presets.py`.", "",
             "Per row: wall clock / CPU seconds of the training process.", "",
             "| method | preset | setup s | s / step | measuring s | full steps | typical duration |",
             "|---|---|---|---|---|---|---|"]
    for row in report["rows"]:
        wall, cpu = row["wall"], row["cpu"]
        lines.append(f"| {row['method']} | {row['preset']} | {wall['setup']} / {cpu['setup']} | "
                     f"{_both(wall, cpu, 'step')} | {_both(wall, cpu, 'measure')} | "
                     f"{', '.join(f'{k} {n}' for k, n in row['steps'].items())} | "
                     f"{wall['typical_seconds'] / 60:.1f} / {cpu['typical_seconds'] / 60:.1f} min |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--domain", default="walker")
    p.add_argument("--methods", nargs="+", default=[m.name for m in trainable()])
    p.add_argument("--presets", nargs="+", default=None, help="default: each method's own")
    p.add_argument("--steps", type=int, default=110, help="gradient steps per kind at most (>= 102: the rate is "
                   "taken from the second report, at step 51, on)")
    p.add_argument("--out", type=Path, default=RESULTS / "training_presets")
    p.add_argument("--one", nargs=2, metavar=("METHOD", "PRESET"), help=argparse.SUPPRESS)  # a row, in its process
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    if args.one:
        print(json.dumps(measure_one(args.one[0], args.domain, args.one[1], args.steps)))
        return 0
    report = {"domain": args.domain, "steps_measured": args.steps, "cpus": os.cpu_count(),
              "load_average_before": round(os.getloadavg()[0], 2), "rows": []}
    for method in args.methods:
        for preset in args.presets or get_method(method).presets:
            if preset not in get_method(method).presets:
                continue
            row = {"method": method, "preset": preset, **measure(method, args.domain, preset, args.steps)}
            print(row, flush=True)
            report["rows"].append(row)
    report["load_average_after"] = round(os.getloadavg()[0], 2)
    save_report(args.out, report, markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
