"""Admin routes on the toy pipeline: auth, uploads (good and bad), page labels, training jobs, versions.

Every bad input asserts the status, the message, and that nothing was stored or changed.
"""

from __future__ import annotations

import io
import json
import logging
import pickle
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from server.main import create_app
from tests.conftest import own_copy

TOKEN = "s3cret-admin-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
STATE_DIM = 4  # the toy domain's


@pytest.fixture
def settings(make_settings, toy_roots, tmp_path, database_url):
    """Own copies of the toy models and data folders: jobs write versions and uploads there."""
    own_copy(toy_roots, tmp_path)
    return make_settings(admin_token=TOKEN, data_dir=tmp_path / "data", models_dir=tmp_path / "models",
                         upload_max_bytes=256 * 1024, upload_max_uncompressed=512 * 1024, database_url=database_url)


@pytest.fixture
def admin(settings):
    with TestClient(create_app(settings)) as c:
        yield c


def npz_bytes(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def labels_bytes(obj) -> bytes:
    return json.dumps(obj).encode()


def serve_ids(client, n: int) -> list[str]:
    r = client.get("/api/admin/pairs", params={"domain": "toy", "size": max(n, 2)}, headers=AUTH)
    assert r.status_code == 200, r.text
    return [c["rollout_id"] for c in r.json()["clips"]][:n]


def upload(client, npz: bytes | None, labels: bytes, name: str = "walks.npz", domain: str = "toy", headers=AUTH):
    files = {"labels": ("labels.json", labels, "application/json")}
    if npz is not None:
        files["trajectories"] = (name, npz, "application/octet-stream")
    return client.post("/api/admin/datasets", data={"domain": domain}, files=files, headers=headers)


def stored(settings) -> list[Path]:
    folder = settings.data_dir / "uploads"
    return sorted(p for p in folder.rglob("*") if p.is_file()) if folder.exists() else []


def datasets(client) -> list:
    r = client.get("/api/admin/datasets", params={"domain": "toy"}, headers=AUTH)
    assert r.status_code == 200, r.text
    return r.json()


def good_trajectories(n: int = 3, rng=None) -> dict[str, np.ndarray]:
    rng = rng or np.random.default_rng(0)
    return {f"mine_{i}": rng.normal(size=(12, STATE_DIM)).astype(np.float32) for i in range(n)}


# -- auth -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("headers, status, message", [
    ({}, 401, "admin token required"),
    ({"Authorization": "Bearer wrong"}, 401, "wrong admin token"),
    ({"Authorization": f"Basic {TOKEN}"}, 401, "admin token required"),
])
def test_admin_routes_need_the_token(admin, headers, status, message):
    for method, url in [("get", "/api/admin/datasets?domain=toy"), ("get", "/api/admin/jobs"),
                        ("get", "/api/admin/models?domain=toy"), ("get", "/api/admin/pairs?domain=toy"),
                        ("get", "/api/admin/labels?domain=toy"), ("post", "/api/admin/train"),
                        ("post", "/api/admin/models/x/activate"), ("get", "/api/admin/jobs/x/curves")]:
        r = getattr(admin, method)(url, headers=headers)
        assert r.status_code == status, (url, r.text)
        assert message in r.json()["detail"]
    r = upload(admin, npz_bytes(**good_trajectories()), labels_bytes({}), headers=headers)
    assert r.status_code == status and message in r.json()["detail"]
    assert datasets(admin) == []


def test_admin_disabled_without_a_token(make_settings):
    with TestClient(create_app(make_settings(admin_token=None))) as c:
        r = c.get("/api/admin/jobs", headers=AUTH)
        assert r.status_code == 503
        assert "admin disabled" in r.json()["detail"]


def test_admin_page_is_served_and_holds_no_data(admin):
    r = admin.get("/admin")
    assert r.status_code == 200
    # the static file as it is (its format help names example ids): every datum comes from token-checked routes
    assert r.text == (Path(__file__).resolve().parents[2] / "frontend" / "admin.html").read_text()
    assert "RBA Studio admin" in r.text


# -- uploads ---------------------------------------------------------------------------------------

def test_upload_stores_once_and_duplicate_is_a_no_op(admin, settings):
    ids = serve_ids(admin, 2)
    traj = good_trajectories()
    labels = {"new_attributes": [{"name": "wobble", "description": "How much the point wobbles."}],
              "orderings": [{"attribute": "wobble", "clips": ["mine_0", ids[0], "mine_1", ids[1]]}],
              "comparisons": [{"attribute": "amplitude", "more": "mine_2", "less": ids[0]}]}
    r = upload(admin, npz_bytes(**traj), labels_bytes(labels), name="../../etc/passwd")
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["trajectories"] == 3 and body["labels"] == 2 and body["new_attributes"] == ["wobble"]
    assert body["duplicate"] is False and body["filename"] == "../../etc/passwd"  # shown, never a path
    files = stored(settings)
    assert [p.name for p in files] == [f"{body['id']}.json", f"{body['id']}.npz"]
    assert all(p.parent == settings.data_dir / "uploads" / "toy" for p in files)
    with np.load(files[1], allow_pickle=False) as z:
        np.testing.assert_array_equal(z["mine_1"], traj["mine_1"])
    attrs = admin.get("/api/admin/attributes", params={"domain": "toy"}, headers=AUTH).json()["attributes"]
    assert {"name": "wobble", "description": "How much the point wobbles.", "added": True} in attrs

    again = upload(admin, npz_bytes(**traj), labels_bytes(labels), name="other.npz")
    assert again.status_code == 200, again.text
    assert again.json()["duplicate"] is True and again.json()["id"] == body["id"]
    assert stored(settings) == files and len(datasets(admin)) == 1


def _pickle_npz() -> bytes:
    return pickle.dumps({"mine_0": np.zeros((5, STATE_DIM))})


def _object_npz() -> bytes:
    buf = io.BytesIO()
    np.savez(buf, mine_0=np.array([np.zeros(3), "x"], dtype=object), allow_pickle=True)
    return buf.getvalue()


def _zip_bomb() -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, mine_0=np.zeros((200_000, STATE_DIM), dtype=np.float64))  # 6.4 MB -> a few KB
    return buf.getvalue()


def _traversal_member() -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        inner = io.BytesIO()
        np.save(inner, np.zeros((5, STATE_DIM), dtype=np.float32))
        zf.writestr("../../x.npy", inner.getvalue())
    return buf.getvalue()


def _nan() -> bytes:
    a = np.zeros((6, STATE_DIM), dtype=np.float32)
    a[2, 1], a[3, 0] = np.nan, np.inf
    return npz_bytes(mine_0=a)


def _ordering(*clips, attribute="amplitude"):
    return labels_bytes({"orderings": [{"attribute": attribute, "clips": list(clips)}]})


BAD_UPLOADS = {
    "pickle disguised as npz": (_pickle_npz, None, 422, "not an .npz file"),
    "object arrays": (_object_npz, None, 422, "object arrays are refused"),
    "NaN and inf": (_nan, None, 422, "NaN or infinite"),
    "wrong state_dim": (lambda: npz_bytes(mine_0=np.zeros((6, 7), np.float32)), None, 422, "expected [T, 4]"),
    "integer dtype": (lambda: npz_bytes(mine_0=np.zeros((6, STATE_DIM), np.int64)), None, 422, "not a float type"),
    "too short": (lambda: npz_bytes(mine_0=np.zeros((1, STATE_DIM), np.float32)), None, 422, "T must be in"),
    "empty npz file": (lambda: b"", None, 422, "trajectories: the file is empty"),
    "no arrays": (lambda: npz_bytes(), None, 422, "holds no arrays"),
    "zip bomb": (_zip_bomb, None, 422, "zip bomb"),
    "path traversal member": (_traversal_member, None, 422, "is not a .npy array named"),
    "missing trajectory": (lambda: npz_bytes(**good_trajectories(1)), _ordering("mine_0", "mine_9"), 422,
                           "labels.orderings[0]: clip 'mine_9' is no train or serve rollout id"),
    "unknown attribute": (lambda: npz_bytes(**good_trajectories(2)), _ordering("mine_0", "mine_1", attribute="zest"),
                          422, "unknown attribute 'zest'; valid: amplitude, pace"),
    "empty labels": (lambda: npz_bytes(**good_trajectories(2)), b"", 422, "labels: the file is empty"),
    "labels not json": (lambda: npz_bytes(**good_trajectories(2)), b"{oops", 422, "not UTF-8 JSON"),
    "unknown label field": (lambda: npz_bytes(**good_trajectories(2)), labels_bytes({"orderz": []}), 422,
                            "labels: unknown key 'orderz'; valid keys: new_attributes, orderings"),
    "oversized upload": (lambda: b"\0" * (300 * 1024), None, 413, "upload too large"),
    "a new attribute declared twice": (  # was a 500 (the database's unique constraint) and a stray file
        lambda: npz_bytes(**good_trajectories(2)),
        labels_bytes({"new_attributes": [{"name": "x1", "description": "First one here."},
                                         {"name": "x1", "description": "Second one here."}],
                      "orderings": [{"attribute": "x1", "clips": ["mine_0", "mine_1"]}]}),
        422, "new attribute 'x1' is declared 2 times; declare each once"),
}


@pytest.mark.parametrize("case", list(BAD_UPLOADS))
def test_bad_upload_is_refused_and_nothing_is_stored(admin, settings, case):
    make_npz, labels, status, message = BAD_UPLOADS[case]
    labels = labels if labels is not None else _ordering("mine_0", serve_ids(admin, 1)[0])
    before = stored(settings)
    r = upload(admin, make_npz(), labels)
    assert r.status_code == status, r.text
    assert message in r.json()["detail"], r.json()
    if status == 422:
        assert message in " ".join(r.json()["problems"])
    assert stored(settings) == before == []
    assert datasets(admin) == []


def test_upload_lists_every_problem(admin):
    a = np.zeros((6, 7), np.float32)
    r = upload(admin, npz_bytes(bad_dim=a, ok=np.zeros((5, STATE_DIM), np.float32)),
               _ordering("ok", "ghost", attribute="zest"))
    assert r.status_code == 422
    problems = r.json()["problems"]
    assert any("expected [T, 4]" in p for p in problems)
    r = upload(admin, npz_bytes(ok=np.zeros((5, STATE_DIM), np.float32)), _ordering("ok", "ghost", attribute="zest"))
    problems = r.json()["problems"]
    assert any("unknown attribute 'zest'" in p for p in problems) and any("'ghost'" in p for p in problems)


def test_every_problem_of_a_label_file_is_listed_at_once(admin, settings):
    """A misspelt key no longer hides the unknown attribute and the unknown clips of the other labels."""
    ids = serve_ids(admin, 2)
    labels = {"comparisons": [{"attribute": "amplitude", "mroe": ids[0], "less": ids[1]},  # misspelt
                              {"attribute": "zest", "more": ids[0], "less": ids[1]}],  # unknown attribute
              "orderings": [{"attribute": "pace", "clips": [ids[0], "ghost-1", "ghost-2"]}],  # unknown clips
              "local_chagnes": []}
    r = upload(admin, None, labels_bytes(labels))
    assert r.status_code == 422, r.text
    problems = r.json()["problems"]
    assert problems == [
        "labels.comparisons[0]: key 'more' is missing; an item of comparisons has the keys attribute, more, less",
        "labels.comparisons[0]: unknown key 'mroe'; valid keys: attribute, more, less",
        "labels: unknown key 'local_chagnes'; valid keys: new_attributes, orderings, comparisons, local_changes",
        "labels.orderings[0]: clip 'ghost-1' is no train or serve rollout id of the domain (ids look like "
        "train-00012 or serve-00086) and no trajectory name of the uploaded .npz",
        "labels.orderings[0]: clip 'ghost-2' is no train or serve rollout id of the domain (ids look like "
        "train-00012 or serve-00086) and no trajectory name of the uploaded .npz",
        "labels.comparisons[1].attribute: unknown attribute 'zest'; valid: amplitude, pace (declare a new one: "
        "new_attributes in an upload, or POST /api/admin/attributes)"], problems
    assert r.json()["detail"] == "; ".join(problems)
    assert stored(settings) == [] and datasets(admin) == []


def test_the_example_label_file_is_accepted(admin):
    r = admin.get("/api/admin/datasets/example", params={"domain": "toy"}, headers=AUTH)
    assert r.status_code == 200, r.text
    assert r.headers["content-disposition"] == 'attachment; filename="labels-example-toy.json"'
    example = r.json()
    assert all(example[group] for group in ("new_attributes", "orderings", "comparisons", "local_changes"))
    stored_as = upload(admin, None, r.content)
    assert stored_as.status_code == 201, stored_as.text
    assert stored_as.json()["labels"] == 4 and stored_as.json()["new_attributes"] == ["my_attribute"]
    assert admin.get("/api/admin/datasets/example", params={"domain": "nope"}, headers=AUTH).status_code == 422


def test_the_api_docs_describe_the_label_file(admin):
    schemas = admin.get("/openapi.json").json()["components"]["schemas"]
    assert "LabelSet" in schemas["DatasetUpload"]["properties"]["labels"]["description"]
    fields = {name: schemas[name]["properties"] for name in ("LabelSet", "Ordering", "Comparison", "LocalChange",
                                                               "NewAttribute")}
    assert all(field.get("description") for props in fields.values() for field in props.values()), fields
    assert "train or serve rollout id" in fields["Comparison"]["more"]["description"]
    assert "least to most" in fields["Ordering"]["clips"]["description"]


def test_upload_body_limit_is_enforced_while_streaming(admin, settings):
    """No Content-Length: the limit still stops the body as it streams in."""
    def body():
        for _ in range(100):
            yield b"x" * 8192  # 800 KB in all, over the 256 KB limit

    r = admin.post("/api/admin/datasets", content=body(),
                   headers={**AUTH, "Content-Type": "multipart/form-data; boundary=zzz"})
    assert r.status_code == 413 and "over the limit of 262144 bytes" in r.json()["detail"]
    assert stored(settings) == []


# -- page labels ---------------------------------------------------------------------------------------

def test_page_labels_are_saved_as_made_and_checked(admin):
    a, b = serve_ids(admin, 2)
    r = admin.post("/api/admin/labels", headers=AUTH,
                   json={"domain": "toy", "comparison": {"attribute": "amplitude", "more": a, "less": b}})
    assert r.status_code == 201, r.text
    assert r.json()["kind"] == "comparison" and r.json()["payload"]["more"] == a
    r = admin.post("/api/admin/labels", headers=AUTH,
                   json={"domain": "toy", "comparison": {"attribute": "nope", "more": a, "less": b}})
    assert r.status_code == 422 and "unknown attribute 'nope'" in r.json()["detail"]
    assert "or POST /api/admin/attributes" in r.json()["detail"]  # this route takes no new_attributes
    r = admin.post("/api/admin/labels", headers=AUTH,
                   json={"domain": "toy", "comparison": {"attribute": "amplitude", "more": a, "less": "test-00001"}})
    assert r.status_code == 422 and "'test-00001'" in r.json()["detail"]  # held-out clips cannot be labelled
    r = admin.post("/api/admin/labels", headers=AUTH, json={"domain": "toy"})
    assert r.status_code == 422 and "exactly one of ordering, comparison, local_change" in r.json()["detail"]
    r = admin.post("/api/admin/attributes", headers=AUTH,
                   json={"domain": "toy", "name": "amplitude", "description": "d"})
    assert r.status_code == 422 and "3-300 characters" in r.json()["detail"]
    r = admin.post("/api/admin/attributes", headers=AUTH,
                   json={"domain": "toy", "name": "amplitude", "description": "Where the point is."})
    assert r.status_code == 409 and "already an attribute" in r.json()["detail"]
    r = admin.post("/api/admin/attributes", headers=AUTH,
                   json={"domain": "toy", "name": "Bad Name", "description": "Where the point is."})
    assert r.status_code == 422 and "must match" in r.json()["detail"]
    listed = admin.get("/api/admin/labels", params={"domain": "toy"}, headers=AUTH).json()
    assert len(listed) == 1


# -- training jobs and versions -----------------------------------------------------------------------

def wait_job(client, job_id: str, timeout: float = 300) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/api/admin/jobs/{job_id}", headers=AUTH).json()
        if job["state"] in ("succeeded", "failed", "cancelled"):
            return job
        time.sleep(0.5)
    raise AssertionError(f"job {job_id} did not finish: {job}")


def test_train_activate_and_sessions_keep_their_version(admin, settings, caplog):
    caplog.set_level(logging.INFO, logger="server.ops.model_versions")
    first = admin.post("/api/sessions", json={"domain": "toy", "method": "global", "rep": "onehot"}).json()
    assert first["model_set"] == "builtin"
    ids = serve_ids(admin, 8)
    labels = {"new_attributes": [{"name": "wobble", "description": "How much the point wobbles."}],
              "orderings": [{"attribute": "wobble", "clips": ids}]}
    ds = upload(admin, None, labels_bytes(labels)).json()
    r = admin.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "datasets": [ds["id"]], "preset": "tiny"})
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    busy = admin.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "preset": "tiny"})
    assert busy.status_code == 409 and f"already running ({job_id})" in busy.json()["detail"]
    job = wait_job(admin, job_id)
    assert job["state"] == "succeeded", job
    assert job["progress"] == 1.0 and job["version"] and "wobble" in job["held_out"]["ranker"]
    version = job["version"]
    assert (settings.models_dir / "versions" / version / "toy" / "ranker-onehot.json").exists()
    assert not list((settings.models_dir / "versions").glob(".tmp-*"))
    curves = admin.get(f"/api/admin/jobs/{job_id}/curves", headers=AUTH).json()  # published with the version
    ranker = {s["tag"]: s for s in next(m for m in curves["models"] if m["model"] == "ranker-onehot")["series"]}
    assert ranker["loss"]["steps"][-1] == 200  # the tiny preset's ζσ steps
    assert ranker["held_out/held_out_pair_accuracy/wobble"]["values"][-1] == pytest.approx(
        job["held_out"]["ranker"]["wobble"]["held_out_pair_accuracy"], abs=1e-6)  # measured as its card's number

    r = admin.post(f"/api/admin/models/{version}/activate", params={"domain": "walker"}, headers=AUTH)
    assert r.status_code == 422  # another domain's version: refused, not activated for its own silently
    assert r.json()["detail"] == (f"version {version} is toy's, not walker's; leave domain out (a version names its "
                                  "own) or give its own")
    r = admin.post(f"/api/admin/models/{version}/activate", params={"domain": "toy"}, headers=AUTH)
    assert r.status_code == 200 and r.json()["active"] is True
    assert r.json()["attributes"] == ["amplitude", "pace", "wobble"]
    new = admin.post("/api/sessions", json={"domain": "toy", "method": "global", "rep": "onehot"}).json()
    assert new["model_set"] == version and [a["name"] for a in new["attributes"]] == ["amplitude", "pace", "wobble"]
    r = admin.post(f"/api/sessions/{new['id']}/feedback",
                   json={"step": 0, "feedback": [{"attribute": "wobble", "direction": "more"}]})
    assert r.status_code == 200, r.text
    # the session that started before keeps its version and attributes
    again = admin.get(f"/api/sessions/{first['id']}").json()
    assert again["model_set"] == "builtin" and [a["name"] for a in again["attributes"]] == ["amplitude", "pace"]
    r = admin.post(f"/api/sessions/{first['id']}/feedback",
                   json={"step": 0, "feedback": [{"attribute": "wobble", "direction": "more"}]})
    assert r.status_code == 422 and "unknown attribute 'wobble' for toy; valid: amplitude, pace" in r.json()["detail"]

    versions = admin.get("/api/admin/models", params={"domain": "toy"}, headers=AUTH).json()
    assert [(v["version"], v["active"]) for v in versions] == [("builtin", False), (version, True)]
    r = admin.post("/api/admin/models/builtin/activate", params={"domain": "toy"}, headers=AUTH)
    assert r.status_code == 200
    back = admin.post("/api/sessions", json={"domain": "toy", "method": "global", "rep": "onehot"}).json()
    assert back["model_set"] == "builtin"
    assert f"toy: new sessions get version {version} (global/onehot; was builtin)" in caplog.text  # who served what
    assert f"toy: new sessions get the built-in models again (was {version})" in caplog.text


def test_activate_missing_version_changes_nothing(admin):
    r = admin.post("/api/admin/models/toy-20260101-000000-abcdef/activate", headers=AUTH)
    assert r.status_code == 404
    assert "no model version 'toy-20260101-000000-abcdef'; versions: none yet, builtin" in r.json()["detail"]
    r = admin.post("/api/admin/models/..%2F..%2Fetc/activate", headers=AUTH)
    assert r.status_code == 404
    s = admin.post("/api/sessions", json={"domain": "toy", "method": "global", "rep": "onehot"}).json()
    assert s["model_set"] == "builtin"


def test_a_method_a_route_lacks_names_every_method_it_takes(admin):
    r = admin.delete("/api/admin/labels", headers=AUTH)
    assert r.status_code == 405 and r.headers["allow"] == "GET, POST"  # Starlette's named only the first route's
    assert r.json()["detail"] == "DELETE is not allowed on /api/admin/labels; allowed: GET, POST"


def test_train_request_errors(admin):
    r = admin.post("/api/admin/train", headers=AUTH, json={"domain": "nope"})
    assert r.status_code == 422 and "unknown domain 'nope'; valid: walker" in r.json()["detail"]
    r = admin.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "datasets": ["missing"]})
    assert r.status_code == 422 and "no dataset 'missing' for toy; uploaded: none" in r.json()["detail"]
    r = admin.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "method": "magic"})
    assert r.status_code == 422 and "method: unknown method 'magic'; valid: global, local" in r.json()["detail"]
    r = admin.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "method": "local", "preset": "pairwise"})
    assert r.status_code == 422, r.text  # another method's preset: refused now, not failed in the job later
    assert "unknown preset 'pairwise' for method local; valid: default, quick, tiny" in r.json()["detail"]
    r = admin.get("/api/admin/jobs/nope", headers=AUTH)
    assert r.status_code == 404 and "no training job 'nope'" in r.json()["detail"]
    assert admin.get("/api/admin/jobs", headers=AUTH).json() == []


def test_cancelled_job_publishes_nothing(admin, settings):
    r = admin.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "preset": "default"})
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    r = admin.post(f"/api/admin/jobs/{job_id}/cancel", headers=AUTH)
    assert r.status_code == 200 and r.json()["state"] == "cancelled"
    admin.app.state.services.jobs.wait(job_id, 30)
    job = wait_job(admin, job_id)
    assert job["state"] == "cancelled" and job["version"] is None
    versions = settings.models_dir / "versions"
    assert not versions.exists() or not any(versions.iterdir())
    assert [v["version"] for v in admin.get("/api/admin/models", params={"domain": "toy"}, headers=AUTH).json()] == [
        "builtin"]
    r = admin.post(f"/api/admin/jobs/{job_id}/cancel", headers=AUTH)
    assert r.status_code == 409 and "is cancelled already" in r.json()["detail"]
    r = admin.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "preset": "tiny"})  # domain free again
    assert r.status_code == 202
    assert wait_job(admin, r.json()["id"])["state"] == "succeeded"


def test_local_job_learns_page_local_changes(admin):
    """Local changes marked on the page train an RBA-Local version that new local sessions get."""
    r = admin.post("/api/sessions", json={"domain": "toy", "method": "local", "rep": "onehot"})
    assert r.status_code == 422 and "no trained local/onehot models for toy" in r.json()["detail"]
    r = admin.post("/api/admin/attributes", headers=AUTH,
                   json={"domain": "toy", "name": "wobble", "description": "How much the point wobbles."})
    assert r.status_code == 201
    for seed in range(6):
        pair = admin.get("/api/admin/pairs", params={"domain": "toy", "anchor": True, "seed": seed},
                         headers=AUTH).json()["clips"]
        r = admin.post("/api/admin/labels", headers=AUTH, json={"domain": "toy", "local_change": {
            "attribute": "wobble", "anchor": pair[0]["rollout_id"], "changed": pair[1]["rollout_id"],
            "direction": "more" if seed % 2 else "less"}})
        assert r.status_code == 201, r.text
    r = admin.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "method": "local", "preset": "tiny"})
    assert r.status_code == 202, r.text
    job = wait_job(admin, r.json()["id"])
    assert job["state"] == "succeeded", job
    card_pairs = job["held_out"]
    assert "local_reward" in card_pairs
    assert admin.post(f"/api/admin/models/{job['version']}/activate", headers=AUTH).status_code == 200
    listed = admin.get("/api/domains").json()["domains"]
    toy = next(d for d in listed if d["name"] == "toy")
    assert ("local", "onehot") in {(a["method"], a["rep"]) for a in toy["available"]}
    assert [a["name"] for a in toy["attributes"]] == ["amplitude", "pace", "wobble"]  # the trained models', not
    assert "carried over into" in job["log_tail"] and "ranker-onehot.pt" in job["log_tail"]  # the carried ones'
    s = admin.post("/api/sessions", json={"domain": "toy", "method": "local", "rep": "onehot"})
    assert s.status_code == 201, s.text
    assert s.json()["model_set"] == job["version"]
    assert [a["name"] for a in s.json()["attributes"]] == ["amplitude", "pace", "wobble"]
    # the global models that served when the job published came along: activating it kept them serving (the
    # version is a whole model set; they know the attributes they were trained on)
    g = admin.post("/api/sessions", json={"domain": "toy", "method": "global", "rep": "onehot"}).json()
    assert g["model_set"] == job["version"] and [a["name"] for a in g["attributes"]] == ["amplitude", "pace"]


def test_a_version_trained_for_one_method_keeps_the_others_serving(admin, settings):
    """Activating a version trained for RBA-Local sent RBA-Global's new sessions back to the shipped models when a
    retrained global version served them: a version now carries over what served its other methods."""
    r = admin.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "preset": "tiny"})
    first = wait_job(admin, r.json()["id"])["version"]
    assert admin.post(f"/api/admin/models/{first}/activate", headers=AUTH).status_code == 200
    r = admin.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "method": "local", "preset": "tiny"})
    job = wait_job(admin, r.json()["id"])
    assert job["state"] == "succeeded", job
    assert admin.post(f"/api/admin/models/{job['version']}/activate", headers=AUTH).status_code == 200
    g = admin.post("/api/sessions", json={"domain": "toy", "method": "global", "rep": "onehot"}).json()
    assert g["model_set"] == job["version"]
    versions = settings.models_dir / "versions"
    for name in ("ranker-onehot.pt", "global_reward-onehot.json"):  # the first version's global models, as they were
        assert (versions / job["version"] / "toy" / name).read_bytes() == (versions / first / "toy" / name).read_bytes()
    assert f"the other models of {first} carried over into {job['version']}" in job["log_tail"]


def test_failed_job_changes_nothing_served(admin, settings):
    ids = serve_ids(admin, 4)
    ds = upload(admin, None, _ordering(*ids)).json()
    (settings.data_dir / "uploads" / "toy" / f"{ds['id']}.json").unlink()  # the dataset vanished from disk
    r = admin.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "datasets": [ds["id"]], "preset": "tiny"})
    assert r.status_code == 202
    job = wait_job(admin, r.json()["id"])
    assert job["state"] == "failed" and job["version"] is None
    assert job["error"] == f"ValueError: dataset {ds['id']}: its file {ds['id']}.json is missing from " \
                           f"{settings.data_dir / 'uploads' / 'toy'}"
    versions = settings.models_dir / "versions"
    assert not versions.exists() or not any(versions.iterdir())
    s = admin.post("/api/sessions", json={"domain": "toy", "method": "global", "rep": "onehot"}).json()
    assert s["model_set"] == "builtin"


def test_a_training_process_that_cannot_start_is_503_and_frees_the_domain(admin, monkeypatch):
    jobs = admin.app.state.services.jobs

    def refuse(proc) -> None:
        raise OSError("no more processes")

    monkeypatch.setattr(jobs._launcher, "start", refuse)
    r = admin.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "preset": "tiny"})
    assert r.status_code == 503
    assert r.json()["detail"] == ("the training process could not start (OSError: no more processes); "
                                  "the job is marked failed: try again")
    [job] = admin.get("/api/admin/jobs", headers=AUTH).json()
    assert job["state"] == "failed" and "could not start: OSError: no more processes" in job["error"]
    again = admin.post("/api/admin/train", headers=AUTH, json={"domain": "toy", "preset": "tiny"})
    assert again.status_code == 503  # not 409: the failed job holds the domain no more
