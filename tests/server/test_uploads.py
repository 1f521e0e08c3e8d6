"""Dataset uploads under hostile input and crashes: every bad file is a 422 that says why, every name
is stored as given, and a crash at any step leaves the whole dataset or nothing once the app restarts.

Crash tests leave what a crash leaves (by hand, by a step that raises, or by a server process that
SIGKILLs itself at a step or is SIGKILLed from outside), start the app again and check what is left.
"""

from __future__ import annotations

import io
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlmodel import Session, select

from rba.core.fileio import load_npz, save_npz
from rba.learn.training import GlobalTrainConfig, train_global
from server.db.admin_tables import Dataset
from server.main import create_app
from server.ops import label_admin
from server.runtime.stored_labels import job_sources
from server.runtime.uploads import LEFTOVER_GRACE_SECONDS, NAME_RULE, claimed, workspace
from tests.server.test_admin import AUTH, STATE_DIM, TOKEN, datasets, labels_bytes, serve_ids, stored, upload

REPO = Path(__file__).resolve().parents[2]
OLD = time.time() - 2 * LEFTOVER_GRACE_SECONDS


@pytest.fixture
def temp_root(tmp_path, monkeypatch) -> Path:
    """This test's own temp folder: the app sweeps upload workspaces there, never in other tests' /tmp."""
    folder = tmp_path / "tmp"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


@pytest.fixture
def settings(make_settings, toy_roots, tmp_path, database_url, temp_root):
    shutil.copytree(toy_roots[0], tmp_path / "data")
    return make_settings(admin_token=TOKEN, data_dir=tmp_path / "data", database_url=database_url,
                         upload_max_bytes=256 * 1024, upload_max_uncompressed=512 * 1024)


@pytest.fixture
def admin(settings):
    with TestClient(create_app(settings)) as c:
        yield c


def npz_of(arrays: dict[str, np.ndarray]) -> bytes:
    """An .npz as numpy.savez writes it, member by member (``np.savez(**arrays)`` cannot take every name)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, a in arrays.items():
            with zf.open(f"{name}.npy", "w") as member:
                np.lib.format.write_array(member, a)
    return buf.getvalue()


def walks(names, steps: int = 12, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {n: rng.normal(size=(steps, STATE_DIM)).astype(np.float32) for n in names}


def ordering(*clips: str) -> bytes:
    return labels_bytes({"orderings": [{"attribute": "amplitude", "clips": list(clips)}]})


def assert_refused(client, settings, r, status: int, message: str) -> None:
    assert r.status_code == status, r.text
    assert message in r.json()["detail"], r.json()
    if status == 422 and "problems" in r.json():
        assert any(message in p for p in r.json()["problems"]), r.json()
    assert stored(settings) == [] and datasets(client) == []


# -- 1. labels JSON: nesting and shape ------------------------------------------------------------

NESTED = {
    "arrays": b"[" * 100_000 + b"]" * 100_000,
    "objects": b'{"a":' * 20_000 + b"1" + b"}" * 20_000,
    "inside a label set": b'{"orderings": [{"attribute": "amplitude", "clips": ' + b"[" * 5000 + b"]" * 5000 + b"}]}",
}


@pytest.mark.parametrize("case", list(NESTED))
def test_deeply_nested_labels_are_a_422_that_says_so(admin, settings, case):
    r = upload(admin, None, NESTED[case])
    assert_refused(admin, settings, r, 422, "labels: nested too deeply (too many levels of [ ] or { }); a label "
                                            "set is an object of lists of objects, at most 4 levels deep")


MALFORMED = {
    "not UTF-8": (b'{"orderings": "\xff"}', "labels: not UTF-8 JSON (byte 0xff at offset 15 is not UTF-8)"),
    "trailing text": (b"{} {}", "labels: not UTF-8 JSON (trailing characters at line 1 column 4)"),
    "lone surrogate": (b'{"orderings": ["\\ud800"]}', "labels: not UTF-8 JSON ("),
    "an array": (b"[]", "labels: the file holds an array; expected an object with new_attributes, orderings"),
    "a string": (b'"labels"', "labels: the file holds a string; expected an object"),
    "null": (b"null", "labels: the file holds null; expected an object"),
    "a huge number": (b"1e999", "labels: the file holds a number; expected an object"),
    "orderings is an object": (b'{"orderings": {"attribute": "amplitude"}}',
                               "labels.orderings: Input should be a valid list"),
    "a misspelt list": (b'{"ordering": []}', "labels: unknown key 'ordering'; valid keys: new_attributes, orderings, "
                                             "comparisons, local_changes"),
    "a misspelt key": (b'{"comparisons": [{"attribute": "amplitude", "mroe": "a", "less": "b"}]}',
                       "labels.comparisons[0]: unknown key 'mroe'; valid keys: attribute, more, less"),
    "a missing key": (b'{"comparisons": [{"attribute": "amplitude", "less": "b"}]}',
                      "labels.comparisons[0]: key 'more' is missing; an item of comparisons has the keys attribute, "
                      "more, less"),
    "a clip is a list": (b'{"orderings": [{"attribute": "amplitude", "clips": [["a"], "b"]}]}',
                         "labels.orderings[0].clips[0]: Input should be a valid string"),
    "a direction": (b'{"local_changes": [{"attribute": "amplitude", "anchor": "a", "changed": "b", "direction": 1}]}',
                    "labels.local_changes[0].direction: Input should be 'more' or 'less'"),
}


@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed_labels_are_a_422_that_says_what_is_wrong(admin, settings, case):
    raw, message = MALFORMED[case]
    assert_refused(admin, settings, upload(admin, None, raw), 422, message)


def test_thousands_of_label_problems_are_listed_up_to_a_limit(admin, settings):
    raw = labels_bytes({"comparisons": [{"attribute": 7, "more": "a", "less": "b"}] * 500})
    r = upload(admin, None, raw)
    assert_refused(admin, settings, r, 422, "labels.comparisons[0].attribute: Input should be a valid string")
    assert len(r.json()["problems"]) == 51
    assert r.json()["problems"][-1] == "and 450 more problem(s)"


def test_labels_with_a_byte_order_mark_are_read(admin, settings):
    ids = serve_ids(admin, 2)
    r = upload(admin, None, b"\xef\xbb\xbf" + ordering(*ids))
    assert r.status_code == 201, r.text
    assert r.json()["labels"] == 1 and len(stored(settings)) == 1


# -- 2. trajectory names are data ------------------------------------------------------------------

NAMES = ["file", "allow_pickle", "args", "kwds", "compress", "arr_0", "x", "x.npy", "歩く_é 1", "..", "a:b"]


def test_names_that_are_savez_parameters_or_unicode_round_trip_through_upload_and_load(admin, settings):
    ids = serve_ids(admin, 1)
    arrays = walks(NAMES)
    r = upload(admin, npz_of(arrays), ordering(ids[0], *NAMES))
    assert r.status_code == 201, r.text
    ds = r.json()
    assert ds["trajectories"] == len(NAMES)

    kept = load_npz(settings.data_dir / "uploads" / "toy" / f"{ds['id']}.npz")
    assert sorted(kept) == sorted(NAMES)
    for name in NAMES:
        np.testing.assert_array_equal(kept[name], arrays[name])
    with np.load(settings.data_dir / "uploads" / "toy" / f"{ds['id']}.npz", allow_pickle=False) as z:
        np.testing.assert_array_equal(z["allow_pickle"], arrays["allow_pickle"])  # numpy reads it too

    svc = admin.app.state.services
    with Session(svc.engine) as db:
        [source] = job_sources(db, svc.store.uploads("toy"), "toy", [ds["id"]], include_page_labels=False)
    assert source.name == f"dataset {ds['id']}" and sorted(source.trajectories) == sorted(NAMES)
    np.testing.assert_array_equal(source.trajectories["file"], arrays["file"])
    source.check(label_admin.library_ids(svc, "toy"), STATE_DIM)  # every reference resolves


BAD_NAMES = {
    "a path": ("walks/a", f"is not a .npy array named with {NAME_RULE}"),
    "a back-slash path": ("..\\a", f"is not a .npy array named with {NAME_RULE}"),
    "a tab": ("a\tb", f"is not a .npy array named with {NAME_RULE}"),
    "a leading space": (" a", f"is not a .npy array named with {NAME_RULE}"),
    "empty": ("", f"is not a .npy array named with {NAME_RULE}"),
    "too long": ("n" * 129, f"is not a .npy array named with {NAME_RULE}"),
}


@pytest.mark.parametrize("case", list(BAD_NAMES))
def test_names_that_cannot_be_shown_or_matched_are_refused(admin, settings, case):
    name, message = BAD_NAMES[case]
    r = upload(admin, npz_of(walks([name, "ok"])), ordering("ok", serve_ids(admin, 1)[0]))
    assert_refused(admin, settings, r, 422, message)


def test_a_name_twice_in_one_npz_is_refused(admin, settings):
    one = npz_of(walks(["mine"]))
    buf = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(one)) as src, zipfile.ZipFile(buf, "w") as zf, pytest.warns(UserWarning):
        zf.writestr("mine.npy", src.read("mine.npy"))
        zf.writestr("mine.npy", src.read("mine.npy"))
    r = upload(admin, buf.getvalue(), ordering("mine", serve_ids(admin, 1)[0]))
    assert_refused(admin, settings, r, 422, "trajectories: member 'mine.npy' appears more than once")


# -- 2b. a training job checks a dataset's references again ----------------------------------------

@pytest.fixture
def dataset(admin, settings) -> tuple[str, Path]:
    ids = serve_ids(admin, 1)
    r = upload(admin, npz_of(walks(["walk_a", "walk_b"])), ordering("walk_a", ids[0], "walk_b"))
    assert r.status_code == 201, r.text
    return r.json()["id"], settings.data_dir / "uploads" / "toy" / f"{r.json()['id']}.npz"


TAMPERED = {
    "a trajectory renamed": (lambda a: {"walk_a": a["walk_a"], "other": a["walk_b"]},
                             "its labels refer to 1 clip(s) that are neither its trajectories nor train/serve "
                             "rollouts: 'walk_b'"),
    "a trajectory of the wrong width": (lambda a: {"walk_a": np.zeros((12, 7), np.float32), "walk_b": a["walk_b"]},
                                        "trajectory 'walk_a' has shape [12, 7], expected [T, 4]"),
}


@pytest.mark.parametrize("case", list(TAMPERED))
def test_training_refuses_a_dataset_whose_references_no_longer_hold(admin, settings, dataset, case, tmp_path):
    dataset_id, npz = dataset
    change, message = TAMPERED[case]
    save_npz(npz, change(load_npz(npz)))
    svc = admin.app.state.services
    with Session(svc.engine) as db:
        sources = job_sources(db, svc.store.uploads("toy"), "toy", [dataset_id], include_page_labels=False)
    with pytest.raises(ValueError) as e:
        train_global("toy", "onehot", GlobalTrainConfig(), data_root=settings.data_dir, models_root=tmp_path / "m",
                     sources=sources)
    assert str(e.value) == f"dataset {dataset_id}: {message}"
    assert not (tmp_path / "m").exists()


def test_loading_a_dataset_that_lost_a_trajectory_names_the_dataset(admin, dataset):
    dataset_id, npz = dataset
    save_npz(npz, {"walk_a": load_npz(npz)["walk_a"]})  # what numpy.savez did to a trajectory named allow_pickle
    svc = admin.app.state.services
    with Session(svc.engine) as db, pytest.raises(ValueError) as e:
        job_sources(db, svc.store.uploads("toy"), "toy", [dataset_id], include_page_labels=False)
    assert str(e.value) == f"dataset {dataset_id}: 1 trajectories stored where its upload had 2"


# -- 4. crashes: the whole dataset or nothing ------------------------------------------------------

def folder_of(settings) -> Path:
    return settings.data_dir / "uploads" / "toy"


def rows(settings) -> list[str]:
    from server.db.engine import make_engine

    engine = make_engine(settings.db_url)
    try:
        with Session(engine) as db:
            return sorted(db.exec(select(Dataset.id)).all())
    finally:
        engine.dispose()


def a_dataset(client, seed: int) -> dict:
    r = upload(client, npz_of(walks(["walk_a", "walk_b"], seed=seed)), ordering("walk_a", "walk_b"))
    assert r.status_code == 201, r.text
    return r.json()


def fail_at(monkeypatch, name: str, error: BaseException) -> None:
    def fail(*_args, **_kwargs):
        raise error

    monkeypatch.setattr(label_admin, name, fail)


def test_restart_removes_what_dead_uploads_left_and_keeps_whole_datasets(admin, settings, monkeypatch):
    folder = folder_of(settings)
    whole = a_dataset(admin, 1)
    committed = a_dataset(admin, 2)
    (folder / f".{committed['id']}.lock").touch()  # killed after its commit, before its lock went
    fail_at(monkeypatch, "_record_upload", RuntimeError("killed before the row"))
    with pytest.raises(RuntimeError):
        a_dataset(admin, 3)
    monkeypatch.undo()
    unrecorded = {p.name for p in folder.iterdir()} - {f"{d['id']}.{x}" for d in (whole, committed)
                                                       for x in ("npz", "json")} - {f".{committed['id']}.lock"}
    assert len(unrecorded) == 3  # its .npz, .json and free lock
    half = "c" * 32  # killed while writing: a temporary and the free lock
    (folder / f".{half}.npz.x1y2z3.tmp").write_bytes(b"")
    (folder / f".{half}.lock").touch()
    old, young = "e" * 32, "f" * 32  # no lock: written by hand, or by a version without locks
    for dataset_id in (old, young):
        for name in (f"{dataset_id}.npz", f"{dataset_id}.json", f".{dataset_id}.json.q9.tmp"):
            (folder / name).write_bytes(b"{}")
    for path in folder.glob(f"*{old}*"):
        os.utime(path, (OLD, OLD))
    (folder / "README.txt").write_text("not the store's")
    live = "d" * 32
    with claimed(folder / f".{live}.lock"):  # an upload under way in another process or replica
        (folder / f"{live}.npz").write_bytes(b"being written")
        with TestClient(create_app(settings)) as again:
            assert {d["id"] for d in datasets(again)} == {whole["id"], committed["id"]}
        assert sorted(p.name for p in folder.iterdir()) == sorted([
            f"{whole['id']}.json", f"{whole['id']}.npz", f"{committed['id']}.json", f"{committed['id']}.npz",
            f"{young}.json", f"{young}.npz", f".{young}.json.q9.tmp", f"{live}.npz", f".{live}.lock", "README.txt"])
    assert rows(settings) == sorted([whole["id"], committed["id"]])
    assert load_npz(folder / f"{whole['id']}.npz").keys() == {"walk_a", "walk_b"}


def test_a_failure_while_saving_leaves_no_dataset_file(admin, settings, monkeypatch):
    fail_at(monkeypatch, "save_text", OSError(28, "No space left on device"))
    with pytest.raises(OSError):
        a_dataset(admin, 1)
    monkeypatch.undo()
    left = [p.name for p in folder_of(settings).iterdir()]
    assert len(left) == 1 and left[0].endswith(".lock") and datasets(admin) == []  # the lock: for the sweep
    again = a_dataset(admin, 1)  # the same upload, now whole
    assert sorted(p.name for p in folder_of(settings).iterdir()) == [f"{again['id']}.json", f"{again['id']}.npz"]


def test_restart_removes_dead_uploads_workspaces_only(settings, temp_root):
    dead = Path(tempfile.mkdtemp(prefix="rba-upload-"))
    (dead / "owner.lock").touch()  # its process died: nothing holds the lock
    (dead / "upload.npz").write_bytes(b"6.7 MB of trajectories")
    old, young = (Path(tempfile.mkdtemp(prefix="rba-upload-")) for _ in range(2))  # no lock yet (or any more)
    os.utime(old, (OLD, OLD))
    other = temp_root / "rba-clip-1234"
    other.mkdir()
    with workspace() as live:
        (live / "upload.npz").write_bytes(b"being checked")
        with TestClient(create_app(settings)):
            pass
        assert sorted(temp_root.iterdir()) == sorted([young, live, other])
        assert (live / "upload.npz").exists()
    assert sorted(temp_root.iterdir()) == sorted([young, other])


# -- 4b. a real server process killed with SIGKILL ------------------------------------------------

def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(settings, temp_root: Path, kill_at: str | None = None) -> tuple[subprocess.Popen, str]:
    port = free_port()
    env = {**os.environ, "RBA_DATA_DIR": str(settings.data_dir), "RBA_MODELS_DIR": str(settings.models_dir),
           "RBA_CACHE_DIR": str(settings.cache_dir), "RBA_DATABASE_URL": settings.db_url, "RBA_ADMIN_TOKEN": TOKEN,
           "RBA_WARM_START": "false", "RBA_PRERENDER": "false", "RBA_PRERENDER_LIBRARY": "false",
           "RBA_UPLOAD_MAX_BYTES": str(64 * 2**20), "RBA_UPLOAD_MAX_UNCOMPRESSED": str(64 * 2**20),
           "RBA_COMPUTE_WORKERS": "1", "TMPDIR": str(temp_root), "PYTHONPATH": str(REPO)}
    args = [sys.executable, "-m", "tests.server.upload_server", str(port), *([kill_at] if kill_at else [])]
    log = temp_root.parent / f"server-{port}.log"
    with log.open("wb") as out:
        proc = subprocess.Popen(args, cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT)
    url, deadline = f"http://127.0.0.1:{port}", time.monotonic() + 120  # a loaded CI machine imports slowly
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            httpx.get(f"{url}/healthz", timeout=1)
            return proc, url
        except httpx.TransportError:
            time.sleep(0.1)
    proc.kill()
    raise AssertionError(f"the server did not start: {log.read_text()[-2000:]}")


def post_upload(url: str, npz: bytes, labels: bytes) -> httpx.Response:
    files = {"labels": ("labels.json", labels, "application/json"),
             "trajectories": ("walks.npz", npz, "application/octet-stream")}
    return httpx.post(f"{url}/api/admin/datasets", data={"domain": "toy"}, files=files, headers=AUTH, timeout=120)


def big_upload(n: int = 400, steps: int = 1000) -> tuple[bytes, bytes]:
    """About 6 MB of trajectories that do not compress: seconds to check and store on a busy machine."""
    names = [f"walk_{i}" for i in range(n)]
    return npz_of(walks(names, steps=steps)), ordering(*names[:50])


def on_disk(settings, temp_root: Path) -> list[str]:
    uploads = sorted(p.name for p in folder_of(settings).iterdir()) if folder_of(settings).exists() else []
    return uploads + sorted(p.name for p in temp_root.glob("rba-upload-*"))


LEFT_BY = {  # what each kill leaves before the restart: a workspace, a temporary, files, a lock
    "checking": lambda names: any(n.startswith("rba-upload-") for n in names),
    "writing": lambda names: any(n.endswith(".tmp") for n in names),
    "saved": lambda names: sum(n.endswith((".npz", ".json")) for n in names) == 2,
    "recorded": lambda names: any(n.endswith(".lock") for n in names),
}


@pytest.mark.parametrize("kill_at", list(LEFT_BY))
def test_server_killed_at_each_step_of_an_upload_leaves_all_or_nothing(settings, temp_root, kill_at):
    if "postgres" in settings.db_url:
        pytest.skip("one database is enough for the process tests (the sweep runs on both above)")
    proc, url = start_server(settings, temp_root, kill_at)
    try:
        npz, labels = big_upload(40, 100)
        with pytest.raises(httpx.TransportError):
            post_upload(url, npz, labels)
        assert proc.wait(30) == -signal.SIGKILL
    finally:
        proc.kill()
    left = on_disk(settings, temp_root)
    assert LEFT_BY[kill_at](left), left
    with TestClient(create_app(settings)) as again:
        kept = datasets(again)
    if kill_at == "recorded":
        assert [d["trajectories"] for d in kept] == [40]
        assert on_disk(settings, temp_root) == [f"{kept[0]['id']}.json", f"{kept[0]['id']}.npz"]
    else:
        assert kept == [] and on_disk(settings, temp_root) == [] and rows(settings) == []


def test_server_sigkilled_mid_upload_leaves_nothing_after_a_restart(settings, temp_root):
    if "postgres" in settings.db_url:
        pytest.skip("one database is enough for the process tests (the sweep runs on both above)")
    npz, labels = big_upload()
    proc, url = start_server(settings, temp_root)
    try:
        answer: list = []
        sending = threading.Thread(target=lambda: answer.append(_attempt(url, npz, labels)))
        sending.start()
        deadline = time.monotonic() + 60
        while not any(temp_root.glob("rba-upload-*/upload.npz")) and time.monotonic() < deadline:
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        sending.join(30)
        assert proc.wait(30) == -signal.SIGKILL
    finally:
        proc.kill()
    assert answer and isinstance(answer[0], httpx.TransportError), answer  # killed before it answered
    assert on_disk(settings, temp_root) != []  # the killed upload did leave its workspace
    proc, url = start_server(settings, temp_root)
    try:
        assert on_disk(settings, temp_root) == [] and rows(settings) == []
        r = post_upload(url, npz, labels)  # and the same upload now goes through whole
        assert r.status_code == 201, r.text
        assert on_disk(settings, temp_root) == [f"{r.json()['id']}.json", f"{r.json()['id']}.npz"]
        assert rows(settings) == [r.json()["id"]]
    finally:
        proc.terminate()
        proc.wait(30)


def _attempt(url: str, npz: bytes, labels: bytes) -> httpx.Response | Exception:
    try:
        return post_upload(url, npz, labels)
    except httpx.TransportError as e:
        return e

