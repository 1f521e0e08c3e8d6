"""The store: one layout from one settings source; clips by key, written atomically, crash debris swept."""

from __future__ import annotations

import ast
import os
import time
from pathlib import Path

import pytest

from rba.core.settings import REPO_ROOT, LibrarySettings
from rba.core.store import ClipStore, Store
from rba.data.library import SkillLibrary
from rba.media.clip_cache import STALE_TMP_SECONDS, ClipCache, ClipKey
from server.common.app_settings import Settings
from tests.fakes import FakeCompute

KEY = ClipKey("toy", "abc123", "serve-00001", 64, 48)


def test_layout_defaults_to_the_repository_not_the_working_directory(monkeypatch, tmp_path):
    for var in ("RBA_DATA_DIR", "RBA_MODELS_DIR", "RBA_CACHE_DIR"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.chdir(tmp_path)
    store = Store.from_settings()
    assert (store.data_dir, store.models_dir) == (REPO_ROOT / "data", REPO_ROOT / "models")
    assert store.cache_dir == REPO_ROOT / "data" / "cache" / "clips"


def test_env_overrides_reach_every_path_and_are_made_absolute(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("RBA_DATA_DIR", "d")
    monkeypatch.setenv("RBA_MODELS_DIR", str(tmp_path / "m"))
    monkeypatch.setenv("RBA_CACHE_DIR", "~/clips")
    monkeypatch.setenv("RBA_CLIP_WIDTH", "64")
    store = Store.from_settings()
    d, m = tmp_path / "d", tmp_path / "m"
    assert store.cache_dir == Path.home() / "clips" and LibrarySettings().clip_width == 64
    assert store.libraries.arrays("walker", "serve") == d / "walker" / "serve.npz"
    assert store.libraries.meta("walker", "serve") == d / "walker" / "serve.json"
    assert store.uploads("walker").labels("ab12") == d / "uploads" / "walker" / "ab12.json"
    assert store.uploads("walker").trajectories("ab12") == d / "uploads" / "walker" / "ab12.npz"
    assert store.models().weights("walker", "ranker", "onehot") == m / "walker" / "ranker-onehot.pt"
    assert store.models().card("walker", "ranker", "onehot") == m / "walker" / "ranker-onehot.json"
    assert store.models("v1").weights("walker", "ranker", "onehot") == m / "versions" / "v1" / "walker" / \
        "ranker-onehot.pt"
    assert store.staging("job9") == m / "versions" / ".tmp-job9"
    assert store.database_file == d / "rba.db"
    server = Store.from_settings(Settings())  # the server's settings are the library's, extended
    assert server == store and Settings().clip_width == 64


def test_publish_renames_the_staging_folder_and_discard_removes_it(tmp_path):
    store = Store(tmp_path / "d", tmp_path / "m", tmp_path / "c")
    (store.staging("j1") / "toy").mkdir(parents=True)
    (store.staging("j1") / "toy" / "ranker-onehot.pt").write_bytes(b"w")
    store.publish("j1", "toy-v1")
    assert store.models("toy-v1").weights("toy", "ranker", "onehot").read_bytes() == b"w"
    assert not store.staging("j1").exists()
    assert store.staged_jobs() == []
    store.staging("j2").mkdir()
    (store.versions_dir / ".tmp-file").write_bytes(b"")  # not a folder: no job's
    assert store.staged_jobs() == ["j2"]
    store.discard("j2")
    assert not store.staging("j2").exists()
    store.unpublish("toy-v1")
    assert not store.models("toy-v1").root.exists()


def test_job_records_live_under_data_jobs(tmp_path):
    store = Store(tmp_path / "d", tmp_path / "m", tmp_path / "c")
    assert store.job_record("j1") == tmp_path / "d" / "jobs" / "j1.json"
    assert store.recorded_jobs() == []
    store.job_record("j1").parent.mkdir(parents=True)
    store.job_record("j1").write_text("{}")
    half = tmp_path / "d" / "jobs" / ".j2.json.123.tmp"
    half.write_text("")  # a record half-written by a crash
    assert store.recorded_jobs() == ["j1"]
    assert store.sweep_job_records(older_than=60) == 0  # it may be being written right now
    os.utime(half, (time.time() - 120, time.time() - 120))
    assert store.sweep_job_records(older_than=60) == 1 and not half.exists()


def test_the_library_loads_from_the_store_when_no_root_is_given(toy_roots, monkeypatch):
    data, _, _ = toy_roots
    monkeypatch.setenv("RBA_DATA_DIR", str(data))
    assert SkillLibrary.load("toy", "test").ids == SkillLibrary.load("toy", "test", data).ids


def test_a_clip_is_written_atomically_and_found_by_key(tmp_path):
    clips = ClipStore(tmp_path)
    assert not clips.exists(KEY)
    seen_while_writing = []

    def fill(tmp: Path) -> int:
        tmp.write_bytes(b"mp4 bytes")
        seen_while_writing.append(clips.exists(KEY))
        return 7

    assert clips.write(KEY, fill) == 7
    assert seen_while_writing == [False]  # readers never see a half-written clip
    assert clips.exists(KEY)
    with clips.open(KEY) as f:
        assert f.read() == b"mp4 bytes"
    assert clips.path(KEY) == tmp_path / "toy" / f"abc123-{KEY.digest}-64x48.mp4"  # the names existing caches use
    assert [p.name for p in (tmp_path / "toy").iterdir()] == [clips.path(KEY).name]


def test_a_failed_write_leaves_nothing(tmp_path):
    clips = ClipStore(tmp_path)

    def fail(tmp: Path) -> None:
        tmp.write_bytes(b"half")
        raise RuntimeError("encoder died")

    with pytest.raises(RuntimeError):
        clips.write(KEY, fail)
    assert not clips.exists(KEY) and not list(tmp_path.rglob("*.tmp"))


def test_what_a_crash_leaves_is_swept_at_start_up(tmp_path):
    folder = tmp_path / "toy"
    folder.mkdir()
    stale, fresh = folder / ".abc-1.mp4.x1.tmp", folder / ".abc-2.mp4.x2.tmp"
    stale_claim, fresh_claim = folder / ".abc-3.mp4.claim", folder / ".abc-4.mp4.claim"
    for f in (stale, fresh, stale_claim, fresh_claim):
        f.write_bytes(b"")  # the fresh ones: another process may be writing or rendering right now
    old = time.time() - STALE_TMP_SECONDS - 60
    for f in (stale, stale_claim):
        os.utime(f, (old, old))
    ClipCache(ClipStore(tmp_path), FakeCompute(), 64, 48)
    assert not stale.exists() and fresh.exists()
    assert not stale_claim.exists() and fresh_claim.exists()


def test_replicas_sharing_a_store_split_the_guesses(toy_roots, tmp_path):
    from rba.data.library import SkillLibrary

    lib = SkillLibrary.load("toy", "serve", toy_roots[0])
    a, b = FakeCompute(), FakeCompute()
    one, two = ClipCache(ClipStore(tmp_path), a, 64, 48), ClipCache(ClipStore(tmp_path), b, 64, 48)
    key = one.key(lib, "serve-00002")
    one.request(key, lib, urgent=False)
    assert two.request(key, lib, urgent=False).result(0) is None and not b.submitted  # one renders it
    wanted = two.request(key, lib)  # a person asks replica two: it renders at once, whoever claimed the guess
    assert len(b.submitted) == 1
    a.submitted[0][1].set_result(b"clip")
    b.submitted[0][1].set_result(b"clip")
    assert wanted.result(5).read_bytes() == b"clip"
    assert not list(tmp_path.rglob(".*.claim"))  # released when the guess was stored


def test_the_library_never_imports_the_server():
    offenders = []
    for path in (REPO_ROOT / "rba").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            offenders += [f"{path.relative_to(REPO_ROOT)}: {n}" for n in names if n.split(".")[0] == "server"]
    assert offenders == []


def test_a_new_renderer_version_gives_every_clip_a_new_name(monkeypatch):
    from rba.media import clip_cache

    before = KEY.digest
    monkeypatch.setattr(clip_cache, "RENDERER_VERSION", clip_cache.RENDERER_VERSION + 1)
    assert KEY.digest != before  # a cache filled by the old renderer is never served as the new one's


def test_a_dot_in_a_reports_name_is_part_of_it(tmp_path):
    """Two runs written to ``--out runs/pull0.001`` and ``--out runs/pull0.003`` keep two reports (``with_suffix``
    made both ``runs/pull0.json``); a name given with its ``.json`` or ``.md`` suffix still names that report."""
    from rba.core.fileio import load_json, report_path, save_report

    for pull in ("0.001", "0.003"):
        save_report(tmp_path / f"pull{pull}", {"pull": pull}, f"# pull {pull}\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pull0.001.json", "pull0.001.md", "pull0.003.json",
                                                          "pull0.003.md"]
    assert load_json(tmp_path / "pull0.001.json") == {"pull": "0.001"}
    assert report_path(tmp_path / "paper_tables.md", ".json") == tmp_path / "paper_tables.json"
    assert report_path(tmp_path / "r", ".png") == tmp_path / "r.png"
