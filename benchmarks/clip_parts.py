"""A clip someone waits for, whole on one worker or in parts on every worker: the wait, the bytes.

The compute layer renders a generated clip (someone always waits for it) in ``CLIP_PARTS`` parts,
one per worker of the pool, and joins them by stream copy (``rba.compute.base.RenderJob.parts``,
``rba.media.video.concat_mp4``). This measures what that buys on this machine: for each domain,
``--clips`` serve rollouts, each rendered both ways, taking turns clip by clip so that a change in
machine load hits both alike, wall-clock from
submission to the MP4's bytes:

* ``whole``: the clip in one piece on one urgent worker whose rasteriser has a thread per core
  (``tasks.render_clip`` without rows on ``LocalCompute(workers=1)``), as the app rendered it before;
* ``parts``: ``LocalCompute(workers=2).render`` of the job split in ``CLIP_PARTS``, what the app runs for a
  generated clip now (one rasteriser thread a worker).

Nothing else runs on the pool. The decoded frame count of every ``parts`` clip is checked against
the rollout's replay rows. Writes ``benchmarks/results/clip_parts.md`` and ``.json``.

    python benchmarks/clip_parts.py                      # 4 domains, 8 clips each
    python benchmarks/clip_parts.py --domains walker --clips 3
"""

from __future__ import annotations

import argparse
import logging
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import imageio_ffmpeg
import numpy as np
from api_load import start_run

from rba.compute import RenderJob, tasks
from rba.compute.base import CLIP_PARTS
from rba.compute.local import LocalCompute
from rba.core.fileio import save_report
from rba.core.settings import LibrarySettings
from rba.data.library import SkillLibrary

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "clip_parts.json", "clip_parts.md",
)
DOMAINS = ("walker", "manipulator", "lane_change", "snake")
WAYS = ("whole", "parts")
log = logging.getLogger("clip_parts")


def render(computes: dict[str, LocalCompute], job: RenderJob, way: str) -> tuple[float, bytes]:
    """Seconds from submission to the MP4's bytes, and the bytes."""
    start = time.perf_counter()
    if way == "whole":  # one task, no rows: the clip in one piece (the pool's own submit, as render did before)
        task = computes[way]._urgent.submit(tasks.render_clip, job.target, job.rollout, job.width, job.height)
    else:
        task = computes[way].render(replace(job, split=CLIP_PARTS), urgent=True)
    clip = task.future.result(300)
    return time.perf_counter() - start, clip


def frame_count(clip: bytes) -> int:
    with tempfile.NamedTemporaryFile(suffix=".mp4") as f:
        f.write(clip)
        f.flush()
        return imageio_ffmpeg.count_frames_and_secs(f.name)[0]


def measure_domain(computes: dict[str, LocalCompute], name: str, clips: int, size: tuple[int, int]) -> dict:
    lib = SkillLibrary.load(name, "serve")
    picks = [round(i * (len(lib) - 1) / max(clips - 1, 1)) for i in range(clips)]
    for way in WAYS:  # warm-up: each worker imports the domain and makes its renderer
        for _ in range(2):
            render(computes, RenderJob.of(name, lib.rollout(picks[0]), *size), way)
    seconds: dict[str, list[float]] = {w: [] for w in WAYS}
    sizes: dict[str, list[int]] = {w: [] for w in WAYS}
    frames, frames_ok = [], True
    for n, i in enumerate(picks):
        rollout = lib.rollout(i)
        job = RenderJob.of(name, rollout, *size)
        frames.append(len(rollout.replay))
        for way in (WAYS if n % 2 == 0 else WAYS[::-1]):
            took, clip = render(computes, job, way)
            seconds[way].append(took)
            sizes[way].append(len(clip))
            if way == "parts":
                frames_ok &= frame_count(clip) == len(rollout.replay)
    row = {"domain": name, "clips": clips, "frames_mean": round(statistics.mean(frames), 1),
           "all_frames_in_parts": frames_ok}
    for way in WAYS:
        row[way] = {"mean_ms": round(statistics.mean(seconds[way]) * 1000, 1),
                    "p95_ms": round(float(np.percentile(seconds[way], 95)) * 1000, 1),
                    "kb_mean": round(statistics.mean(sizes[way]) / 1024, 1)}
    row["saved"] = round(1 - row["parts"]["mean_ms"] / row["whole"]["mean_ms"], 3)
    log.info("%s: whole %.0f ms, parts %.0f ms", name, row["whole"]["mean_ms"], row["parts"]["mean_ms"])
    return row


def markdown(report: dict) -> str:
    lines = ["# A waited-for clip: whole on one worker, or in parts on every worker", "",
             f"`{report['command']}`  ", f"{report['date']} · {report['machine']} · load average (1 min) "
             f"{report['load'][0]:.2f} → {report['load'][1]:.2f} · clips {report['size']} · "
             f"{CLIP_PARTS} parts", "",
             __doc__.split("\n\n")[1].replace("\n", " "), "",
             "| domain | clips | frames (mean) | whole: mean / p95 ms | **parts: mean / p95 ms** | saved | "
             "MP4 kB mean (whole → parts) | every frame in the joined clip |",
             "|---|---:|---:|---:|---:|---:|---:|---|"]
    for r in report["domains"]:
        w, p = r["whole"], r["parts"]
        lines.append(f"| {r['domain']} | {r['clips']} | {r['frames_mean']} | {w['mean_ms']:.0f} / {w['p95_ms']:.0f} | "
                     f"**{p['mean_ms']:.0f} / {p['p95_ms']:.0f}** | {r['saved']:.0%} | {w['kb_mean']} → "
                     f"{p['kb_mean']} | {r['all_frames_in_parts']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--domains", nargs="+", default=list(DOMAINS), choices=DOMAINS)
    p.add_argument("--clips", type=int, default=8, help="serve clips per domain, spread over the library")
    p.add_argument("--out", type=Path, default=RESULTS / "clip_parts", help="writes <out>.json and <out>.md")
    args = p.parse_args(argv)
    if not 2 <= args.clips <= 200:
        p.error(f"--clips must be in 2..200, got {args.clips}")
    settings = LibrarySettings()
    size = (settings.clip_width, settings.clip_height)
    run = start_run("clip_parts.py", argv)
    load = [float(Path("/proc/loadavg").read_text().split()[0])]
    with LocalCompute(workers=1) as whole, LocalCompute(workers=2) as parts:
        rows = [measure_domain({"whole": whole, "parts": parts}, d, args.clips, size) for d in args.domains]
    load.append(float(Path("/proc/loadavg").read_text().split()[0]))
    report = {**run, "load": load, "size": f"{size[0]}x{size[1]}", "domains": rows}
    save_report(args.out, report, markdown(report))
    print(markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
