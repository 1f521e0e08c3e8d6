"""The clip cache renders once per key; prerendering fills it without touching the session's agent."""

from __future__ import annotations

import threading

import pytest
from fastapi.testclient import TestClient

from rba.compute.base import CLIP_PARTS
from rba.core.store import ClipStore
from rba.data.library import SkillLibrary
from rba.interact import AttributeFeedback
from rba.media.clip_cache import ClipCache, ClipKey, ClipStatus
from server.main import create_app
from server.ops.prerender import answer_order
from server.runtime import transitions
from server.runtime.background import Background
from server.runtime.prefetch import Prefetcher
from tests.fakes import FakeCompute
from tests.server.conftest import more


def test_concurrent_requests_for_one_clip_render_it_once(toy_roots, tmp_path, local_compute):
    data, _, _ = toy_roots
    lib = SkillLibrary.load("toy", "serve", data)
    cache = ClipCache(ClipStore(tmp_path / "clips"), local_compute, 64, 48)
    key = cache.key(lib, "serve-00007")
    barrier = threading.Barrier(6)
    paths = []

    def fetch() -> None:
        barrier.wait()
        paths.append(cache.request(key, lib).result(60))

    threads = [threading.Thread(target=fetch) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert cache.renders == 1
    assert len(set(paths)) == 1 and paths[0].stat().st_size > 0
    assert paths[0].parent == tmp_path / "clips" / "toy" and paths[0].name.endswith("-64x48.mp4")
    assert "serve" not in paths[0].name  # file names come from validated parts and a hash, not from ids
    assert not list(paths[0].parent.glob(".*.tmp"))


def test_a_request_while_the_finished_clip_is_being_stored_joins_that_render(toy_roots, tmp_path):
    """The render stays in flight until its file exists: a request in between must not render it again."""
    data, _, _ = toy_roots
    lib = SkillLibrary.load("toy", "serve", data)
    compute = FakeCompute()
    store = ClipStore(tmp_path / "clips")
    cache = ClipCache(store, compute, 64, 48)
    key = cache.key(lib, "serve-00003")
    first = cache.request(key, lib, urgent=False)
    joined: list = []
    real_write = store.write

    def write_and_ask_again(k, fill):  # the moment between the render's end and its file's existence
        joined.append(cache.request(key, lib, urgent=True))
        return real_write(k, fill)

    store.write = write_and_ask_again
    compute.submitted[0][1].set_result(b"mp4")
    assert len(compute.submitted) == 1  # nothing new was submitted
    assert joined[0] is first and first.result(1) == store.path(key) and cache.renders == 1


def test_clip_status_goes_absent_queued_rendering_ready_with_a_typical_time(toy_roots, tmp_path):
    """What the page shows while a person waits: the render's real state, and how long this domain's take."""
    data, _, _ = toy_roots
    lib = SkillLibrary.load("toy", "serve", data)
    compute = FakeCompute()
    cache = ClipCache(ClipStore(tmp_path / "clips"), compute, 64, 48)
    first, second = cache.key(lib, "serve-00001"), cache.key(lib, "serve-00002")
    assert cache.status(first) == ClipStatus("absent")
    cache.request(first, lib)
    queued = cache.status(first)
    assert (queued.state, queued.typical) == ("queued", None) and queued.elapsed >= 0
    compute.submitted[0][1].set_running_or_notify_cancel()
    assert cache.status(first).state == "rendering"
    compute.submitted[0][1].set_result(b"mp4")
    done = cache.status(first)
    assert done.state == "ready" and done.elapsed is None and done.typical > 0
    cache.request(second, lib, urgent=False)
    guess = cache.status(second)
    assert (guess.state, guess.typical) == ("queued", done.typical)


def test_clip_keys_only_accept_library_ids(toy_roots, tmp_path):
    data, _, _ = toy_roots
    lib = SkillLibrary.load("toy", "serve", data)
    cache = ClipCache(ClipStore(tmp_path / "clips"), FakeCompute(), 64, 48)
    try:
        cache.key(lib, "../serve-00001")
    except KeyError as exc:
        assert "unknown rollout id" in str(exc)
    else:
        raise AssertionError("a rollout id outside the library was accepted")


def test_prerendering_renders_every_next_clip_and_leaves_the_agent_alone(make_settings, monkeypatch):
    settings = make_settings(prerender=True)
    with TestClient(create_app(settings)) as client:
        svc = client.app.state.services
        s = client.post("/api/sessions", json={"domain": "toy"}).json()
        assert svc.wait_idle(60)
        stored = client.get(f"/api/sessions/{s['id']}").json()
        assert stored["step"] == 0 and stored["clip"] == {**s["clip"], "ready": True}
        assert svc.clips.renders >= 2  # the current clip and at least two distinct candidates
        computed_in: list[str] = []  # threads that ran an agent from now on
        real_restore = transitions.restore_agent

        def spy(method, state, ctx):
            computed_in.append(threading.current_thread().name)
            return real_restore(method, state, ctx)

        monkeypatch.setattr(transitions, "restore_agent", spy)
        r = client.post(f"/api/sessions/{s['id']}/feedback", json=more("pace", 0, "less"))
        assert r.status_code == 200
        assert r.json()["clip"]["ready"] is True  # rendered while we "watched"
        assert svc.wait_idle(60)
        assert all(name.startswith("rba-think") for name in computed_in)  # the answer was precomputed
        assert svc.thinker.failed == 0 and svc.prefetch.failed == 0


def test_warm_start_renders_the_first_clip(make_settings):
    with TestClient(create_app(make_settings(warm_start=True))) as client:
        svc = client.app.state.services
        assert svc.wait_idle(60)
        s = client.post("/api/sessions", json={"domain": "toy"}).json()
        assert s["clip"]["ready"] is True


def test_background_keeps_only_the_newest_job_per_key():
    gate, ran = threading.Event(), []
    bg = Background(workers=1)
    try:
        bg.submit("blocker", gate.wait)  # occupies the only worker
        for step in range(5):
            bg.submit("session", lambda step=step: ran.append(step))
        gate.set()
        assert bg.wait_idle(10)
        assert ran == [4]  # the steps nobody can see any more were never worked on
    finally:
        bg.stop()


@pytest.fixture
def fake_cache(toy_roots, tmp_path):
    """A clip cache over the toy serve library whose renders the test finishes by hand."""
    compute = FakeCompute()
    return ClipCache(ClipStore(tmp_path), compute, 64, 48), compute, SkillLibrary.load("toy", "serve", toy_roots[0])


def test_answers_start_with_the_last_one_then_combine_attributes():
    order = [[(fb.attribute, fb.direction) for fb in a]
             for a in answer_order(("amplitude", "pace"), [AttributeFeedback("pace", -1)])]
    assert order[:4] == [[("pace", -1)], [("pace", 1)], [("amplitude", 1)], [("amplitude", -1)]]
    assert sorted(map(tuple, order[4:])) == sorted(  # then every two-attribute answer
        tuple(zip(("amplitude", "pace"), d, strict=True)) for d in ((1, 1), (1, -1), (-1, 1), (-1, -1)))
    assert len(answer_order(("a", "b", "c"), None)) == 6 + 12


def test_an_urgent_request_overtakes_its_queued_guess(fake_cache, tmp_path):
    cache, compute, lib = fake_cache
    key = cache.key(lib, "serve-00003")
    guess = cache.request(key, lib, urgent=False)
    wanted = cache.request(key, lib, urgent=True)
    assert [urgent for urgent, _ in compute.submitted] == [False, True]
    assert compute.submitted[0][1].cancelled() and guess.cancelled()  # the guess was dropped, not run twice
    compute.submitted[1][1].set_result(b"mp4 bytes")
    assert wanted.result(5).read_bytes() == b"mp4 bytes" and cache.cached(key)
    assert cache.request(key, lib).result(0) == wanted.result()  # cached: no new render
    assert len(compute.submitted) == 2 and not list(tmp_path.glob("*/.*.tmp"))


def test_a_failed_render_reaches_every_waiter_and_leaves_no_file(fake_cache):
    cache, compute, lib = fake_cache
    key = cache.key(lib, "serve-00004")
    a, b = cache.request(key, lib), cache.request(key, lib)
    compute.submitted[0][1].set_exception(RuntimeError("EGL went away"))
    for f in (a, b):
        with pytest.raises(RuntimeError, match="EGL"):
            f.result(5)
    assert not cache.cached(key) and not cache.pending(key)
    cache.request(key, lib)  # asking again renders again
    assert len(compute.submitted) == 2


def test_the_prefetcher_takes_sessions_round_robin_newest_first_then_the_sources_in_order(fake_cache):
    cache, compute, lib = fake_cache
    prefetch = Prefetcher(cache, lambda rid: (cache.key(lib, rid), lib), window=1)
    try:
        prefetch.offer("first", ["serve-00099"])
        assert compute.next_rollout(timeout=5) == "serve-00099"  # the window is full while we queue the rest
        prefetch.extend(iter(["serve-00010", "serve-00011", "serve-00001"]))  # 00001 is rendered by then: skipped
        prefetch.extend(iter(["serve-00020"]))
        prefetch.offer("old", ["serve-00001", "serve-00002"])
        prefetch.offer("new", ["serve-00003", "serve-00005"])
        compute.submitted[-1][1].set_result(b"x")
        order = []
        for _ in range(7):
            order.append(compute.next_rollout(timeout=5))
            compute.submitted[-1][1].set_result(b"x")
        assert order == ["serve-00003", "serve-00001", "serve-00005", "serve-00002",  # newest first, round-robin
                         "serve-00010", "serve-00011", "serve-00020"]
        assert prefetch.wait_idle(5) and all(not urgent for urgent, _ in compute.submitted)
    finally:
        prefetch.stop()


def test_guesses_wait_while_someone_waits_on_the_compute_layer(fake_cache):
    """``hold`` (``Services.someone_waits``): no guess starts while it says a person waits; they start after."""
    cache, compute, lib = fake_cache
    waiting = [True]
    prefetch = Prefetcher(cache, lambda rid: (cache.key(lib, rid), lib), window=2, hold=lambda: waiting[0])
    try:
        prefetch.offer("s", ["serve-00003", "serve-00005"])
        with pytest.raises(TimeoutError):
            compute.next_rollout(timeout=0.5)
        waiting[0] = False
        assert compute.next_rollout(timeout=5) == "serve-00003" and compute.next_rollout(timeout=5) == "serve-00005"
    finally:
        prefetch.stop()


def test_a_guess_worked_out_while_someone_began_to_wait_waits_too(fake_cache):
    """A guess can take a while to work out (a tree's thinking); if a search began meanwhile, the guess is held
    until nobody waits, not started beside the search's clip."""
    cache, compute, lib = fake_cache
    waiting = [False]

    def thinking():  # a person starts waiting while the guess is worked out
        waiting[0] = True
        yield "serve-00003"

    prefetch = Prefetcher(cache, lambda rid: (cache.key(lib, rid), lib), window=2, hold=lambda: waiting[0])
    try:
        prefetch.extend(thinking())
        with pytest.raises(TimeoutError):
            compute.next_rollout(timeout=0.5)
        assert not prefetch.idle()  # held, not dropped
        waiting[0] = False
        assert compute.next_rollout(timeout=5) == "serve-00003"
    finally:
        prefetch.stop()


def test_a_key_renders_in_its_parts(fake_cache):
    """The clip cache never asks what a rollout id names: its key says how many parts the render is split into
    (``server.runtime.clip_sources`` gives a made clip's key ``CLIP_PARTS``)."""
    cache, compute, lib = fake_cache
    cache.request(cache.key(lib, "serve-00004"), lib, urgent=True)
    made = lib.rollout(5)
    made.id = "gen-0123456789abcdef"
    cache.request(ClipKey("toy", "generated", made.id, cache.width, cache.height, CLIP_PARTS), made, urgent=True)
    assert [job.split for job in compute.jobs] == [1, CLIP_PARTS]
    for _, future in compute.submitted:
        future.set_result(b"x")


def test_prerender_library_renders_every_serve_clip_once(make_settings, toy_roots, tmp_path):
    from rba.data.library import build_all

    data = tmp_path / "small"  # a 24-clip serve library: the test is about coverage, not volume
    build_all("toy", seed=3, sizes={"train": 12, "serve": 24, "val": 4, "test": 4}, workers=1, root=data,
              progress=False)
    settings = make_settings(data_dir=data, warm_start=True, prerender=True, prerender_library=True,
                             clip_width=32, clip_height=24)
    with TestClient(create_app(settings)) as c:
        svc = c.app.state.services
        assert svc.wait_idle(240)
        lib = SkillLibrary.load("toy", "serve", data)
        assert all(svc.clips.cached(svc.clips.key(lib, rid)) for rid in lib.ids)
        assert svc.clips.renders == len(lib)  # each clip once, however many jobs asked
