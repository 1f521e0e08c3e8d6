"""Clip data: server CPU and bytes per clip when the page draws the clip itself, against rendering its MP4.

For each domain, ``--clips`` rollouts spread evenly over the serve library go through what a compute worker runs
for a new clip's data (``rba.compute.tasks.describe``: per-frame poses, overlays, description, gzipped JSON; the
domain's scene made once before, as a worker keeps it) and, clip by clip in turn so that a change in machine load
hits both alike, through what it runs for the clip's MP4 (``rba.compute.tasks.render_here``: render and encode,
whole). CPU is this process's (``time.process_time``) plus its children's (the encoder), per clip; bytes are the
data's JSON raw and gzipped and the MP4's. The scene's cost (its first computation, with the model's load) and
size are reported once per domain. Writes ``benchmarks/results/clip_data.md`` and ``.json``.

    python benchmarks/clip_data.py                          # 4 domains, 20 clips each
    python benchmarks/clip_data.py --domains walker --clips 5
"""

from __future__ import annotations

import argparse
import gzip
import json
import logging
import os
import platform
import resource
import sys
import time
from pathlib import Path

import numpy as np

from rba.compute.base import RenderJob
from rba.compute.tasks import describe, render_here
from rba.core.fileio import report_path, save_markdown, save_text
from rba.core.settings import LibrarySettings
from rba.data.library import SkillLibrary
from rba.domains import domain_target

log = logging.getLogger("clip_data")

RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "clip_data.json", "clip_data.md",
)
DOMAINS = ("walker", "manipulator", "snake", "lane_change")
GOAL_MS = 30.0  # walker: server CPU per new clip's data, median


def cpu_seconds() -> float:
    """CPU of this process and of its children waited for (the MP4 encoder)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def timed(fn):
    cpu, wall = cpu_seconds(), time.perf_counter()
    out = fn()
    return out, cpu_seconds() - cpu, time.perf_counter() - wall


def measure_domain(name: str, clips: int, size: tuple[int, int]) -> dict:
    target, library = domain_target(name), SkillLibrary.load(name, "serve")
    scene, scene_cpu, _ = timed(lambda: describe(target, *size))
    picks = np.linspace(0, len(library) - 1, clips).round().astype(int)
    describe(target, *size, library.rollout(int(picks[0])))  # warm-up: the first clip's imports
    render_here(RenderJob.of(name, library.rollout(int(picks[0])), *size))
    rows = []
    for i in picks:
        rollout = library.rollout(int(i))
        data, cpu, wall = timed(lambda r=rollout: describe(target, *size, r))
        mp4, mp4_cpu, mp4_wall = timed(lambda r=rollout: render_here(RenderJob.of(name, r, *size)))
        rows.append({"rollout_id": rollout.id, "frames": len(rollout.replay), "cpu_ms": 1e3 * cpu,
                     "wall_ms": 1e3 * wall, "raw_bytes": len(gzip.decompress(data)), "gzip_bytes": len(data),
                     "mp4_cpu_ms": 1e3 * mp4_cpu, "mp4_wall_ms": 1e3 * mp4_wall, "mp4_bytes": len(mp4)})
        log.info("%s %s: data %.1f ms CPU, %d B; MP4 %.0f ms CPU, %d B", name, rollout.id, 1e3 * cpu, len(data),
                 1e3 * mp4_cpu, len(mp4))

    def stat(key: str, q: float) -> float:
        return round(float(np.percentile([r[key] for r in rows], q)), 2)

    return {"domain": name, "clips": len(rows), "scene_first_cpu_ms": round(1e3 * scene_cpu, 1),
            "scene_gzip_bytes": len(scene), "scene_raw_bytes": len(gzip.decompress(scene)),
            "cpu_ms_median": stat("cpu_ms", 50), "cpu_ms_p95": stat("cpu_ms", 95),
            "wall_ms_median": stat("wall_ms", 50), "raw_bytes_median": stat("raw_bytes", 50),
            "gzip_bytes_median": stat("gzip_bytes", 50), "mp4_bytes_median": stat("mp4_bytes", 50),
            "mp4_cpu_ms_median": stat("mp4_cpu_ms", 50), "mp4_cpu_ms_p95": stat("mp4_cpu_ms", 95),
            "frames_median": stat("frames", 50), "rows": rows}


def markdown(report: dict) -> str:
    lines = [
        "# Clip data: server CPU and bytes per clip, against the MP4",
        "",
        f"`{report['command']}` — {report['machine']}, load average (1/5/15 min) "
        f"{'/'.join(map(str, report['load_before']))} before, {'/'.join(map(str, report['load_after']))} after; "
        f"clips {report['size']}.",
        "",
        "Per new clip: the data a compute worker makes (`rba.compute.tasks.describe`: poses, overlays, description, "
        "gzipped JSON; the scene made once before) against rendering and encoding its MP4 (`render_here`), clip by "
        "clip in turn. CPU is the process's and its encoder's. The scene is fetched once per domain and cached "
        "(immutable per version).",
        "",
        "| domain | clips | frames | data CPU ms median / p95 | data wall ms | JSON KB raw / gzip | MP4 KB | "
        "MP4 CPU ms median / p95 | CPU ratio | bytes ratio | scene KB gzip (first CPU ms) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for d in report["domains"]:
        lines.append(
            f"| {d['domain']} | {d['clips']} | {d['frames_median']:g} "
            f"| {d['cpu_ms_median']:.1f} / {d['cpu_ms_p95']:.1f} "
            f"| {d['wall_ms_median']:.1f} | {d['raw_bytes_median'] / 1024:.1f} / {d['gzip_bytes_median'] / 1024:.1f} "
            f"| {d['mp4_bytes_median'] / 1024:.1f} | {d['mp4_cpu_ms_median']:.0f} / {d['mp4_cpu_ms_p95']:.0f} "
            f"| {d['mp4_cpu_ms_median'] / max(d['cpu_ms_median'], 1e-9):.0f}x "
            f"| {d['gzip_bytes_median'] / d['mp4_bytes_median']:.2f} "
            f"| {d['scene_gzip_bytes'] / 1024:.1f} ({d['scene_first_cpu_ms']:.0f}) |")
    walker = next((d for d in report["domains"] if d["domain"] == "walker"), None)
    if walker is not None:
        met = "met" if walker["cpu_ms_median"] <= GOAL_MS else "NOT met"
        lines += ["", f"Goal: walker ≤ {GOAL_MS:g} ms CPU median per new clip's data: {met} "
                      f"({walker['cpu_ms_median']:.1f} ms)."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--domains", nargs="+", default=list(DOMAINS), help="domains with clip data and a serve library")
    p.add_argument("--clips", type=int, default=20, help="rollouts per domain, spread evenly over the serve library")
    p.add_argument("--out", type=Path, default=RESULTS / "clip_data", help="writes <out>.json and <out>.md")
    args = p.parse_args(argv)
    if not 1 <= args.clips <= 200:
        p.error("--clips must be in 1..200")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    settings = LibrarySettings()
    size = (settings.clip_width, settings.clip_height)
    load_before = [round(x, 2) for x in os.getloadavg()]  # other work on the machine skews every number below
    domains = [measure_domain(name, args.clips, size) for name in args.domains]
    report = {
        "command": " ".join(["python benchmarks/clip_data.py", *(argv if argv is not None else sys.argv[1:])]),
        "date": time.strftime("%Y-%m-%d %H:%M"), "load_before": load_before,
        "load_after": [round(x, 2) for x in os.getloadavg()],
        "machine": f"{os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}",
        "size": f"{size[0]}x{size[1]}", "domains": domains,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_text(report_path(args.out, ".json"), json.dumps(report, indent=2) + "\n")
    text = markdown(report)
    save_markdown(report_path(args.out, ".md"), text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
