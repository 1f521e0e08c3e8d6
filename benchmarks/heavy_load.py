"""Heavy-load benchmark: 200 interpret requests at once, and how long a light GET of a session waits meanwhile.

Each configuration starts the real server (``api_load.LiveServer``: a subprocess on 127.0.0.1, a fresh SQLite
database, no warm start, prerendering off) with its heavy-request limits (``server.api.admission``) set by
``RBA_HEAVY_*`` variables, starts one session, then fires ``--burst`` concurrent ``POST
/api/domains/walker/interpret`` requests (each on its own connection, all from 127.0.0.1) while a probe asks
``GET /api/sessions/{id}`` every ``--probe-every`` seconds. Reported per configuration: how the burst was answered
(status codes, transport errors, timeouts at ``--timeout`` seconds), its wall time, the light GET's latency
(p50 / p95 / max) before and during the burst, and the load average.

Configurations (``--configs``):

* ``default``: the settings' defaults (one client: past its share it gets 429);
* ``many_clients``: no per-client share (as if each request came from its own client): past the queue, 503;
* ``unbounded``: 32 heavy workers and no queue or per-client bound: close to a server without admission.

    python benchmarks/heavy_load.py                    # all three, writes benchmarks/results/heavy_load.{md,json}
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import shutil
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import httpx
from api_load import RESULTS, LiveServer, ServerOptions, start_run, summarize

from rba.core.fileio import save_report

OUTPUTS = ("heavy_load.json", "heavy_load.md")  # what this script writes into benchmarks/results/
CONFIGS = {  # name -> the server's RBA_HEAVY_* variables (unset: the defaults)
    "default": {},
    "many_clients": {"RBA_HEAVY_PER_CLIENT": "10000"},
    "unbounded": {"RBA_HEAVY_WORKERS": "32", "RBA_HEAVY_QUEUE": "10000", "RBA_HEAVY_PER_CLIENT": "10000"},
}
PHRASE = "take bigger steps"  # a walker phrasing the sentence model understands (tests/data/interpret_phrasings)
BASELINE_PROBES = 20

log = logging.getLogger("heavy_load")


@contextlib.contextmanager
def environment(variables: dict[str, str]) -> Iterator[None]:
    """``variables`` in this process's environment (the server subprocess inherits it) until the block ends."""
    saved = {k: os.environ.get(k) for k in variables}
    os.environ.update(variables)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def probe(url: str, every: float, stop: threading.Event, out: list[float], timeout: float) -> None:
    """GET ``url`` every ``every`` seconds until ``stop``; each latency (ms) into ``out`` (a failure: the timeout)."""
    with httpx.Client(timeout=timeout) as client:
        while not stop.is_set():
            t = time.perf_counter()
            try:
                client.get(url).raise_for_status()
                out.append((time.perf_counter() - t) * 1000)
            except httpx.HTTPError:
                out.append(timeout * 1000)
            stop.wait(every)


def burst(base: str, n: int, timeout: float) -> tuple[Counter, list[float]]:
    """``n`` interpret requests at once; how they were answered (status code, or the error's name) and the
    Retry-After values of the refusals."""
    answers: Counter = Counter()
    retry_after: list[float] = []
    lock, start = threading.Lock(), threading.Barrier(n)

    def one() -> None:
        with httpx.Client(base_url=base, timeout=timeout) as client:
            start.wait()
            try:
                r = client.post("/api/domains/walker/interpret", json={"text": PHRASE})
                answer = str(r.status_code)
                wait = r.headers.get("Retry-After")
            except httpx.TimeoutException:
                answer, wait = "timeout", None
            except httpx.HTTPError as exc:
                answer, wait = type(exc).__name__, None
        with lock:
            answers[answer] += 1
            if wait is not None:
                retry_after.append(float(wait))

    threads = [threading.Thread(target=one) for _ in range(n)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    return answers, retry_after


def run_config(name: str, args) -> dict:
    load_before = round(os.getloadavg()[0], 2)
    workdir = Path(tempfile.mkdtemp(prefix=f"rba-heavy-{name}-"))
    try:
        with environment(CONFIGS[name]):
            server = LiveServer(ServerOptions(prerender=False, heavy_per_client=None), workdir, workdir / "clips")
        try:
            with httpx.Client(base_url=server.url, timeout=args.timeout) as c:
                session = c.post("/api/sessions", json={"domain": "walker", "method": "global", "rep": "onehot"})
                session.raise_for_status()
            url = f"{server.url}/api/sessions/{session.json()['id']}"
            quiet: list[float] = []
            with httpx.Client(timeout=args.timeout) as c:  # one connection, as the probe during the burst
                for _ in range(BASELINE_PROBES):
                    t = time.perf_counter()
                    c.get(url).raise_for_status()
                    quiet.append((time.perf_counter() - t) * 1000)
                    time.sleep(args.probe_every)
            during: list[float] = []
            stop = threading.Event()
            prober = threading.Thread(target=probe, args=(url, args.probe_every, stop, during, args.timeout))
            prober.start()
            t = time.monotonic()
            answers, retry_after = burst(server.url, args.burst, args.timeout)
            wall = time.monotonic() - t
            stop.set()
            prober.join()
        finally:
            server.stop()
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    result = {"config": name, "variables": CONFIGS[name], "burst": args.burst, "answers": dict(sorted(answers.items())),
              "burst_seconds": round(wall, 1),
              "retry_after_s": summarize(retry_after) if retry_after else None,
              "get_session_ms_quiet": summarize(quiet), "get_session_ms_during": summarize(during),
              "load_average_before": load_before, "load_average_after": round(os.getloadavg()[0], 2)}
    log.info("%s: %s", name, json.dumps(result))
    return result


def markdown(report: dict) -> str:
    rows = ["| configuration | answers to the burst | burst s | GET session ms quiet p50 / p95 | "
            "during p50 / p95 / max (n) | Retry-After s p50 / max | load before / after |",
            "|---|---|---|---|---|---|---|"]
    for r in report["results"]:
        answers = ", ".join(f"{k}: {v}" for k, v in r["answers"].items())
        q, d, ra = r["get_session_ms_quiet"], r["get_session_ms_during"], r["retry_after_s"]
        retry = "-" if ra is None else f"{ra['p50']} / {ra['max']}"
        rows.append(f"| {r['config']} | {answers} | {r['burst_seconds']} | {q['p50']} / {q['p95']} | "
                    f"{d['p50']} / {d['p95']} / {d['max']} ({d['n']}) | "
                    f"{retry} | "
                    f"{r['load_average_before']} / {r['load_average_after']} |")
    return "\n".join([
        "# Heavy load: 200 interpret requests at once, and a light GET meanwhile",
        "",
        f"`{report['command']}` on {report['machine']}, {report['date']}. Heavy requests run in bounded slots "
        "(server/api/admission.py); `default` is the settings' limits, `many_clients` lifts the per-client share "
        "(503 past the queue), `unbounded` is close to a server without admission. Answers: HTTP status codes "
        f"(422: not understood), `timeout` after {report['args']['timeout']:g} s.",
        "",
        *rows,
        "",
        "NOTES",
        "",
    ])


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--configs", nargs="+", choices=sorted(CONFIGS), default=list(CONFIGS))
    p.add_argument("--burst", type=int, default=200, help="interpret requests fired at once")
    p.add_argument("--probe-every", type=float, default=0.1, help="seconds between light GETs during the burst")
    p.add_argument("--timeout", type=float, default=120.0, help="seconds a request may take")
    p.add_argument("--out", type=Path, default=RESULTS / "heavy_load")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    run = start_run("heavy_load.py", argv)
    report = {**run, "args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
              "results": [run_config(name, args) for name in args.configs]}
    save_report(args.out, report, markdown(report))
    log.info("wrote %s.json and %s.md", args.out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
