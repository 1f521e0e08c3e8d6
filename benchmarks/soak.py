"""Soak benchmark: N scripted users tuning the walker without pause for M minutes, on SQLite and on PostgreSQL.

The server runs in a subprocess on 127.0.0.1 with a fresh database and a cold clip cache, prerendering on
(as ``rba serve`` runs). Each user repeats sessions back to back (``api_load.run_user``: start, watch each
clip, answer, finish satisfied after ``--rounds`` rounds) until the time is up. Every ``--sample`` seconds
the benchmark reads the resident memory (``VmRSS``) of the API process and of its whole process group
(the API plus its compute workers).

Reported per database: sessions finished, feedback requests and their latency, errors (any failed or
timed-out request), and the API's RSS when the users started, at the end and at its peak. Memory is
judged *flat* when the API's RSS at the end is within ``FLAT_GROWTH`` of its RSS after the first two
minutes (start-up allocations and the first models settle in those).

PostgreSQL: ``--postgres-url`` (default ``$RBA_TEST_POSTGRES_URL``) names a server the benchmark may
create a throwaway database on (dropped afterwards).

    python benchmarks/soak.py                               # 50 users, 10 minutes, SQLite and PostgreSQL
    python benchmarks/soak.py --users 5 --minutes 1 --db sqlite --out /tmp/soak   # a smoke run
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import sys
import tempfile
import threading
import time
import uuid
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from api_load import LiveServer, ServerOptions, UserLog, run_user, start_run, summarize
from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url

from rba.core.fileio import save_report

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
OUTPUTS = ("soak.json", "soak.md")  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
FLAT_GROWTH = 0.05  # the API's RSS may end at most 5 % above its level after the first two minutes
SETTLE_SECONDS = 120.0

log = logging.getLogger("soak")


def rss_mb(pid: int) -> float | None:
    """Resident memory of one process in MB (None once it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None


def group_rss_mb(pgid: int) -> float:
    """Resident memory of every process in a process group (the API and its compute workers)."""
    total = 0.0
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError, IndexError):
            continue
        if int(fields[2]) == pgid:  # after ")": state, ppid, pgrp
            total += rss_mb(int(stat.parent.name)) or 0.0
    return total


@dataclass
class MemorySampler:
    """Samples (seconds since start, API MB, group MB) on a thread until stopped."""

    pid: int
    every: float
    samples: list[tuple[float, float, float]] = field(default_factory=list)
    _stop: threading.Event = field(default_factory=threading.Event)

    def run(self) -> None:
        start = time.monotonic()
        while True:
            api = rss_mb(self.pid)
            if api is not None:
                self.samples.append((round(time.monotonic() - start, 1), round(api, 1),
                                     round(group_rss_mb(self.pid), 1)))
            if self._stop.wait(self.every):
                return

    def stop(self) -> None:
        self._stop.set()

    def summary(self) -> dict:
        api = [s[1] for s in self.samples]
        settled = next((s[1] for s in self.samples if s[0] >= SETTLE_SECONDS), api[0])
        growth = (api[-1] - settled) / settled
        return {"api_rss_mb_start": api[0], "api_rss_mb_after_settle": settled, "api_rss_mb_end": api[-1],
                "api_rss_mb_max": max(api), "group_rss_mb_start": self.samples[0][2],
                "group_rss_mb_end": self.samples[-1][2], "growth_after_settle": round(growth, 3),
                "flat": growth <= FLAT_GROWTH, "samples": self.samples}


@contextmanager
def throwaway_postgres(url: str):
    """A fresh database on the PostgreSQL server ``url`` points at; dropped afterwards."""
    name = f"rba_soak_{uuid.uuid4().hex[:8]}"
    admin = create_engine(make_url(url).set(database="postgres"), isolation_level="AUTOCOMMIT")
    with admin.connect() as c:
        c.execute(text(f'CREATE DATABASE "{name}"'))
    try:
        yield make_url(url).set(database=name).render_as_string(hide_password=False)
    finally:
        with admin.connect() as c:
            c.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


def soak_user(base: str, args, deadline: float, seed: int, out: UserLog, sessions: list[int]) -> None:
    """Sessions back to back until the deadline; a failed session is logged and the user starts another."""
    n = 0
    while time.monotonic() < deadline:
        run_user(base, "walker", "global", "onehot", args.rounds, args.watch, deadline, seed * 1000 + n, out)
        n += 1
    sessions.append(n)


def soak(args, db: str, database_url: str | None) -> dict:
    workdir = Path(tempfile.mkdtemp(prefix=f"rba-soak-{db}-"))
    server = LiveServer(ServerOptions(prerender=True, database_url=database_url), workdir, workdir / "clips")
    sampler = MemorySampler(server.proc.pid, args.sample)
    logs = [UserLog() for _ in range(args.users)]
    sessions: list[int] = []
    try:
        threading.Thread(target=sampler.run, daemon=True).start()
        deadline = time.monotonic() + args.minutes * 60
        threads = [threading.Thread(target=soak_user, args=(server.url, args, deadline, i, logs[i], sessions))
                   for i in range(args.users)]
        for th in threads:
            th.start()
            time.sleep(0.1)
        for th in threads:
            th.join()
        sampler.stop()
        alive = server.proc.poll() is None
    finally:
        server.stop()
        shutil.rmtree(workdir, ignore_errors=True)
    errors = sorted({e for u in logs for e in u.errors})
    result = {"db": db, "users": args.users, "minutes": args.minutes, "server_alive_at_end": alive,
              "sessions": sum(sessions), "feedback_ms": summarize([x for u in logs for x in u.feedback_ms]),
              "next_clip_playable_ms": summarize([x for u in logs for x in u.next_clip_ms]),
              "error_count": sum(len(u.errors) for u in logs), "errors": errors[:10], **sampler.summary()}
    log.info("%s: %d sessions, %d feedbacks, %d errors, API RSS %.0f → %.0f MB", db, result["sessions"],
             result["feedback_ms"]["n"], result["error_count"], result["api_rss_mb_start"], result["api_rss_mb_end"])
    return result


def markdown(report: dict) -> str:
    lines = ["# Soak benchmark", "", f"`{report['command']}`  ",
             f"{report['date']} · {report['machine']} · walker (global/onehot) · prerendering on · cold clip cache "
             f"· {report['args']['rounds']} rounds per session, watching {report['args']['watch']:g} s per clip",
             "", "| database | users | minutes | sessions | feedbacks | feedback p50 / p95 (ms) | next clip p50 / p95 "
             "(ms) | errors | API RSS start → after 2 min → end (max) MB | API + workers RSS start → end MB "
             "| memory |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in report["results"]:
        f, n = r["feedback_ms"], r["next_clip_playable_ms"]
        lines.append(f"| {r['db']} | {r['users']} | {r['minutes']:g} | {r['sessions']} | {f['n']} | {f['p50']} / "
                     f"{f['p95']} | {n['p50']} / {n['p95']} | {r['error_count']} | {r['api_rss_mb_start']:.0f} → "
                     f"{r['api_rss_mb_after_settle']:.0f} → {r['api_rss_mb_end']:.0f} ({r['api_rss_mb_max']:.0f}) | "
                     f"{r['group_rss_mb_start']:.0f} → {r['group_rss_mb_end']:.0f} | "
                     f"{'flat' if r['flat'] else 'GROWS'} ({r['growth_after_settle']:+.1%}) |")
    lines += ["", f"Goal (the issue's): 0 errors and memory flat. *Flat*: the API's RSS at the end is at most "
              f"{FLAT_GROWTH:.0%} above its RSS after the first {SETTLE_SECONDS:g} s. Errors: any request that "
              f"failed or timed out: {sorted({e for r in report['results'] for e in r['errors']})}.", ""]
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--users", type=int, default=50)
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--rounds", type=int, default=8, help="answers per session before it ends satisfied")
    p.add_argument("--watch", type=float, default=3.0, help="seconds a user watches each clip before answering")
    p.add_argument("--sample", type=float, default=10.0, help="seconds between memory samples")
    p.add_argument("--db", choices=("sqlite", "postgres", "both"), default="both")
    p.add_argument("--postgres-url", default=os.environ.get("RBA_TEST_POSTGRES_URL"))
    p.add_argument("--out", type=Path, default=RESULTS / "soak", help="writes <out>.json and <out>.md")
    args = p.parse_args(argv)
    if not 1 <= args.users <= 200 or not 0 < args.minutes <= 60 or not 1 <= args.rounds <= 50:
        p.error("users must be in 1..200, minutes in (0, 60], rounds in 1..50")
    if args.db != "sqlite" and not args.postgres_url:
        p.error("PostgreSQL needs --postgres-url (or RBA_TEST_POSTGRES_URL); or pass --db sqlite")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    run = start_run("soak.py", argv)
    results = []
    if args.db in ("sqlite", "both"):
        results.append(soak(args, "SQLite", None))
    if args.db in ("postgres", "both"):
        with throwaway_postgres(args.postgres_url) as url:
            results.append(soak(args, "PostgreSQL", url))
    report = {**run,
              "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items() if k != "postgres_url"},
              "results": results}
    save_report(args.out, report, markdown(report))
    log.info("wrote %s.json and %s.md", args.out, args.out)
    return 0 if all(r["error_count"] == 0 and r["flat"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
