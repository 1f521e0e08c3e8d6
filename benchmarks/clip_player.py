"""The page's clip player (frontend/player.js) in headless Chromium with software WebGL, on a live local server.

Per domain, ``--clips`` serve clips fetched through the server's clip data routes (computed on its compute layer,
cached as the app does) and drawn by the player:

* the drawn frame against the MP4's: the agent's silhouette IoU at each clip's first, middle and last frame
  (``rba.media.silhouette``: MuJoCo's segmentation of the same frame, the agent car's colour for the road);
* a clip's first frame on screen: ``player.show`` of a clip not seen before until its first frame is drawn
  (the clip's data downloaded, its scene from the page's cache after the first);
* playing in real time at the studio page's clip size on a laptop (740x555) and a phone (360x270) window: one
  clip played through at 1x, the frames skipped (a frame whose time passed before the browser drew) in percent
  of the frames due, and the milliseconds of script each drawn frame took.

Writes ``benchmarks/results/clip_player.md`` and ``.json``; the machine's load average before and after.

    python benchmarks/clip_player.py                     # four domains, 5 clips each
    python benchmarks/clip_player.py --domains walker --clips 2
"""

from __future__ import annotations

import argparse
import base64
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from api_load import start_run

from rba.core.fileio import save_report
from rba.data.library import SkillLibrary
from rba.domains import get_domain
from rba.media.silhouette import agent_masks, iou
from server.common.app_settings import Settings
from server.main import serve_in_thread

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "clip_player.json", "clip_player.md",
)
DOMAINS = ("walker", "manipulator", "snake", "lane_change")
SIZES = {"laptop": ((1280, 800), (740, 555)), "phone": ((390, 844), (360, 270))}
CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run"]  # as tests/browser: software WebGL
PAGE = """<!doctype html><html lang="en"><head><meta charset="utf-8"><title>Clip player</title></head>
<body><div id="box" style="width:{w}px;height:{h}px"></div><script type="module">
import {{ ClipPlayer }} from "/static/player.js";
window.player = new ClipPlayer(document.getElementById("box"), {{ label: "Clip" }});
</script></body></html>"""
SHOW = """async ([d, id]) => { const t = performance.now();
  await player.show({ data_url: `/api/clips/${d}/${id}.json`, url: `/api/clips/${d}/${id}.mp4`, rollout_id: id });
  player.pause(); return performance.now() - t; }"""
PLAY = """() => new Promise((done) => { player.pause(); player.seek(0); player.loop = false; player.rate = 1;
  player.stats = { drawn: 0, dropped: 0, ms: 0 }; player.play();
  const wait = () => (player.paused ? done({ ...player.stats, frames: player.clip.frames }) : setTimeout(wait, 50));
  wait(); })"""


def open_page(browser, base: str, size: str):
    viewport, box = SIZES[size]
    page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
    page.route(f"{base}/player", lambda r: r.fulfill(content_type="text/html", body=PAGE.format(w=box[0], h=box[1])))
    page.goto(f"{base}/player")
    page.wait_for_function("() => window.player !== undefined")
    return page


def measure_domain(browser, base: str, domain: str, clips: int) -> dict:
    dom = get_domain(domain)
    lib = SkillLibrary.load(domain, "serve", REPO / "data")
    picks = np.linspace(0, len(lib) - 1, clips).astype(int)
    page = open_page(browser, base, "laptop")
    first_ms, ious = [], []
    for i in picks:
        rollout = lib.rollout(int(i))
        first_ms.append(page.evaluate(SHOW, [domain, rollout.id]))
        mode = page.evaluate("player.mode")
        if mode == "video":
            raise RuntimeError(f"{domain} {rollout.id}: the player fell back to the MP4")
        scene = page.evaluate("[player.clip.scene.width, player.clip.scene.height]")
        n = len(rollout.replay)
        frames = [0, n // 2, n - 1]
        for f, ref in zip(frames, agent_masks(dom, rollout, frames, *scene), strict=True):
            raw = base64.b64decode(page.evaluate("f => player.silhouette(f)", f))
            ious.append(iou(np.frombuffer(raw, np.uint8).reshape(scene[1], scene[0]).astype(bool), ref))
    page.close()
    play = {}
    for size in SIZES:
        page = open_page(browser, base, size)
        page.evaluate(SHOW, [domain, lib.rollout(int(picks[0])).id])
        stats = page.evaluate(PLAY)
        due = stats["drawn"] + stats["dropped"]
        play[size] = {"frames": stats["frames"], "drawn": stats["drawn"], "dropped": stats["dropped"],
                      "dropped_pct": 100 * stats["dropped"] / max(1, due),
                      "ms_per_frame": stats["ms"] / max(1, stats["drawn"])}
        page.close()
    return {"domain": domain, "mode": mode, "clips": len(picks), "iou": ious,
            "first_frame_ms": first_ms, "play": play}


def markdown(report: dict) -> str:
    lines = ["# The clip player in Chromium (software WebGL)", "",
             f"`{report['command']}` · {report['date']} · {report['machine']} · load average "
             f"{report['load'][0]:.1f} before, {report['load'][1]:.1f} after", "",
             "Agent silhouette IoU of the drawn frame against the MP4's (first, middle and last frame of each clip; "
             "goal ≥ 0.9); a new clip's first frame on screen (its data from the server's routes); one clip played "
             "at 1x at the studio page's clip size: frames skipped (goal ≤ 10 %) and the script's ms per drawn frame "
             "(software WebGL rasterises after it, which shows in the frames skipped). The first clip's first frame "
             "includes the server's compute workers starting and the domain's scene.", "",
             "| domain | drawn by | clips | IoU min | IoU median | first frame ms (median / max) | laptop skipped "
             "| laptop ms/frame | phone skipped | phone ms/frame |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in report["domains"]:
        lap, ph = r["play"]["laptop"], r["play"]["phone"]
        lines.append(f"| {r['domain']} | {r['mode']} | {r['clips']} | {min(r['iou']):.3f} | "
                     f"{statistics.median(r['iou']):.3f} | {statistics.median(r['first_frame_ms']):.0f} / "
                     f"{max(r['first_frame_ms']):.0f} | {lap['dropped_pct']:.1f} % | {lap['ms_per_frame']:.1f} | "
                     f"{ph['dropped_pct']:.1f} % | {ph['ms_per_frame']:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--domains", nargs="+", default=list(DOMAINS), choices=DOMAINS)
    p.add_argument("--clips", type=int, default=5, help="serve clips per domain, spread over the library")
    p.add_argument("--out", type=Path, default=RESULTS / "clip_player", help="writes <out>.json and <out>.md")
    args = p.parse_args(argv)
    if not 1 <= args.clips <= 50:
        p.error(f"--clips must be in 1..50, got {args.clips}")
    if not Path(CHROMIUM).exists():
        p.error(f"{CHROMIUM} is missing (apt-get install -y chromium)")
    from playwright.sync_api import sync_playwright

    run = start_run("clip_player.py", argv)
    load = [float(Path("/proc/loadavg").read_text().split()[0])]
    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as pw:
        settings = Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp}/rba.db",
                            cache_dir=Path(tmp) / "clips", warm_start=False, prerender=False)
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        with serve_in_thread(settings, timeout=30) as base:
            start = time.perf_counter()
            rows = [measure_domain(browser, base, d, args.clips) for d in args.domains]
        browser.close()
    load.append(float(Path("/proc/loadavg").read_text().split()[0]))
    report = {**run, "load": load, "seconds": time.perf_counter() - start, "domains": rows}
    save_report(args.out, report, markdown(report))
    print(markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
