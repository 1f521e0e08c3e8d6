"""Load benchmark of the web API: N scripted users tuning the walker at once, on a live local server.

Each configuration starts ``rba serve`` in a subprocess on 127.0.0.1 (a free port) with a
fresh SQLite database and a cold clip cache, warms it like ``RBA_WARM_START`` would (one
session renders the shared first clip), then runs N users in threads. A user starts a
session, downloads its clip, "watches" it for ``--watch`` seconds, answers like a
simulated person chasing a random target (more/less of the attribute furthest from it,
judged on the measured values the API returns), and repeats for ``--rounds`` rounds.

Measured per configuration:
* feedback latency: POST /feedback until its response arrives;
* next clip playable: POST /feedback until the new clip's MP4 is completely downloaded;
* whether the next clip was already rendered when the answer arrived (``clip.ready``).

Configurations: N in ``--users`` x prerendering on/off (``RBA_PRERENDER``). Every loop is
bounded by ``--rounds`` and by ``--time-limit`` seconds per configuration; all traffic goes
to 127.0.0.1. Results: ``benchmarks/results/api_load.json`` and ``.md``.

    python benchmarks/api_load.py                      # walker, N = 1 10 50, prerender on and off
    python benchmarks/api_load.py --users 10 --prerender on --watch 3
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import random
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx

from rba.storage import save_text

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
HOST = "127.0.0.1"  # loopback only
REQUEST_TIMEOUT = 120.0
GOALS = {"feedback_p95_ms_at_10": 100.0, "next_clip_p95_ms_with_prerender": 200.0}

log = logging.getLogger("api_load")


# ---------------------------------------------------------------- the server under test

def free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


class LiveServer:
    """``rba serve`` in a subprocess with its own database and clip cache."""

    def __init__(self, prerender: bool, workdir: Path, data_dir: Path | None, models_dir: Path | None,
                 register: str | None, cache_dir: Path | None = None) -> None:
        self.port = free_port()
        self.url = f"http://{HOST}:{self.port}"
        env = {**os.environ, "RBA_DATABASE_URL": f"sqlite:///{workdir / 'bench.db'}",
               "RBA_CACHE_DIR": str(cache_dir or workdir / "clips"), "RBA_PRERENDER": str(prerender).lower(),
               "RBA_WARM_START": "false", "RBA_LOG_LEVEL": "warning", "MUJOCO_GL": "egl"}
        if data_dir:
            env["RBA_DATA_DIR"] = str(data_dir)
        if models_dir:
            env["RBA_MODELS_DIR"] = str(models_dir)
        code = "import sys; from server.main import run; run(host=sys.argv[1], port=int(sys.argv[2]))"
        if register:  # e.g. the test suite's toy domain, "toy=tests.toy:Toy", for a quick smoke run
            name, target = register.split("=", 1)
            code = f"from rba.domains import register; register({name!r}, {target!r}); " + code
        self.log = open(workdir / "server.log", "wb")  # noqa: SIM115 (closed in stop())
        self.proc = subprocess.Popen([sys.executable, "-c", code, HOST, str(self.port)], cwd=REPO, env=env,
                                     stdout=self.log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the server exited; see {workdir / 'server.log'}")
            try:
                if httpx.get(f"{self.url}/healthz", timeout=1).status_code == 200:
                    return
            except httpx.TransportError:
                time.sleep(0.1)
        self.stop()
        raise RuntimeError("the server did not answer within 30 s")

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(15)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
        self.log.close()


# ---------------------------------------------------------------- scripted users

@dataclass
class UserLog:
    create_ms: float | None = None
    feedback_ms: list[float] = field(default_factory=list)
    next_clip_ms: list[float] = field(default_factory=list)
    ready_at_answer: list[bool] = field(default_factory=list)
    rounds: int = 0
    errors: list[str] = field(default_factory=list)


def choose(session: dict, target: dict[str, float]) -> dict:
    """More/less of the attribute whose measured value is furthest (relative to its range) from the target."""
    best, best_gap = None, 0.0
    for a in session["attributes"]:
        span = max((a["high"] or 1.0) - (a["low"] or 0.0), 1e-9)
        gap = (target[a["name"]] - session["clip"]["measured"][a["name"]]) / span
        if best is None or abs(gap) > abs(best_gap):
            best, best_gap = a["name"], gap
    return {"attribute": best, "direction": "more" if best_gap > 0 else "less"}


def fetch_clip(client: httpx.Client, url: str) -> None:
    r = client.get(url)
    r.raise_for_status()
    if not r.content:
        raise RuntimeError(f"empty clip {url}")


def run_user(base: str, domain: str, method: str, rep: str, rounds: int, watch: float, deadline: float,
             seed: int, out: UserLog) -> None:
    rng = random.Random(seed)
    with httpx.Client(base_url=base, timeout=REQUEST_TIMEOUT) as client:
        try:
            t = time.perf_counter()
            r = client.post("/api/sessions", json={"domain": domain, "method": method, "rep": rep})
            r.raise_for_status()
            out.create_ms = (time.perf_counter() - t) * 1000
            session = r.json()
            target = {a["name"]: rng.uniform(a["low"], a["high"]) for a in session["attributes"]}
            fetch_clip(client, session["clip"]["url"])
            for _ in range(rounds):
                time.sleep(watch)  # the person watches the looping clip
                if time.monotonic() > deadline:
                    break
                body = {"step": session["step"], "feedback": [choose(session, target)]}
                t = time.perf_counter()
                r = client.post(f"/api/sessions/{session['id']}/feedback", json=body)
                r.raise_for_status()
                out.feedback_ms.append((time.perf_counter() - t) * 1000)
                session = r.json()
                out.ready_at_answer.append(bool(session["clip"]["ready"]))
                fetch_clip(client, session["clip"]["url"])
                out.next_clip_ms.append((time.perf_counter() - t) * 1000)
                out.rounds += 1
            client.post(f"/api/sessions/{session['id']}/feedback", json={"step": session["step"], "satisfied": True})
        except (httpx.HTTPError, RuntimeError, KeyError) as exc:
            out.errors.append(f"{type(exc).__name__}: {exc}")


# ---------------------------------------------------------------- one configuration

def pct(values: list[float], q: float) -> float | None:
    if not values:
        return None
    if len(values) == 1:
        return round(values[0], 1)
    return round(statistics.quantiles(values, n=100, method="inclusive")[int(q) - 1], 1)


def summarize(values: list[float]) -> dict:
    return {"n": len(values), "p50": pct(values, 50), "p95": pct(values, 95),
            "max": round(max(values), 1) if values else None}


def run_config(args, users: int, prerender: bool) -> dict:
    load_before = round(os.getloadavg()[0], 2)  # other work on the machine skews every number below
    workdir = Path(tempfile.mkdtemp(prefix=f"rba-bench-{users}-{'on' if prerender else 'off'}-"))
    server = LiveServer(prerender, workdir, args.data_dir, args.models_dir, args.register, args.cache_dir)
    try:
        with httpx.Client(base_url=server.url, timeout=REQUEST_TIMEOUT) as c:  # warm-up: models + first clip
            t = time.perf_counter()
            s = c.post("/api/sessions", json={"domain": args.domain, "method": args.method, "rep": args.rep})
            s.raise_for_status()
            fetch_clip(c, s.json()["clip"]["url"])
            c.post(f"/api/sessions/{s.json()['id']}/abandon")
            warm_s = time.perf_counter() - t
        logs = [UserLog() for _ in range(users)]
        start = time.monotonic()
        deadline = start + args.time_limit
        threads = [threading.Thread(target=run_user, args=(server.url, args.domain, args.method, args.rep, args.rounds,
                                                           args.watch, deadline, args.seed * 1000 + i, logs[i]))
                   for i in range(users)]
        for i, th in enumerate(threads):
            th.start()
            time.sleep(min(args.ramp / max(users, 1), 0.2) if i else 0)  # people do not all click at once
        for th in threads:
            th.join(max(deadline - time.monotonic(), 0) + REQUEST_TIMEOUT)
        wall = time.monotonic() - start
    finally:
        server.stop()
    renders = sum(1 for _ in (workdir / "clips").rglob("*.mp4"))
    shutil.rmtree(workdir, ignore_errors=True)
    feedback = [x for u in logs for x in u.feedback_ms]
    next_clip = [x for u in logs for x in u.next_clip_ms]
    ready = [x for u in logs for x in u.ready_at_answer]
    result = {
        "users": users, "prerender": prerender, "rounds_done": sum(u.rounds for u in logs),
        "rounds_planned": users * args.rounds, "wall_seconds": round(wall, 1), "warm_up_seconds": round(warm_s, 1),
        "create_ms": summarize([u.create_ms for u in logs if u.create_ms is not None]),
        "feedback_ms": summarize(feedback), "next_clip_playable_ms": summarize(next_clip),
        "next_clip_ready_at_answer": round(sum(ready) / len(ready), 3) if ready else None,
        "clips_rendered": renders, "error_count": sum(len(u.errors) for u in logs),
        "errors": sorted({e for u in logs for e in u.errors})[:10], "load_average_before": load_before,
        "load_average_after": round(os.getloadavg()[0], 2),
    }
    log.info("N=%d prerender=%s: %s", users, prerender, json.dumps(result))
    return result


# ---------------------------------------------------------------- report

def fmt(v) -> str:
    return "–" if v is None else f"{v:g}"


def markdown(report: dict) -> str:
    a = report["args"]
    lines = [
        "# API load benchmark",
        "",
        f"`{report['command']}`  ",
        f"{report['date']} · {report['machine']} · domain `{a['domain']}` ({a['method']}/{a['rep']}) · "
        f"{a['rounds']} rounds per user · watching {a['watch']:g} s per clip · time limit {a['time_limit']:g} s "
        "per configuration · fresh database per configuration · "
        + (f"warm clip cache (`{a['cache_dir']}`, filled beforehand with `rba cache`)" if a.get("cache_dir") else
           "cold clip cache per configuration (after a one-session warm-up that renders the shared first clip)"),
        "",
        "| users | prerender | rounds done | feedback p50 / p95 (ms) | next clip playable p50 / p95 / max (ms) "
        "| next clip ready at answer | clips rendered | wall (s) | errors | load avg before → after |",
        "|---:|:---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in report["results"]:
        f, n = r["feedback_ms"], r["next_clip_playable_ms"]
        ready = "–" if r["next_clip_ready_at_answer"] is None else f"{r['next_clip_ready_at_answer']:.0%}"
        lines.append(f"| {r['users']} | {'on' if r['prerender'] else 'off'} | {r['rounds_done']}/{r['rounds_planned']} "
                     f"| {fmt(f['p50'])} / {fmt(f['p95'])} | {fmt(n['p50'])} / {fmt(n['p95'])} / {fmt(n['max'])} "
                     f"| {ready} | {r['clips_rendered']} | {r['wall_seconds']:g} | {r['error_count']} "
                     f"| {r['load_average_before']:g} → {r['load_average_after']:g} |")
    lines += ["", "Goals: feedback p95 ≤ 100 ms at N = 10; next clip playable p95 ≤ 200 ms with prerendering.", ""]
    for name, verdict in report["goals"].items():
        lines.append(f"- {name}: {verdict}")
    kinds = sorted({e for r in report["results"] for e in r["errors"]})
    lines += ["", "Definitions: *feedback* = POST /api/sessions/{id}/feedback until the response; *next clip "
              "playable* = the same POST until the new clip's MP4 is fully downloaded; *ready at answer* = the "
              "feedback response said the clip was already rendered (a prerender hit). Errors are requests that "
              f"timed out ({REQUEST_TIMEOUT:g} s) or failed: {kinds}. "
              "The load average (1 min, 2 cores) shows how busy the machine was besides the benchmark.", ""]
    return "\n".join(lines)


def judge(results: list[dict]) -> dict[str, str]:
    goals = {}
    at10 = [r for r in results if r["users"] == 10]
    for r in at10:
        p95 = r["feedback_ms"]["p95"]
        ok = p95 is not None and p95 <= GOALS["feedback_p95_ms_at_10"]
        goals[f"feedback p95 at N=10, prerender {'on' if r['prerender'] else 'off'}"] = \
            f"{fmt(p95)} ms — {'met' if ok else 'NOT met'}"
    for r in results:
        if r["prerender"]:
            p95 = r["next_clip_playable_ms"]["p95"]
            ok = p95 is not None and p95 <= GOALS["next_clip_p95_ms_with_prerender"]
            goals[f"next clip playable p95 at N={r['users']} with prerender"] = \
                f"{fmt(p95)} ms — {'met' if ok else 'NOT met'}"
    return goals


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--users", type=int, nargs="+", default=[1, 10, 50])
    p.add_argument("--prerender", choices=("on", "off", "both"), default="both")
    p.add_argument("--rounds", type=int, default=4, help="feedback rounds per user")
    p.add_argument("--watch", type=float, default=3.0, help="seconds a user watches each clip before answering")
    p.add_argument("--time-limit", type=float, default=240.0, help="seconds per configuration; users stop after")
    p.add_argument("--ramp", type=float, default=3.0, help="seconds over which the users arrive")
    p.add_argument("--cache-dir", type=Path, default=None,
                   help="a clip cache filled beforehand (`rba cache walker`), shared by every configuration; "
                        "default: a cold cache per configuration")
    p.add_argument("--domain", default="walker")
    p.add_argument("--method", default="global")
    p.add_argument("--rep", default="onehot")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--data-dir", type=Path, default=None)
    p.add_argument("--models-dir", type=Path, default=None)
    p.add_argument("--register", default=None, help="register a domain in the server first, e.g. toy=tests.toy:Toy")
    p.add_argument("--out", type=Path, default=RESULTS / "api_load", help="writes <out>.json and <out>.md")
    args = p.parse_args(argv)
    if any(n < 1 or n > 200 for n in args.users) or not 1 <= args.rounds <= 50 or args.time_limit > 1800:
        p.error("users must be in 1..200, rounds in 1..50, time limit at most 1800 s")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    logging.getLogger("httpx").setLevel(logging.WARNING)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # unwind, so the server subprocess is stopped
    modes = {"on": [True], "off": [False], "both": [True, False]}[args.prerender]
    results = [run_config(args, n, pre) for pre in modes for n in args.users]
    report = {
        "command": "python benchmarks/api_load.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "machine": f"{os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}",
        "args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "results": results,
        "goals": judge(results),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_text(args.out.with_suffix(".json"), json.dumps(report, indent=2) + "\n")
    save_text(args.out.with_suffix(".md"), markdown(report))
    log.info("wrote %s.json and %s.md", args.out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
