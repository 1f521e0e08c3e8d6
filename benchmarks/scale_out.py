"""Scale-out on Ray: a library build and its full render on 1 vs 2 worker nodes, and a projection to 32 cores.

For each node count in ``--nodes`` (default 1 2) a fresh Ray cluster starts on this machine, all on
127.0.0.1 (``ray.cluster_utils.Cluster``: a head with no CPUs, N worker nodes with one CPU each), and
``make_compute(ray_address=cluster.address)`` connects to it. With ``--pin`` (the default) each worker
node's processes are also pinned to one core of their own (node i on core i): Ray's ``num_cpus=1`` only
limits how many tasks a node runs, while software OpenGL and the H.264 encoder would use every core.
After an untimed warm-up (a few simulations and renders, so every worker has imported the simulator
and made its renderer), two things are timed on the same backend the app and ``rba build --ray`` use:

a. a library build: ``rba.data.library.generate(domain, "serve", --rollouts, compute=ray)``;
b. a full render of that library's first ``--clips`` clips into a fresh ``ClipStore``
   (``ClipCache.fill``, as ``rba cache`` does).

Reported: seconds per rollout and per clip on one node (the per-task cost), the speed-up of 2 nodes
over 1 (goal ≥ 1.8), whether both runs gave the same library and the same clips, and the projected
time for a 100,000-rollout library (simulated and rendered) on 32 cores: 100,000 x per-task cost / 32,
assuming linear scaling, and the same divided by the measured 2-node efficiency (speed-up / 2).
Every listening TCP socket of this process's tree is logged after each cluster starts and after
its work; any outside 127.0.0.1 is reported. Numbers mean something only on an otherwise idle
machine: the report states the load average before and after.

    python benchmarks/scale_out.py                                  # 400 rollouts, 120 clips, 1 and 2 nodes
    python benchmarks/scale_out.py --rollouts 8 --clips 4 --out /tmp/scale_out_smoke
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import ipaddress
import json
import logging
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rba.compute import Compute, make_compute
from rba.core.fileio import save_report
from rba.core.store import ClipStore
from rba.data.library import SkillLibrary, generate
from rba.media.clip_cache import ClipCache

RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "scale_out.json", "scale_out.md",
)
GOAL_SPEEDUP = 1.8
PROJECT_ROLLOUTS, PROJECT_CORES = 100_000, 32
RAY_ENV = {"RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "disabled",
           "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}  # "0": addresses stay on 127.0.0.1, never the LAN's
HEAD_ARGS = {"num_cpus": 0, "node_ip_address": "127.0.0.1", "include_dashboard": False}
PROCESS = re.compile(r'\("([^"]+)",pid=(\d+)')

log = logging.getLogger("scale_out")


# ---------------------------------------------------------------- processes, sockets, pinning

def process_tree(root: int) -> set[int]:
    """``root`` and every process below it (from /proc)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            with contextlib.suppress(OSError, IndexError, ValueError):
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
                children.setdefault(ppid, []).append(int(entry.name))
    tree, todo = {root}, [root]
    while todo:
        for child in children.get(todo.pop(), []):
            if child not in tree:
                tree.add(child)
                todo.append(child)
    return tree


def pin(pids: set[int], core: int) -> int:
    """Every thread of ``pids`` on ``core`` (children started later inherit it); returns how many processes."""
    pinned = 0
    for pid in pids:
        with contextlib.suppress(OSError):
            for tid in os.listdir(f"/proc/{pid}/task"):
                with contextlib.suppress(OSError):
                    os.sched_setaffinity(int(tid), {core})
            pinned += 1
    return pinned


def is_loopback(local: str) -> bool:
    host = local.rsplit(":", 1)[0].strip("[]").split("%")[0]
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:  # "*": every address
        return False
    return ip.is_loopback or bool(getattr(ip, "ipv4_mapped", None) and ip.ipv4_mapped.is_loopback)


def listening(stage: str) -> dict:
    """The listening TCP sockets (``ss -tlnp``) of this process's tree; those outside loopback are flagged."""
    ours = process_tree(os.getpid())
    out = subprocess.run(["ss", "-tlnpH"], capture_output=True, text=True, check=True).stdout
    sockets = []
    for line in out.splitlines():
        parts = line.split()
        owners = [(name, int(pid)) for name, pid in PROCESS.findall(line) if int(pid) in ours]
        if len(parts) >= 4 and owners:
            sockets.append({"local": parts[3], "process": owners[0][0]})
    outside = [s for s in sockets if not is_loopback(s["local"])]
    log.info("%s: %d listening sockets of this run, %d outside loopback%s", stage, len(sockets), len(outside),
             f": {outside}" if outside else "")
    return {"stage": stage, "listening": len(sockets), "outside_loopback": outside}


# ---------------------------------------------------------------- one cluster

def start_cluster(nodes: int, pin_cores: bool):
    """A head with no CPUs and ``nodes`` one-CPU worker nodes on 127.0.0.1; with ``pin_cores``, node i on core i."""
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True, head_node_args=HEAD_ARGS)
    workers = [cluster.add_node(num_cpus=1, node_ip_address="127.0.0.1") for _ in range(nodes)]
    cluster.wait_for_nodes()
    if pin_cores:
        pin_nodes(workers)
    return cluster, workers


def pin_nodes(workers: list) -> None:
    """Each worker node's raylet and its workers (present and future: they inherit it) on a core of its own."""
    cores = sorted(os.sched_getaffinity(0))
    for i, node in enumerate(workers):
        raylet = node.all_processes["raylet"][0].process.pid
        n = pin(process_tree(raylet), cores[i % len(cores)])
        log.debug("node %d: %d processes on core %d", i, n, cores[i % len(cores)])


def node_cores(workers: list) -> list[list[int]]:
    """The cores each worker node's processes (raylet, workers, agents) may run on: what pinning achieved."""
    cores = []
    for node in workers:
        allowed: set[int] = set()
        for pid in process_tree(node.all_processes["raylet"][0].process.pid):
            with contextlib.suppress(OSError):
                allowed |= os.sched_getaffinity(pid)
        cores.append(sorted(allowed))
    return cores


def warm(compute: Compute, args, scratch: Path) -> float:
    """Untimed: two simulations and two renders per node, so every worker has imported and rendered once."""
    start = time.perf_counter()
    lib = generate(args.domain, "serve", 2 * compute.capacity, seed=args.seed + 1, progress=False, compute=compute)
    cache = ClipCache(ClipStore(scratch / "warm"), compute, args.width, args.height)
    cache.fill((cache.key(lib, rid), lib) for rid in lib.ids)
    return time.perf_counter() - start


def clips_digest(store: ClipStore) -> str:
    """One hash over every clip's bytes (in file-name order): equal clips on every node count."""
    h = hashlib.sha256()
    for path in sorted(store.root.rglob("*.mp4")):
        h.update(path.name.encode() + path.read_bytes())
    return h.hexdigest()[:16]


def timed_work(compute: Compute, args, scratch: Path) -> dict:
    """(a) the library build, (b) the render of its first ``--clips`` clips; seconds and what they made."""
    start = time.perf_counter()
    lib: SkillLibrary = generate(args.domain, "serve", args.rollouts, seed=args.seed, progress=False,
                                 compute=compute)
    build_s = time.perf_counter() - start
    store = ClipStore(scratch / "clips")
    cache = ClipCache(store, compute, args.width, args.height)
    keys = [(cache.key(lib, rid), lib) for rid in lib.ids[: args.clips]]
    start = time.perf_counter()
    rendered = cache.fill(keys, window=args.window)
    render_s = time.perf_counter() - start
    return {"build_seconds": round(build_s, 2), "attempted": int(lib.meta["attempted"]), "rollouts": len(lib),
            "library_version": lib.version, "render_seconds": round(render_s, 2), "clips": rendered,
            "clips_digest": clips_digest(store)}


def run_nodes(nodes: int, args) -> dict:
    """One fresh cluster of ``nodes`` worker nodes: warm it, time the work, shut it down cleanly."""
    import ray

    load_before = round(os.getloadavg()[0], 2)
    scratch = Path(tempfile.mkdtemp(prefix=f"rba-scale-{nodes}-"))
    cluster, _ = start_cluster(nodes, args.pin)
    try:
        compute = make_compute(ray_address=cluster.address)
        try:
            if compute.capacity != nodes:
                raise RuntimeError(f"the cluster has {compute.capacity} CPUs, expected {nodes}")
            warm_s = warm(compute, args, scratch)
            if args.pin:
                pin_nodes(list(cluster.worker_nodes))  # workers started by the warm-up were pinned by inheritance
            sockets = [listening(f"{nodes} node(s), warmed")]
            work = timed_work(compute, args, scratch)
            sockets.append(listening(f"{nodes} node(s), after the work"))
            cores = node_cores(list(cluster.worker_nodes))
        finally:
            compute.close()
            ray.shutdown()
    finally:
        cluster.shutdown()
    left = wait_for_exit()
    result = {"nodes": nodes, "node_cores": cores, "warm_up_seconds": round(warm_s, 1), **work, "sockets": sockets,
              "processes_left_after_shutdown": left, "load_average_before": load_before,
              "load_average_after": round(os.getloadavg()[0], 2)}
    log.info("%d node(s): %s", nodes, json.dumps({k: v for k, v in result.items() if k != "sockets"}))
    shutil.rmtree(scratch, ignore_errors=True)
    return result


def running(pid: int) -> bool:
    """Alive and not a zombie waiting to be reaped."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def wait_for_exit(timeout: float = 20.0) -> int:
    """How many processes this run started are still alive ``timeout`` seconds after the cluster's shutdown."""
    deadline = time.monotonic() + timeout
    while True:
        left = {p for p in process_tree(os.getpid()) - {os.getpid()} if running(p)}
        if not left or time.monotonic() > deadline:
            if left:
                log.warning("%d processes of the cluster still run: %s", len(left), sorted(left))
            return len(left)
        time.sleep(0.5)


# ---------------------------------------------------------------- summary and report

def summarize(runs: list[dict]) -> dict:
    """Per-task cost on one node, speed-ups of the largest node count over one, and the 32-core projection."""
    by = {r["nodes"]: r for r in runs}
    one, many = by.get(1), by[max(by)]
    if one is None:
        return {}
    per_rollout = one["build_seconds"] / one["rollouts"]  # a kept rollout's share, failed attempts included
    per_clip = one["render_seconds"] / max(one["clips"], 1)
    n = many["nodes"]
    build_up = one["build_seconds"] / many["build_seconds"]
    render_up = one["render_seconds"] / many["render_seconds"]
    total_up = (one["build_seconds"] + one["render_seconds"]) / (many["build_seconds"] + many["render_seconds"])
    linear = PROJECT_ROLLOUTS * (per_rollout + per_clip) / PROJECT_CORES
    efficiency = total_up / n if n > 1 else 1.0
    return {
        "seconds_per_rollout_one_node": round(per_rollout, 4), "seconds_per_attempt_one_node":
        round(one["build_seconds"] / one["attempted"], 4), "seconds_per_clip_one_node": round(per_clip, 4),
        "compared_nodes": n, "build_speedup": round(build_up, 2), "render_speedup": round(render_up, 2),
        "total_speedup": round(total_up, 2), "efficiency": round(efficiency, 3),
        "projection": {"rollouts": PROJECT_ROLLOUTS, "cores": PROJECT_CORES, "linear_hours": round(linear / 3600, 2),
                       "with_measured_efficiency_hours": round(linear / efficiency / 3600, 2)},
        "identical_library": len({r["library_version"] for r in runs}) == 1,
        "identical_clips": len({r["clips_digest"] for r in runs}) == 1,
    }


def judge(summary: dict) -> dict[str, str]:
    if not summary or summary["compared_nodes"] != 2:
        return {}
    return {f"{name} speed-up 2 nodes vs 1 ≥ {GOAL_SPEEDUP:g}×":
            f"{summary[key]:g}× — {'met' if summary[key] >= GOAL_SPEEDUP else 'NOT met'}"
            for name, key in (("library build", "build_speedup"), ("full-library render", "render_speedup"))}


def socket_lines(runs: list[dict]) -> list[str]:
    checks = [c for r in runs for c in r["sockets"]]
    outside = [s for c in checks for s in c["outside_loopback"]]
    most = max((c["listening"] for c in checks), default=0)
    if outside:
        return [f"- Network: sockets of this run listened outside 127.0.0.1: {outside}"]
    return [f"- Network: checked {len(checks)} times with `ss -tlnp`; up to {most} listening TCP sockets of this "
            "run's processes, all on loopback (none outside 127.0.0.1)."]


def markdown(report: dict) -> str:
    s, a = report["summary"], report["args"]
    lines = [
        "# Scale-out on Ray: 1 vs 2 worker nodes", "",
        f"`{report['command']}`  ",
        f"{report['date']} · {report['machine']} · Ray {report['ray']} · domain `{a['domain']}` · {a['rollouts']} "
        f"rollouts, {a['clips']} clips at {a['width']}x{a['height']} · load average (1 min) "
        f"{report['load_average_before']:g} → {report['load_average_after']:g}", "",
        "Each node count gets a fresh Ray cluster on 127.0.0.1: a head with 0 CPUs and N worker nodes with 1 CPU "
        "each" + (", each node's processes pinned to a core of their own" if a["pin"] else " (not pinned)")
        + ", warmed up untimed; the build and the render then run on `make_compute(ray_address=...)` exactly as "
        "`rba build --ray` and `rba cache --ray` do.", "",
        "| nodes | cores of each node | build (s) | rollouts (attempted) | render (s) | clips | warm-up (s) | library "
        "| clips digest | processes left after shutdown | load avg before → after |",
        "|---:|:---:|---:|---:|---:|---:|---:|:---:|:---:|---:|---:|",
    ]
    for r in report["runs"]:
        cores = " · ".join(",".join(map(str, c)) for c in r["node_cores"])
        lines.append(f"| {r['nodes']} | {cores} | {r['build_seconds']:g} | {r['rollouts']} ({r['attempted']}) "
                     f"| {r['render_seconds']:g} | {r['clips']} | {r['warm_up_seconds']:g} | `{r['library_version']}` "
                     f"| `{r['clips_digest']}` | {r['processes_left_after_shutdown']} "
                     f"| {r['load_average_before']:g} → {r['load_average_after']:g} |")
    lines += [""]
    if s:
        p = s["projection"]
        lines += [
            f"- Per-task cost on one node: {s['seconds_per_rollout_one_node']:g} s per library rollout "
            f"({s['seconds_per_attempt_one_node']:g} s per simulated attempt), {s['seconds_per_clip_one_node']:g} s "
            "per clip.",
            f"- Speed-up {s['compared_nodes']} nodes vs 1: build {s['build_speedup']:g}×, render "
            f"{s['render_speedup']:g}×, both together {s['total_speedup']:g}× (efficiency {s['efficiency']:.0%}).",
            f"- Same library and same clips on every node count: {s['identical_library']} / {s['identical_clips']}.",
            f"- Projected time for a {p['rollouts']:,}-rollout library, simulated and rendered, on {p['cores']} "
            f"cores: {p['rollouts']:,} × ({s['seconds_per_rollout_one_node']:g} + "
            f"{s['seconds_per_clip_one_node']:g}) s / {p['cores']} = **{p['linear_hours']:g} h** assuming linear "
            f"scaling; **{p['with_measured_efficiency_hours']:g} h** with the measured {s['compared_nodes']}-node "
            f"efficiency ({s['efficiency']:.0%}) applied. Both assume a cluster core as fast as one of this "
            "machine's and that the efficiency measured on 2 nodes holds at 32 (the driver collects every "
            "rollout and clip, which grows with the cluster).",
        ]
    lines += socket_lines(report["runs"])
    lines += ["", f"Goal (the issue's): speed-up ≥ {GOAL_SPEEDUP:g}× from 1 to 2 nodes.", ""]
    verdicts = [f"- {name}: {verdict}" for name, verdict in report["goals"].items()]
    lines += verdicts or ["- not judged: no run on 1 and on 2 nodes"]
    lines += ["", f"The nodes share this machine's {os.cpu_count()} cores with the head, the driver and Ray's own "
              "services, so the numbers mean something only on an otherwise idle machine (see the load average); "
              "a per-task cost measured while other work runs overstates the projection.", ""]
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--nodes", type=int, nargs="+", default=[1, 2], help="worker node counts to compare (one CPU each)")
    p.add_argument("--rollouts", type=int, default=400, help="rollouts in the timed library build")
    p.add_argument("--clips", type=int, default=120, help="clips rendered from that library (its first ones)")
    p.add_argument("--domain", default="walker")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--width", type=int, default=320)
    p.add_argument("--height", type=int, default=240)
    p.add_argument("--window", type=int, default=None,
                   help="renders in flight at once (default: the cluster's CPUs, as `rba cache` does)")
    p.add_argument("--no-pin", dest="pin", action="store_false",
                   help="do not pin each worker node to a core of its own (Ray's num_cpus=1 alone only limits "
                        "how many tasks it runs)")
    p.add_argument("--out", type=Path, default=RESULTS / "scale_out", help="writes <out>.json and <out>.md")
    args = p.parse_args(argv)
    if not all(1 <= n <= 16 for n in args.nodes) or args.rollouts < 1 or args.clips < 1:
        p.error("nodes must be in 1..16, rollouts and clips at least 1")
    args.clips = min(args.clips, args.rollouts)
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    os.environ.update(RAY_ENV)
    import ray

    load_before = round(os.getloadavg()[0], 2)
    runs = [run_nodes(n, args) for n in sorted(set(args.nodes))]
    summary = summarize(runs)
    report = {
        "command": "python benchmarks/scale_out.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "machine": f"{os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}",
        "ray": ray.__version__, "args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "load_average_before": load_before, "load_average_after": round(os.getloadavg()[0], 2),
        "runs": runs, "summary": summary, "goals": judge(summary),
    }
    save_report(args.out, report, markdown(report))
    log.info("wrote %s.json and %s.md", args.out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
