"""GET /api/clips/{domain}/scene.json and /{rollout_id}.json: the page's clip data, gzip on the wire, ETag and 304,
404 for what has none, computed on the compute layer (never in the request) and cached like the MP4s."""

from __future__ import annotations

import hashlib
import threading
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlmodel import Session

from rba.compute.tasks import describe
from rba.core.store import ClipStore
from rba.data.library import SkillLibrary
from rba.domains import domain_target
from rba.media.clip_cache import RENDERER_VERSION, ClipCache, ClipKey
from server.common.app_settings import Settings
from server.main import create_app
from server.ops.label_admin import clips_to_label
from server.ops.views import clip_public
from server.runtime.prefetch import Prefetcher
from tests.fakes import FakeCompute, InstantCompute

SHIPPED = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture
def settings(tmp_path) -> Settings:
    """The shipped walker serve library (read only) and nothing else; the toy domain is registered, unbuilt."""
    data = tmp_path / "data"
    data.mkdir()
    (data / "walker").symlink_to(SHIPPED / "walker")
    return Settings(data_dir=data, models_dir=tmp_path / "models", cache_dir=tmp_path / "clips", warm_start=False,
                    prerender_library=False, prerender=False, database_url=f"sqlite:///{tmp_path / 'rba.db'}")


@pytest.fixture
def walker_id() -> str:
    return SkillLibrary.load("walker", "serve", SHIPPED).ids[3]


def test_scene_and_clip_data_are_gzip_json_with_etags_beside_the_mp4(settings, walker_id):
    with TestClient(create_app(settings, InstantCompute())) as client:
        r = client.get("/api/clips/walker/scene.json")
        assert r.status_code == 200 and r.headers["content-encoding"] == "gzip"
        scene = r.json()
        assert scene["kind"] == "mujoco" and r.headers["etag"] == f'"{scene["version"]}"'
        assert r.headers["cache-control"] == "no-cache"
        versioned = client.get(f"/api/clips/walker/scene.json?v={scene['version']}")
        assert versioned.headers["cache-control"] == "public, max-age=31536000, immutable"
        assert client.get("/api/clips/walker/scene.json", headers={"If-None-Match": r.headers["etag"]}).status_code \
            == 304

        r = client.get(f"/api/clips/walker/{walker_id}.json")
        assert r.status_code == 200 and r.headers["content-encoding"] == "gzip"
        clip = r.json()
        assert clip["rollout_id"] == walker_id and clip["scene_url"].endswith(f"?v={scene['version']}")
        assert clip["frames"] == len(SkillLibrary.load("walker", "serve", SHIPPED).rollout(3).replay)
        again = client.get(f"/api/clips/walker/{walker_id}.json", headers={"If-None-Match": r.headers["etag"]})
        assert again.status_code == 304 and again.content == b""
        plain = client.get(f"/api/clips/walker/{walker_id}.json", headers={"Accept-Encoding": "identity"})
        assert "content-encoding" not in plain.headers and plain.json() == clip

        mp4 = client.get(f"/api/clips/walker/{walker_id}.mp4")  # the MP4 and its status routes are as they were
        assert mp4.content == InstantCompute.CLIP and mp4.headers["etag"] != r.headers["etag"]
        assert client.get(f"/api/clips/walker/{walker_id}/status").json()["state"] == "ready"
    stored = sorted(p.name for p in (settings.cache_dir / "walker").iterdir())
    assert sorted(name.rsplit("-", 1)[1] for name in stored) == ["320x240.json.gz", "320x240.mp4"]


def test_an_mp4_key_s_digest_is_unchanged_and_its_data_has_another():
    key = ClipKey("walker", "abc123", "serve-00001", 320, 240)
    raw = f"walker\x00abc123\x00serve-00001\x00320x240\x00{RENDERER_VERSION}"  # the MP4 key's digest as it was
    before = hashlib.sha256(raw.encode()).hexdigest()[:24]
    assert key.digest == before and key.suffix == ".mp4"
    assert key.data().digest != before and key.data().suffix == ".json.gz"


def test_what_has_no_clip_data_is_a_404_with_the_app_s_error_body(settings, walker_id):
    with TestClient(create_app(settings, InstantCompute())) as client:
        for url, said in [("/api/clips/walker/serve-99999.json", "unknown rollout id"),
                          ("/api/clips/walker/gen-0123456789abcdef.json", "unknown generated rollout"),
                          ("/api/clips/toy/scene.json", "MP4s only"),
                          ("/api/clips/toy/serve-00001.json", "MP4s only")]:
            r = client.get(url)
            assert r.status_code == 404 and said in r.json()["detail"], url
        assert client.get("/api/clips/nosuch/scene.json").status_code == 422  # not a domain name, as for the MP4


def test_clip_data_is_computed_on_the_compute_layer_once_and_then_served_from_the_store(settings, walker_id):
    compute = FakeCompute()
    with TestClient(create_app(settings, compute)) as client:
        answers: list = []
        asking = threading.Thread(target=lambda: answers.append(client.get(f"/api/clips/walker/{walker_id}.json")))
        asking.start()
        deadline = time.monotonic() + 30
        while not compute.data_jobs and time.monotonic() < deadline:
            time.sleep(0.01)
        job, future, _ = compute.data_jobs[0]
        assert job.rollout.id == walker_id and job.target == domain_target("walker") and not answers
        future.set_result(describe(job.target, job.width, job.height, job.rollout))  # the worker's part
        asking.join(30)
        assert answers[0].status_code == 200 and answers[0].json()["rollout_id"] == walker_id
        assert client.get(f"/api/clips/walker/{walker_id}.json").status_code == 200
        assert len(compute.data_jobs) == 1 and not compute.jobs  # stored once; no MP4 was rendered for it


def test_session_and_labelling_clips_name_their_data_url_where_the_domain_has_data(settings, walker_id):
    with TestClient(create_app(settings, InstantCompute())) as client:
        svc = client.app.state.services
        with Session(svc.engine) as db:
            walker = clip_public(svc, db, "walker", walker_id)
            toy = clip_public(svc, db, "toy", "serve-00001")
            pairs = clips_to_label(svc, db, "walker", 2, anchor=False, seed=0).clips
    assert walker.data_url == f"/api/clips/walker/{walker_id}.json" and walker.url.endswith(".mp4")
    assert toy.data_url is None
    assert [c.data_url for c in pairs] == [c.url.removesuffix(".mp4") + ".json" for c in pairs]  # admin labelling


def test_the_prefetcher_asks_for_a_guess_s_data_beside_its_mp4(tmp_path, walker_id):
    library = SkillLibrary.load("walker", "serve", SHIPPED)
    compute = FakeCompute()
    cache = ClipCache(ClipStore(tmp_path / "clips"), compute, 320, 240)
    prefetch = Prefetcher(cache, lambda rid: (cache.key(library, rid), library), window=1)
    try:
        prefetch.offer("s", [walker_id])
        assert compute.next_rollout(timeout=5) == walker_id
        assert [job.rollout.id for job, _, _ in compute.data_jobs] == [walker_id]
    finally:
        prefetch.stop()
