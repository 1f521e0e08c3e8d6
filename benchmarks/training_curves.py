"""What writing training curves costs: each trainer's time with its curves (TensorBoard event files and the held-out
measure at ``HELD_OUT_POINTS`` steps, ``rba.learn.curves``) and without them.

Each row runs the real trainer of a method on one domain at a preset, every kind's steps capped at ``--steps``, in a
fresh process, once with curves and once without (the trainers then get no ``curve``, as before curves existed),
alternating which goes first per repeat. It records wall-clock and CPU seconds of the whole training call, and,
with curves, the seconds inside the held-out measures (timed around ``CurveWriter._measured``). Capping the steps
keeps the ten held-out points per model and shortens the rest, so the share measured here is larger than a full
run's. Writes ``benchmarks/results/training_curves.md`` and ``.json`` with the machine's load average.

    python benchmarks/training_curves.py                     # walker, global and local, tiny, 120 steps
    python benchmarks/training_curves.py --preset quick --steps 300 --repeats 2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from training_presets import capped_run  # a sibling script, on sys.path when run as one

from rba.core.fileio import save_report

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "training_curves.json", "training_curves.md",
)


def measure_one(method: str, domain: str, preset: str, steps: int, curves: bool) -> dict:
    """In this process: the training call's wall and CPU seconds, and the seconds its held-out measures took."""
    from rba.learn import curves as curves_module
    from rba.learn import training

    if not curves:
        training._curve = lambda *args, **kwargs: None  # the trainers' ``curve=None``: no writer, no measure
    spent = {"seconds": 0.0, "count": 0}
    measured = curves_module.CurveWriter._measured

    def timed(self) -> dict:
        t0 = time.perf_counter()
        try:
            return measured(self)
        finally:
            spent["seconds"] += time.perf_counter() - t0
            spent["count"] += 1
    curves_module.CurveWriter._measured = timed
    wall, cpu = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory() as models:
        capped_run(method, domain, preset, steps, Path(models))
        size = sum(p.stat().st_size for p in Path(models).rglob("events.out.tfevents.*"))
    return {"wall": round(time.perf_counter() - wall, 2), "cpu": round(time.process_time() - cpu, 2),
            "held_out_seconds": round(spent["seconds"], 2), "held_out_points": spent["count"], "event_bytes": size}


def measure(method: str, domain: str, preset: str, steps: int, curves: bool) -> dict:
    """``measure_one`` in a fresh process: nothing loaded or warmed up by an earlier run."""
    done = subprocess.run([sys.executable, __file__, "--one", method, "--domain", domain, "--preset", preset,
                           "--steps", str(steps), *([] if curves else ["--no-curves"])],
                          check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def markdown(report: dict) -> str:
    lines = [f"# Training curves: what writing them costs ({report['domain']}, {report['preset']})", "",
             f"Every kind's steps capped at {report['steps']}; {report['repeats']} repeat(s) each, alternating the "
             f"order; load average {report['load_average_before']} before, {report['load_average_after']} after, on "
             f"{report['cpus']} CPU cores. `python benchmarks/training_curves.py --domain {report['domain']} "
             f"--preset {report['preset']} --steps {report['steps']} --repeats {report['repeats']}`.", "",
             "Seconds of the whole training call (labels, steps, the card's held-out numbers, saving), the median of "
             "the repeats (of an even count, the higher): wall clock / CPU time of the training process.", "",
             "| method | without curves | with curves | CPU change | in held-out measures | points | event files |",
             "|---|---|---|---|---|---|---|"]
    for row in report["rows"]:
        off, on = row["without"], row["with"]
        change = 100 * (on["cpu"] - off["cpu"]) / off["cpu"]
        lines.append(f"| {row['method']} | {off['wall']} / {off['cpu']} | {on['wall']} / {on['cpu']} | "
                     f"{change:+.1f} % | {on['held_out_seconds']} s | {on['held_out_points']} | "
                     f"{on['event_bytes'] / 1024:.1f} KiB |")
    return "\n".join(lines) + "\n"


def _median(runs: list[dict]) -> dict:
    return {k: sorted(r[k] for r in runs)[len(runs) // 2] for k in runs[0]}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--domain", default="walker")
    p.add_argument("--methods", nargs="+", default=["global", "local"])
    p.add_argument("--preset", default="tiny")
    p.add_argument("--steps", type=int, default=120, help="gradient steps per kind at most")
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--out", type=Path, default=RESULTS / "training_curves")
    p.add_argument("--one", metavar="METHOD", help=argparse.SUPPRESS)  # one run, in its own process
    p.add_argument("--no-curves", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.one:
        print(json.dumps(measure_one(args.one, args.domain, args.preset, args.steps, not args.no_curves)))
        return 0
    report = {"domain": args.domain, "preset": args.preset, "steps": args.steps, "repeats": args.repeats,
              "cpus": os.cpu_count(), "load_average_before": round(os.getloadavg()[0], 2), "rows": []}
    for method in args.methods:
        runs: dict[bool, list[dict]] = {True: [], False: []}
        for r in range(args.repeats):
            for curves in ((True, False) if r % 2 == 0 else (False, True)):
                runs[curves].append(measure(method, args.domain, args.preset, args.steps, curves))
        row = {"method": method, "with": _median(runs[True]), "without": _median(runs[False]), "runs": {
            "with": runs[True], "without": runs[False]}}
        print(row, flush=True)
        report["rows"].append(row)
    report["load_average_after"] = round(os.getloadavg()[0], 2)
    save_report(args.out, report, markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
