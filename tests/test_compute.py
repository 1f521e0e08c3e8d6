"""The compute layer: both backends give byte-identical rollouts and clips, and a killed Ray worker loses nothing.

The Ray tests start a real cluster on this machine (``ray.cluster_utils.Cluster``: a head with no
CPUs and two one-CPU worker nodes, all on 127.0.0.1) and run the same jobs on it as on the local pools.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from concurrent.futures import Future
from pathlib import Path

import numpy as np
import pytest

from rba.compute import DataJob, RenderJob, SimJob, Task, make_compute
from rba.compute.base import CLIP_PARTS, SIM_CHUNK, joined, sim_chunk
from rba.compute.local import LocalCompute
from rba.core.store import ClipStore
from rba.data.library import SkillLibrary, build_all, generate
from rba.domains import domain_target
from rba.media.clip_cache import ClipCache


@pytest.fixture(scope="module")
def ray_cluster():
    """A two-node Ray cluster on loopback; yields (cluster, worker nodes, a RayCompute connected to it)."""
    os.environ.update(RAY_USAGE_STATS_ENABLED="0", RAY_AUTH_MODE="disabled",
                      RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0")  # "0": addresses stay on 127.0.0.1, never the LAN's
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 0, "node_ip_address": "127.0.0.1",
                                                            "include_dashboard": False})
    nodes = [cluster.add_node(num_cpus=1, node_ip_address="127.0.0.1") for _ in range(2)]
    compute = make_compute(ray_address=cluster.address)
    try:
        yield cluster, nodes, compute
    finally:
        compute.close()
        cluster.shutdown()


def test_ray_runs_on_both_nodes_and_simulates_the_toy_library_identically(ray_cluster, local_compute):
    _, _, ray = ray_cluster
    assert ray.name == "ray" and ray.capacity == 2
    assert sim_chunk(16, ray.capacity) == 2  # the library below goes in tasks of 2 rollouts on both backends
    on_ray = generate("toy", "serve", 16, seed=3, progress=False, compute=ray)
    assert on_ray.version == generate("toy", "serve", 16, seed=3, progress=False, compute=local_compute).version
    assert on_ray.version == generate("toy", "serve", 16, seed=3, workers=1, progress=False).version


def test_a_tiny_walker_build_and_its_clips_are_identical_on_both_backends(ray_cluster, local_compute, tmp_path):
    _, _, ray = ray_cluster
    sizes = {"train": 3, "serve": 4, "val": 2, "test": 2}
    on_ray = build_all("walker", seed=11, sizes=sizes, root=tmp_path / "ray", progress=False, compute=ray)
    local = build_all("walker", seed=11, sizes=sizes, root=tmp_path / "local", progress=False, compute=local_compute)
    assert {s: lib.version for s, lib in on_ray.items()} == {s: lib.version for s, lib in local.items()}
    rollout = local["serve"].rollout(0)
    job = RenderJob.of("walker", rollout, 96, 72)
    clip = ray.render(job).future.result(120)
    assert clip[4:8] == b"ftyp" and clip == local_compute.render(job).future.result(120)
    data = DataJob.of("walker", rollout, 96, 72)
    assert ray.clip_data(data).future.result(120) == local_compute.clip_data(data).future.result(120)


def test_a_killed_ray_worker_loses_no_clip_and_leaves_no_half_file(ray_cluster, local_compute, tmp_path):
    cluster, nodes, ray = ray_cluster
    lib = build_all("walker", seed=12, sizes={"train": 2, "serve": 4, "val": 2, "test": 2}, root=tmp_path / "data",
                    progress=False, compute=local_compute)["serve"]
    cache = ClipCache(ClipStore(tmp_path / "clips"), ray, 96, 72)
    keys = [(cache.key(lib, rid), lib) for rid in lib.ids]
    result: list[int] = []
    filling = threading.Thread(target=lambda: result.append(cache.fill(keys, window=4)))
    filling.start()
    time.sleep(1.0)  # the renders are running on both nodes
    cluster.remove_node(nodes[1], allow_graceful=False)  # kills its raylet and every worker on it, mid-task
    filling.join(240)
    assert result == [len(lib)]
    expected = local_compute.render(RenderJob.of("walker", lib.rollout(3), 96, 72)).future.result(120)
    assert cache.path(keys[3][0]).read_bytes() == expected
    assert all(cache.cached(k) for k, _ in keys)
    assert not list((tmp_path / "clips").rglob("*.tmp"))


def test_the_local_pool_replaces_a_killed_worker_and_runs_the_task_again(toy_roots):
    data, _, _ = toy_roots
    rollout = SkillLibrary.load("toy", "serve", data).rollout(5)
    with LocalCompute(workers=1, nice=0) as compute:
        job = RenderJob.of("toy", rollout, 32, 24)
        expected = compute.render(job).future.result(60)
        for pid in list(compute._urgent.executor._processes):  # the pool's worker, killed as the OOM killer would
            os.kill(pid, 9)
        time.sleep(0.5)
        assert compute.render(job).future.result(60) == expected


def test_workers_exit_when_their_pool_process_is_killed(tmp_path):
    """A server killed outright leaves no compute workers behind (they watch their parent)."""
    script = ("import os, sys, time\n"
              "from rba.compute.local import LocalCompute\n"
              "compute = LocalCompute(workers=2, nice=0)\n"
              "pids = {compute._urgent.submit(os.getpid).future.result(60) for _ in range(4)}\n"
              "print(*pids, flush=True)\n"
              "time.sleep(600)\n")
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        workers = [int(p) for p in proc.stdout.readline().split()]
        assert workers and all(_alive(p) for p in workers)
    finally:
        proc.kill()
        proc.wait()
    deadline = time.monotonic() + 30
    while any(_alive(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(_alive(p) for p in workers), f"workers {workers} outlived their killed pool process"


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, dead but not yet reaped by its new parent, does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_a_library_is_simulated_in_chunks_and_a_searchs_candidates_one_per_task():
    assert sim_chunk(1200, 2) == SIM_CHUNK and sim_chunk(100_000, 32) == SIM_CHUNK
    assert sim_chunk(16, 2) == 2  # a small library: every worker still gets a few tasks
    assert sim_chunk(8, 2) == sim_chunk(1, 1) == 1  # a search's generation of candidates


def test_simulate_keeps_the_jobs_order(local_compute):
    target = domain_target("toy")
    jobs = [SimJob(target, {"amplitude": 0.2 + 0.05 * i, "pace": 0.5}, seed=i) for i in range(9)]
    got = list(local_compute.simulate(jobs))
    assert [r.seed for r in got] == list(range(9))
    assert all(np.array_equal(a.states, b.states) for a, b in zip(got, local_compute.simulate(jobs), strict=True))


def test_a_searchs_jobs_are_taken_as_workers_free_up_and_none_once_the_stream_is_closed(local_compute):
    """A search out of time closes its stream: what the pool had already been handed ran anyway, and the clip
    rendered next waited for it. Jobs are now taken one per free worker: when the first rollout arrives, about
    ``workers`` of them (more if it was the slowest: the others take jobs as they free up), not all. Many jobs, so
    that a first one slowed by a loaded machine still leaves most untaken (with 9, one CI run took all)."""
    target, taken, n = domain_target("toy"), [], 64
    list(local_compute.simulate(iter([SimJob(target, {"amplitude": 0.3, "pace": 0.5}, seed=0)] * 2)))  # warm

    def jobs():
        for i in range(n):
            taken.append(i)
            yield SimJob(target, {"amplitude": 0.2 + 0.01 * i, "pace": 0.5}, seed=i)

    stream = local_compute.simulate(jobs())
    assert next(stream).seed == 0
    stream.close()
    assert local_compute.workers <= len(taken) < n // 2  # handed over at once, all were taken


def test_a_generated_clip_is_rendered_in_parts_on_the_workers_and_joined(local_compute, tmp_path):
    """Both workers render half the clip each; joined, it is every frame, and the split, not the number of workers,
    decides the bytes. A library clip (split 1) renders whole: the bytes ``rba render`` writes."""
    import imageio_ffmpeg

    from rba.cli import main

    lib = SkillLibrary.load("walker", "serve")
    rollout = lib.rollout(2)
    job = RenderJob.of("walker", rollout, 96, 72, split=CLIP_PARTS)
    half = len(rollout.replay) // 2
    assert [p.rows for p in job.parts()] == [(0, half), (half, len(rollout.replay))]
    clip = local_compute.render(job).future.result(120)
    with LocalCompute(workers=1, nice=0) as one:  # the parts one after the other on one worker
        assert one.render(job).future.result(120) == clip
    (tmp_path / "clip.mp4").write_bytes(clip)
    assert imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "clip.mp4"))[0] == len(rollout.replay)
    whole = RenderJob.of("walker", rollout, 96, 72)
    assert [p.rows for p in whole.parts()] == [(0, len(rollout.replay))]
    out = tmp_path / "cli.mp4"
    assert main(["render", "walker", lib.ids[2], str(out), "--width", "96", "--height", "72"]) == 0
    assert local_compute.render(whole).future.result(120) == out.read_bytes() != clip


def _task() -> Task:
    future: Future = Future()
    return Task(future, future.cancel, future.running)


def test_joined_tasks_join_the_parts_in_order_once_all_are_in():
    parts, joins = [_task(), _task()], []

    def join(results: list) -> Task:
        joins.append(results)
        done = _task()
        done.future.set_result("+".join(results))
        return done

    task = joined(parts, join)
    parts[1].future.set_result("b")
    assert not joins and not task.future.done()
    parts[0].future.set_result("a")
    assert joins == [["a", "b"]] and task.future.result(1) == "a+b"


def test_a_joined_task_fails_with_a_part_and_is_cancelled_with_one():
    parts = [_task(), _task()]
    task = joined(parts, lambda results: pytest.fail("joined a failed clip"))
    parts[0].future.set_exception(RuntimeError("worker died"))
    with pytest.raises(RuntimeError, match="worker died"):
        task.future.result(1)
    assert parts[1].future.cancelled()  # not started: dropped, no wasted render
    parts = [_task(), _task()]
    parts[1].future.set_running_or_notify_cancel()  # started: cannot be cancelled any more
    task = joined(parts, lambda results: pytest.fail("joined a cancelled clip"))
    assert task.cancel() and task.future.cancelled() and parts[0].future.cancelled()
    started = [_task(), _task()]
    for part in started:
        part.future.set_running_or_notify_cancel()
    assert not joined(started, lambda results: pytest.fail("not in yet")).cancel()


def test_a_joined_task_is_cancelled_with_its_queued_join_and_fails_if_the_join_cannot_start():
    """An urgent request for a guess whose parts are in but whose join still waits in the guess queue cancels
    that join (and resubmits the clip as urgent), rather than waiting behind the guesses."""
    parts, join = [_task(), _task()], _task()
    task = joined(parts, lambda results: join)
    for part in parts:
        part.future.set_result(b"part")
    assert not task.future.done() and task.cancel() and join.future.cancelled() and task.future.cancelled()

    def broken(results: list) -> Task:
        raise RuntimeError("the pool is shut down")

    parts = [_task(), _task()]
    task = joined(parts, broken)
    for part in parts:
        part.future.set_result(b"part")
    with pytest.raises(RuntimeError, match="shut down"):
        task.future.result(1)


def test_warming_up_starts_every_urgent_worker():
    """The first clip's parts render on every urgent worker: warming starts them all, not one."""
    with LocalCompute(workers=2, nice=0) as compute:
        compute.warm(domain_target("toy"))
        deadline = time.monotonic() + 60
        while len(compute._urgent.executor._processes) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(compute._urgent.executor._processes) == 2
