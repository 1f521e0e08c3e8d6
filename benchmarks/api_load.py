"""Load benchmark of the web API: N scripted users tuning the walker at once, on a live local server.

Each configuration starts the server in a subprocess on 127.0.0.1 (a free port) with a fresh
SQLite database, then runs N users in threads. A user starts a session, downloads its clip,
"watches" it for ``--watch`` seconds, answers like a simulated person chasing a random target
(more/less of the attribute furthest from it, judged on the measured values the API returns),
and repeats for ``--rounds`` rounds.

How the server starts:

* default (a bench start): ``RBA_WARM_START=false`` and a cold clip cache per configuration; the
  benchmark warms it with one session that renders the shared first clip;
* ``--warm-start``: as a real user gets it: ``RBA_WARM_START=true`` (the server loads its models,
  renders every context's first clip and, with prerendering on, queues the shared answer trees
  and then, with ``--prerender-library on``, the whole serve library), no benchmark session;
* ``--start-delay S``: the users start S seconds after the server first answers (the issue's
  "2 minutes after a cold start" is ``--warm-start --start-delay 120``);
* ``--cache-dir DIR``: one clip cache shared by every configuration instead of a cold one each;
  ``--fill-cache`` renders the domain's serve clips into it first (``rba cache``), so the run
  starts on a warm cache.

Measured per configuration:
* feedback latency: POST /feedback until its response arrives;
* next clip playable: POST /feedback until the new clip's MP4 is completely downloaded;
* whether the next clip was already rendered when the answer arrived (``clip.ready``);
* clips in the cache when the users started and when they finished; the server's renders (from
  its log: each render is logged with its time) before and while the users ran, urgent or guessed.

Configurations: N in ``--users`` x prerendering on/off (``RBA_PRERENDER``). Every loop is
bounded by ``--rounds`` and by ``--time-limit`` seconds per configuration; all traffic goes
to 127.0.0.1. Results: ``<out>.json`` and ``<out>.md`` (default ``benchmarks/results/api_load``).
Goals (the issue's): next clip playable p95 ≤ 300 ms at N = 10 with prerendering; feedback
p95 ≤ 100 ms at N = 50 while renders run.

    python benchmarks/api_load.py                      # walker, N = 1 10 50, prerender on and off
    python benchmarks/api_load.py --users 10 50 --prerender on --rounds 8 --warm-start --start-delay 120 \\
        --out benchmarks/results/api_load_cold         # cold cache
    python benchmarks/api_load.py --users 10 50 --prerender on --rounds 8 --warm-start --start-delay 120 \\
        --cache-dir /tmp/walker_clips --fill-cache --out benchmarks/results/api_load_warm
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import platform
import random
import re
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

from rba.core.fileio import save_report

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "api_load_cold.json", "api_load_cold.md", "api_load_warm.json", "api_load_warm.md",
)
HOST = "127.0.0.1"  # loopback only
REQUEST_TIMEOUT = 120.0
START_TIMEOUT = 90.0  # seconds for the server to answer /healthz (imports take a while on a busy machine)
GOALS = {"next_clip_p95_ms_at_10": 300.0, "feedback_p95_ms_at_50": 100.0}  # the issue's
RENDERED = re.compile(r"rba\.media\.clip_cache INFO rendered \S+ \(\d+ kB(?P<guess>, background)?\) in (?P<s>[\d.]+) s")

log = logging.getLogger("api_load")


# ---------------------------------------------------------------- the server under test

def free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


@dataclass(frozen=True)
class ServerOptions:
    """How the server under test is configured (each becomes an ``RBA_*`` variable)."""

    prerender: bool
    warm_start: bool = False  # the server's own warm-up (models, first clips, trees, library), as users get it
    prerender_library: bool = True  # with warm start and prerender: render the whole serve library as guesses
    domain: str = "walker"  # warmed up first
    data_dir: Path | None = None
    models_dir: Path | None = None
    register: str | None = None  # e.g. the test suite's toy domain, "toy=tests.toy:Toy", for a quick smoke run
    database_url: str | None = None  # default: a fresh SQLite file in the configuration's folder
    generate: bool = False  # RBA_GENERATE: RBA-Global sessions make new behaviours (benchmarks/generation_latency.py)
    generate_seconds: float | None = None  # RBA_GENERATE_SECONDS (None: the server's default)
    # RBA_HEAVY_PER_CLIENT: the simulated users all come from 127.0.0.1 but each stands for a person, so no share of
    # the heavy slots per address (None: the server's default, server/api/admission.py)
    heavy_per_client: int | None = 10_000


def server_env(opts: ServerOptions, workdir: Path, cache_dir: Path) -> dict[str, str]:
    env = {**os.environ, "RBA_DATABASE_URL": opts.database_url or f"sqlite:///{workdir / 'bench.db'}",
           "RBA_CACHE_DIR": str(cache_dir),
           "RBA_PRERENDER": str(opts.prerender).lower(), "RBA_WARM_START": str(opts.warm_start).lower(),
           "RBA_PRERENDER_LIBRARY": str(opts.prerender_library).lower(), "RBA_DEFAULT_DOMAIN": opts.domain,
           "RBA_GENERATE": str(opts.generate).lower(),
           **({} if opts.generate_seconds is None else {"RBA_GENERATE_SECONDS": str(opts.generate_seconds)}),
           "RBA_LOG_LEVEL": "info", "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}  # info: renders are logged
    if opts.heavy_per_client is not None:
        env["RBA_HEAVY_PER_CLIENT"] = str(opts.heavy_per_client)
    if opts.data_dir:
        env["RBA_DATA_DIR"] = str(opts.data_dir)
    if opts.models_dir:
        env["RBA_MODELS_DIR"] = str(opts.models_dir)
    return env


def python_code(register: str | None, code: str) -> str:
    """``code`` for ``python -c``, after registering the ``name=module:Class`` domain if one is given."""
    if not register:
        return code
    name, target = register.split("=", 1)
    return f"from rba.domains import register; register({name!r}, {target!r}); " + code


class LiveServer:
    """The server in a subprocess (its own process group) with its own database and clip cache."""

    def __init__(self, opts: ServerOptions, workdir: Path, cache_dir: Path) -> None:
        self.port = free_port()
        self.url = f"http://{HOST}:{self.port}"
        self.log_path = workdir / "server.log"
        code = python_code(opts.register, "import sys; from server.main import run; "
                                          "run(host=sys.argv[1], port=int(sys.argv[2]))")
        self.log = self.log_path.open("wb")  # closed in stop()
        self.proc = subprocess.Popen([sys.executable, "-c", code, HOST, str(self.port)], cwd=REPO,
                                     env=server_env(opts, workdir, cache_dir), stdout=self.log,
                                     stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.monotonic() + START_TIMEOUT
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the server exited; see {self.log_path}")
            try:
                if httpx.get(f"{self.url}/healthz", timeout=1).status_code == 200:
                    return
            except httpx.TransportError:
                time.sleep(0.1)
        self.stop()
        raise RuntimeError(f"the server did not answer within {START_TIMEOUT:g} s")

    def log_offset(self) -> int:
        """Where the server's log ends now: ``renders(since=...)`` counts what it logs after."""
        self.log.flush()
        return self.log_path.stat().st_size

    def renders(self, since: int = 0, until: int | None = None) -> dict:
        """The renders the server logged between two ``log_offset``s: urgent, guesses and their mean seconds."""
        with self.log_path.open("rb") as f:
            f.seek(since)
            text = f.read(None if until is None else until - since).decode(errors="replace")
        found = [(bool(m["guess"]), float(m["s"])) for m in RENDERED.finditer(text)]
        seconds = [sec for _, sec in found]
        return {"urgent": sum(not g for g, _ in found), "guesses": sum(g for g, _ in found),
                "mean_seconds": round(statistics.mean(seconds), 2) if seconds else None}

    def stop(self) -> None:
        """SIGTERM to the server (it stops its compute workers), then SIGKILL to what is left of its group."""
        self.proc.terminate()
        try:
            self.proc.wait(20)
        except subprocess.TimeoutExpired:
            log.warning("the server did not stop in 20 s; killing its process group")
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(5)
        self.log.close()


def fill_cache(opts: ServerOptions, cache_dir: Path) -> dict:
    """Render the domain's serve clips into ``cache_dir`` (``rba cache``; what is there already is kept)."""
    env = server_env(opts, cache_dir.parent, cache_dir)
    code = python_code(opts.register, f"import sys; from rba.cli import main; sys.exit(main(['cache', "
                                      f"{opts.domain!r}]))")
    before, start = count_clips(cache_dir), time.monotonic()
    subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, check=True)
    result = {"clips_before": before, "clips_after": count_clips(cache_dir),
              "seconds": round(time.monotonic() - start, 1)}
    log.info("filled %s: %s", cache_dir, result)
    return result


def count_clips(cache_dir: Path) -> int:
    return sum(1 for _ in cache_dir.rglob("*.mp4")) if cache_dir.exists() else 0


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


def options(args, prerender: bool) -> ServerOptions:
    return ServerOptions(prerender, args.warm_start, args.prerender_library == "on", args.domain, args.data_dir,
                         args.models_dir, args.register)


def bench_warm_up(server: LiveServer, args) -> float:
    """The bench start's warm-up: one session loads the models and renders the shared first clip; its seconds."""
    with httpx.Client(base_url=server.url, timeout=REQUEST_TIMEOUT) as c:
        t = time.perf_counter()
        s = c.post("/api/sessions", json={"domain": args.domain, "method": args.method, "rep": args.rep})
        s.raise_for_status()
        fetch_clip(c, s.json()["clip"]["url"])
        c.post(f"/api/sessions/{s.json()['id']}/abandon")
        return time.perf_counter() - t


def run_users(server: LiveServer, args, users: int) -> tuple[list[UserLog], float]:
    """``users`` scripted users arriving over ``--ramp`` seconds; their logs and the wall time."""
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
    return logs, time.monotonic() - start


def run_config(args, users: int, prerender: bool) -> dict:
    load_before = round(os.getloadavg()[0], 2)  # other work on the machine skews every number below
    workdir = Path(tempfile.mkdtemp(prefix=f"rba-bench-{users}-{'on' if prerender else 'off'}-"))
    cache_dir = args.cache_dir or workdir / "clips"
    server = LiveServer(options(args, prerender), workdir, cache_dir)
    try:
        warm_s = None if args.warm_start else bench_warm_up(server, args)
        time.sleep(args.start_delay)
        at_start, cached_at_start = server.log_offset(), count_clips(cache_dir)
        logs, wall = run_users(server, args, users)
        at_end, cached_at_end = server.log_offset(), count_clips(cache_dir)
        renders = {"before_users": server.renders(0, at_start), "during_users": server.renders(at_start, at_end)}
    finally:
        server.stop()
    if args.keep:
        log.info("kept %s", workdir)
    else:
        shutil.rmtree(workdir, ignore_errors=True)
    result = {
        "users": users, "prerender": prerender, "rounds_done": sum(u.rounds for u in logs),
        "rounds_planned": users * args.rounds, "wall_seconds": round(wall, 1),
        "warm_up_seconds": None if warm_s is None else round(warm_s, 1),
        "clips_cached_at_start": cached_at_start, "clips_cached_at_end": cached_at_end, "renders": renders,
        "load_average_before": load_before, "load_average_after": round(os.getloadavg()[0], 2), **latencies(logs),
    }
    log.info("N=%d prerender=%s: %s", users, prerender, json.dumps(result))
    return result


def latencies(logs: list[UserLog]) -> dict:
    feedback = [x for u in logs for x in u.feedback_ms]
    next_clip = [x for u in logs for x in u.next_clip_ms]
    ready = [x for u in logs for x in u.ready_at_answer]
    return {"create_ms": summarize([u.create_ms for u in logs if u.create_ms is not None]),
            "feedback_ms": summarize(feedback), "next_clip_playable_ms": summarize(next_clip),
            "next_clip_ready_at_answer": round(sum(ready) / len(ready), 3) if ready else None,
            "error_count": sum(len(u.errors) for u in logs), "errors": sorted({e for u in logs for e in u.errors})[:10]}


# ---------------------------------------------------------------- report

def fmt(v) -> str:
    return "–" if v is None else f"{v:g}"


def describe_start(a: dict, fill: dict | None) -> str:
    """How the server started and on which cache, in words, for the report's header."""
    if a["warm_start"]:
        start = ("the server's own warm-up as users get it (`RBA_WARM_START=true`: models, every context's first "
                 "clip, then the shared answer trees" + (" and the whole serve library" if a["prerender_library"]
                                                          == "on" else "") + " as guesses)")
    else:
        start = "bench start (`RBA_WARM_START=false`; one session renders the shared first clip)"
    start += f"; users start {a['start_delay']:g} s after the server first answered"
    if not a.get("cache_dir"):
        return start + " · cold clip cache per configuration"
    filled = (f", filled first with `rba cache` ({fill['clips_before']} → {fill['clips_after']} clips in "
              f"{fill['seconds']:g} s)") if fill else ""
    return start + f" · clip cache `{a['cache_dir']}` shared by every configuration{filled}"


def render_cell(r: dict) -> str:
    before, during = r["renders"]["before_users"], r["renders"]["during_users"]
    mean = "" if during["mean_seconds"] is None else f", {during['mean_seconds']:g} s each"
    return f"{before['urgent']} + {before['guesses']} | {during['urgent']} + {during['guesses']}{mean}"


def markdown(report: dict) -> str:
    a = report["args"]
    lines = [
        "# API load benchmark",
        "",
        f"`{report['command']}`  ",
        f"{report['date']} · {report['machine']} · domain `{a['domain']}` ({a['method']}/{a['rep']}) · "
        f"{a['rounds']} rounds per user · watching {a['watch']:g} s per clip · time limit {a['time_limit']:g} s "
        "per configuration · fresh server and database per configuration · "
        + describe_start(a, report.get("fill_cache")),
        "",
        "| users | prerender | rounds done | feedback p50 / p95 (ms) | next clip playable p50 / p95 / max (ms) "
        "| next clip ready at answer | clips cached at start → end | renders before users (urgent + guesses) "
        "| renders while users ran | wall (s) | errors | load avg before → after |",
        "|---:|:---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in report["results"]:
        f, n = r["feedback_ms"], r["next_clip_playable_ms"]
        ready = "–" if r["next_clip_ready_at_answer"] is None else f"{r['next_clip_ready_at_answer']:.0%}"
        lines.append(f"| {r['users']} | {'on' if r['prerender'] else 'off'} | {r['rounds_done']}/{r['rounds_planned']} "
                     f"| {fmt(f['p50'])} / {fmt(f['p95'])} | {fmt(n['p50'])} / {fmt(n['p95'])} / {fmt(n['max'])} "
                     f"| {ready} | {r['clips_cached_at_start']} → {r['clips_cached_at_end']} | {render_cell(r)} "
                     f"| {r['wall_seconds']:g} | {r['error_count']} "
                     f"| {r['load_average_before']:g} → {r['load_average_after']:g} |")
    lines += ["", f"Goals (the issue's): next clip playable p95 ≤ {GOALS['next_clip_p95_ms_at_10']:g} ms at N = 10 "
              f"with prerendering; feedback p95 ≤ {GOALS['feedback_p95_ms_at_50']:g} ms at N = 50 while renders run.",
              ""]
    for name, verdict in report["goals"].items():
        lines.append(f"- {name}: {verdict}")
    if not report["goals"]:
        lines.append("- not judged: no configuration the goals name (N = 10 with prerendering, N = 50) was run")
    kinds = sorted({e for r in report["results"] for e in r["errors"]})
    lines += ["", "Definitions: *feedback* = POST /api/sessions/{id}/feedback until the response; *next clip "
              "playable* = the same POST until the new clip's MP4 is fully downloaded; *ready at answer* = the "
              "feedback response said the clip was already rendered (a prerender hit); *clips cached* = MP4 files "
              "in the cache folder; *renders* = the renders the server logged (urgent: a request waits for it, or "
              "the warm-up's first clip of a context; guesses: prerender), before the users started and while they "
              "ran. Errors are requests that "
              f"timed out ({REQUEST_TIMEOUT:g} s) or failed: {kinds}. "
              f"The load average (1 min, {os.cpu_count()} cores) shows how busy the machine was besides the "
              "benchmark.", ""]
    return "\n".join(lines)


def verdict(value: float | None, goal: float, note: str = "") -> str:
    ok = value is not None and value <= goal
    return f"{fmt(value)} ms — {'met' if ok else 'NOT met'}{note}"


def judge(results: list[dict]) -> dict[str, str]:
    """The issue's goals on the configurations they name (other configurations are reported, not judged)."""
    goals = {}
    for r in results:
        if r["users"] == 10 and r["prerender"]:
            goals["next clip playable p95 at N=10 with prerender"] = \
                verdict(r["next_clip_playable_ms"]["p95"], GOALS["next_clip_p95_ms_at_10"])
        if r["users"] == 50:
            during = r["renders"]["during_users"]
            ran = during["urgent"] + during["guesses"]
            note = (f" ({ran} renders ran meanwhile)" if ran else
                    " (no render ran meanwhile: the 'while renders run' condition was not exercised)")
            goals[f"feedback p95 at N=50, prerender {'on' if r['prerender'] else 'off'}"] = \
                verdict(r["feedback_ms"]["p95"], GOALS["feedback_p95_ms_at_50"], note)
    return goals


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--users", type=int, nargs="+", default=[1, 10, 50])
    p.add_argument("--prerender", choices=("on", "off", "both"), default="both")
    p.add_argument("--rounds", type=int, default=8, help="feedback rounds per user")
    p.add_argument("--watch", type=float, default=3.0, help="seconds a user watches each clip before answering")
    p.add_argument("--time-limit", type=float, default=240.0, help="seconds per configuration; users stop after")
    p.add_argument("--ramp", type=float, default=3.0, help="seconds over which the users arrive")
    p.add_argument("--warm-start", action="store_true",
                   help="start the server as users get it (RBA_WARM_START=true: its own warm-up and, with "
                        "prerendering, the trees and library as guesses) instead of one benchmark warm-up session")
    p.add_argument("--prerender-library", choices=("on", "off"), default="on",
                   help="RBA_PRERENDER_LIBRARY: with --warm-start and prerendering, render the whole serve library")
    p.add_argument("--start-delay", type=float, default=0.0,
                   help="seconds between the server's first answer (and the bench warm-up) and the users' start")
    p.add_argument("--cache-dir", type=Path, default=None,
                   help="one clip cache shared by every configuration (e.g. filled beforehand with `rba cache "
                        "walker`, or see --fill-cache); default: a cold cache per configuration")
    p.add_argument("--fill-cache", action="store_true",
                   help="render the domain's serve clips into --cache-dir first (`rba cache`; kept clips stay)")
    p.add_argument("--domain", default="walker")
    p.add_argument("--method", default="global")
    p.add_argument("--rep", default="onehot")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--data-dir", type=Path, default=None)
    p.add_argument("--models-dir", type=Path, default=None)
    p.add_argument("--register", default=None, help="register a domain in the server first, e.g. toy=tests.toy:Toy")
    p.add_argument("--keep", action="store_true", help="keep each configuration's folder (database, server.log)")
    p.add_argument("--out", type=Path, default=RESULTS / "api_load", help="writes <out>.json and <out>.md")
    args = p.parse_args(argv)
    if any(n < 1 or n > 200 for n in args.users) or not 1 <= args.rounds <= 50 or args.time_limit > 1800:
        p.error("users must be in 1..200, rounds in 1..50, time limit at most 1800 s")
    if args.fill_cache and not args.cache_dir:
        p.error("--fill-cache needs --cache-dir")
    if not 0 <= args.start_delay <= 1800:
        p.error("the start delay must be in 0..1800 s")
    return args


def start_run(script: str, argv: list[str] | None) -> dict:
    """Logging and SIGTERM for a benchmark that drives a server subprocess; its report's command, date, machine."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    logging.getLogger("httpx").setLevel(logging.WARNING)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # unwind, so the server subprocess is stopped
    return {"command": f"python benchmarks/{script} " + " ".join(argv if argv is not None else sys.argv[1:]),
            "date": time.strftime("%Y-%m-%d %H:%M"),
            "machine": f"{os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}"}


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    run = start_run("api_load.py", argv)
    fill = fill_cache(options(args, True), args.cache_dir) if args.fill_cache else None
    modes = {"on": [True], "off": [False], "both": [True, False]}[args.prerender]
    results = [run_config(args, n, pre) for pre in modes for n in args.users]
    report = {
        **run,
        "args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "fill_cache": fill,
        "results": results,
        "goals": judge(results),
    }
    save_report(args.out, report, markdown(report))
    log.info("wrote %s.json and %s.md", args.out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
