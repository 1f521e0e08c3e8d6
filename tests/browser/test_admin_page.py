"""The admin page in a real browser: the token, labelling only about clips both seen, the upload form's problems,
WCAG AA by axe-core, and the API docs without a network. Screenshots go to the test's temporary folder."""

from __future__ import annotations

import datetime as dt
import io
import json
import re
import shutil
from pathlib import Path
from urllib.parse import urlparse

import httpx
import numpy as np
import pytest
from playwright.sync_api import expect
from sqlalchemy import create_engine
from sqlmodel import Session

from server.common.app_settings import Settings
from server.db.admin_tables import ModelVersion, TrainJob
from tests.browser.conftest import axe_violations

REPO = Path(__file__).resolve().parents[2]
TOKEN = "browser-admin-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
CLIPS_PLAYING = """() => {
  const p = [...document.querySelectorAll('#pair .clip-player')];
  return p.length === 2 && p.every((x) => x.dataset.ready === 'true' && (x.dataset.mode === 'video'
    ? x.querySelector('video').readyState >= 3 && x.querySelector('video').currentTime > 0.2 : x.dataset.frame > 3));
}"""
BOTH_SEEN = "() => document.getElementById('right-more').getAttribute('aria-disabled') === 'false'"

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def url(live_server, tmp_path_factory) -> str:
    tmp = tmp_path_factory.mktemp("admin")
    return live_server(Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp}/rba.db",
                                cache_dir=tmp / "clips", warm_start=False, prerender=False, admin_token=TOKEN))


@pytest.fixture
def page(browser):
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    yield page
    assert not errors, errors
    page.close()


def unlock(page, url: str) -> None:
    page.goto(f"{url}/admin")
    page.fill("#token", TOKEN)
    page.get_by_role("button", name="Unlock").click()
    page.wait_for_function("() => document.querySelectorAll('#pair .clip-player').length === 2", timeout=30_000)


def labels(url: str) -> list[dict]:
    r = httpx.get(f"{url}/api/admin/labels", params={"domain": "walker"}, headers=AUTH)
    assert r.status_code == 200, r.text
    return r.json()


def test_a_wrong_token_is_refused(url, page):
    page.goto(f"{url}/admin")
    page.fill("#token", "not-the-token")
    page.get_by_role("button", name="Unlock").click()
    page.wait_for_function("() => !document.getElementById('toast').hidden")
    assert "wrong admin token" in page.locator("#toast").inner_text()
    assert page.locator("#admin").is_hidden()


def test_answers_wait_until_both_clips_played_and_focus_stays(url, page, tmp_path):
    unlock(page, url)
    assert page.locator("#toast").is_hidden()
    # the clips render on request, then must play a second: until then neither buttons nor keys save anything
    for name in ("left-more", "right-more", "skip"):
        assert page.locator(f"#{name}").get_attribute("aria-disabled") == "true"
    shown_first = page.eval_on_selector_all("#pair figcaption", "c => c.map((x) => x.textContent)")
    page.locator("#right-more").click(force=True)  # Playwright would wait for it to be enabled; a person doesn't
    page.keyboard.press("ArrowLeft")
    page.keyboard.press("ArrowDown")
    assert "Watch both clips" in page.locator("#watch-status").inner_text()
    assert page.eval_on_selector_all("#pair figcaption", "c => c.map((x) => x.textContent)") == shown_first
    assert page.evaluate("() => [...document.querySelectorAll('#pair .clip-player')].some((p) => !p.dataset.played)")

    page.wait_for_function(BOTH_SEEN, timeout=90_000)
    assert page.evaluate("() => [...document.querySelectorAll('#pair .clip-player')].every((p) => p.dataset.played)")
    assert labels(url) == []  # the early press, ← and ↓ did nothing
    assert page.locator("#attribute").input_value() == "step_size"
    methods = page.eval_on_selector_all("#train-method option", "o => o.map((x) => [x.value, x.textContent])")
    assert methods == [["global", "RBA-Global"], ["local", "RBA-Local"]]  # from the server's method registry
    assert page.eval_on_selector_all("#preset option", "o => o.map((x) => x.value)") == ["default", "pairwise", "quick",
                                                                                     "tiny"]
    # the key hints show beside the labels the script sets
    assert [page.locator(f"#{b} kbd").inner_text() for b in ("left-more", "skip", "right-more")] == ["←", "↓", "→"]
    assert page.locator("#skip").evaluate("b => getComputedStyle(b).borderTopWidth") == "1px"  # looks like a button

    shown = page.eval_on_selector_all("#pair figcaption", "c => c.map((x) => x.textContent.split(' · ')[1])")
    page.locator("#right-more").focus()
    page.keyboard.press("Enter")
    page.wait_for_function("() => document.getElementById('label-count').textContent.includes('1 saved')")
    assert [(x["kind"], x["attribute"], x["payload"]["more"], x["payload"]["less"]) for x in labels(url)] == [
        ("comparison", "step_size", shown[1], shown[0])]
    assert page.evaluate("() => document.activeElement.id") == "right-more"  # focus did not fall to the body
    # the next pair locks the answers again (a clip needs a second of play, so this runs well within it)
    assert page.locator("#right-more").get_attribute("aria-disabled") == "true"
    page.keyboard.press("ArrowLeft")  # ignored
    page.wait_for_function(BOTH_SEEN, timeout=90_000)
    assert len(labels(url)) == 1
    page.keyboard.press("ArrowLeft")
    page.wait_for_function("() => document.getElementById('label-count').textContent.includes('2 saved')")
    assert len(labels(url)) == 2
    page.wait_for_function(BOTH_SEEN, timeout=90_000)
    page.locator("#pair .clip-player").first.locator(".cp-play:visible, video:visible").first.focus()  # ← → step
    assert page.evaluate("() => Boolean(document.activeElement.closest('.clip-player'))")  # frames: no label
    page.keyboard.press("ArrowLeft")
    page.wait_for_timeout(500)
    assert len(labels(url)) == 2
    assert "serving new sessions" in page.locator("#versions").inner_text()
    page.screenshot(path=str(tmp_path / "admin.png"), full_page=True)


def _npz(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def test_upload_form_shows_the_problems_of_each_file(url, page):
    unlock(page, url)
    bad_labels = {"orderings": [{"attribute": "step_size", "clips": ["mine_0", "no-such-clip"]}]}
    bad_npz = _npz(mine_0=np.zeros((12, 3), np.float32))  # walker states are wider than 3
    page.set_input_files("#upload-labels", {"name": "my-labels.json", "mimeType": "application/json",
                                            "buffer": json.dumps(bad_labels).encode()})
    page.set_input_files("#upload-npz", {"name": "my-walks.npz", "mimeType": "application/octet-stream",
                                         "buffer": bad_npz})
    page.get_by_role("button", name=re.compile("Upload to walker")).click()
    result = page.locator("#upload-result")
    result.locator(".refused").wait_for()
    text = result.inner_text()
    assert "Refused: nothing was stored" in text
    groups = page.eval_on_selector_all("#upload-result .file-problems", """g => g.map((x) => [
        x.querySelector('strong').textContent, [...x.querySelectorAll('li')].map((li) => li.textContent)])""")
    assert [name for name, _ in groups] == ["my-labels.json", "my-walks.npz"]
    npz_problems = dict(groups)["my-walks.npz"]
    assert any("trajectory 'mine_0': shape [12, 3], expected [T," in p for p in npz_problems), npz_problems
    r = httpx.get(f"{url}/api/admin/datasets", params={"domain": "walker"}, headers=AUTH)
    assert r.status_code == 200 and r.json() == []

    page.set_input_files("#upload-labels", {"name": "broken.json", "mimeType": "application/json", "buffer": b"{oops"})
    page.set_input_files("#upload-npz", [])
    page.get_by_role("button", name=re.compile("Upload to walker")).click()
    page.wait_for_function("() => document.querySelector('#upload-result strong')?.textContent === 'broken.json'")
    assert "labels: not UTF-8 JSON" in result.inner_text()


def test_axe_finds_no_serious_violation_on_the_admin_page(url, page):
    page.goto(f"{url}/admin")
    assert axe_violations(page) == []  # locked
    unlock(page, url)
    page.wait_for_function(CLIPS_PLAYING, timeout=90_000)
    page.wait_for_function("() => document.querySelectorAll('#versions li').length > 0")
    assert axe_violations(page) == []  # unlocked, with the clips, the forms and the versions
    page.locator("#skip").focus()
    page.keyboard.press("Tab")  # focus moved by the keyboard: the ring must show
    assert page.evaluate("() => document.activeElement.id") == "right-more"
    ring = page.locator("#right-more").evaluate(
        "b => { const s = getComputedStyle(b); return [s.outlineStyle, s.outlineWidth, s.outlineColor]; }")
    assert ring == ["solid", "3px", "rgb(55, 48, 163)"]  # 3 px of #3730a3: 10:1 on white
    assert page.locator("h1").inner_text() == "RBA Studio admin"


@pytest.mark.parametrize(("path", "shown"), [("/docs", ".opblock"), ("/redoc", "[data-section-id^='tag/admin']")])
def test_api_docs_render_offline(url, page, path, shown):
    blocked: list[str] = []

    def only_local(route) -> None:
        if urlparse(route.request.url).hostname in ("127.0.0.1", "localhost"):
            route.continue_()
        else:
            blocked.append(route.request.url)
            route.abort()

    page.route("**/*", only_local)
    page.goto(f"{url}{path}")
    page.locator(shown).first.wait_for(timeout=30_000)
    text = page.locator("body").inner_text()
    assert "/api/admin/datasets" in text and "/api/sessions" in text
    # ReDoc's sidebar asks for Redocly's logo and hides it when it fails; nothing else is asked of another host
    assert [u for u in blocked if u != "https://cdn.redoc.ly/redoc/logo-mini.svg"] == []
    if path == "/docs":
        assert page.locator(".opblock").count() >= 15  # every operation listed


def _worse_version(models, db_url: str) -> None:
    """A published walker version that is worse on test and has an attribute no held-out pair measures."""
    folder = models / "versions" / "walker-worse" / "walker"
    folder.mkdir(parents=True)
    for kind in ("ranker", "global_reward"):
        for suffix in (".pt", ".json"):
            shutil.copy(models / "walker" / f"{kind}-onehot{suffix}", folder)
    ranker = json.loads((folder / "ranker-onehot.json").read_text())
    ranker["attributes"].append({"name": "foot_lift", "description": "How high the feet lift.", "unit": "m"})
    ranker["held_out"]["foot_lift"] = {"held_out_pair_accuracy": None, "held_out_pairs": 0}
    (folder / "ranker-onehot.json").write_text(json.dumps(ranker))
    reward = json.loads((folder / "global_reward-onehot.json").read_text())
    reward["held_out"]["argmax_within_epsilon"] = 0.37
    (folder / "global_reward-onehot.json").write_text(json.dumps(reward))
    now = dt.datetime.now(dt.UTC)
    engine = create_engine(db_url)
    with Session(engine) as db:
        db.add(ModelVersion(version="walker-worse", domain="walker", method="global", rep="onehot", job_id="0" * 32,
                            attributes=["step_size", "softness", "foot_lift"], held_out={}))
        db.add(TrainJob(domain="walker", method="global", rep="onehot", preset="default", datasets=[], state="running",
                        stage="global_reward[onehot]", step=500, total=1000, created_at=now - dt.timedelta(seconds=100),
                        updated_at=now, heartbeat_at=now, stages=[  # ζσ done, rθ half done at 0.1 s a step
                            {"stage": "ranker[onehot]", "total": 800, "first_step": 1, "first_at": 5.0, "step": 800,
                             "at": 50.0},
                            {"stage": "global_reward[onehot]", "total": 1000, "first_step": 1, "first_at": 51.0,
                             "step": 500, "at": 100.9}]))
        db.commit()
    engine.dispose()


def test_activating_a_worse_version_asks_first_and_the_intro_follows(live_server, page, tmp_path):
    models = tmp_path / "models"
    shutil.copytree(REPO / "models", models, ignore=shutil.ignore_patterns("versions"))
    db_url = f"sqlite:///{tmp_path}/rba.db"
    url = live_server(Settings(data_dir=REPO / "data", models_dir=models, database_url=db_url, cache_dir=tmp_path / "c",
                               warm_start=False, prerender=False, admin_token=TOKEN))
    _worse_version(models, db_url)
    unlock(page, url)
    page.wait_for_function("() => document.querySelectorAll('#versions li').length === 2")
    # one bar for the whole job, as the API weighs it; the time left from rθ's rate: 500 steps at 0.1 s and measuring
    job = httpx.get(f"{url}/api/admin/jobs", params={"domain": "walker"}, headers=AUTH).json()[0]
    done = round(100 * job["progress"])
    assert 40 < done < 100 and 0 < job["eta_seconds"] < 60, job  # 500 steps at 0.1 s, less the time since
    assert page.locator("#progress").get_attribute("aria-valuenow") == str(done)
    assert re.search(rf"{done} % done · about \d+ (s|min) left · global_reward\[onehot\] step 500/1000",
                     page.locator("#job-detail").inner_text())
    worse = page.locator("#versions li", has_text="walker-worse")
    assert "serving now: builtin" in worse.inner_text()
    assert page.eval_on_selector_all("#versions li:nth-child(2) tr.worse th", "t => t.map((x) => x.textContent)") == [
        "pair accuracy · foot lift", "argmax within ε"]
    page.get_by_role("button", name="Activate walker-worse").click()
    dialog = page.locator("#confirm")
    dialog.wait_for()
    shipped = json.loads((REPO / "models" / "walker" / "global_reward-onehot.json").read_text())["held_out"]
    assert f"argmax within ε: 0.370, below {shipped['argmax_within_epsilon']:.3f} of builtin" in dialog.inner_text()
    assert "pair accuracy · foot lift: untested (no held-out pairs)" in dialog.inner_text()
    page.screenshot(path=str(tmp_path / "admin-confirm.png"))
    page.get_by_role("button", name="Keep the current one").click()
    assert dialog.is_hidden()
    assert page.evaluate("() => document.activeElement.textContent") == "Activate"  # back where it was
    assert "✓ serving" in page.locator("#versions li:nth-child(1)").inner_text()  # builtin still serves

    page.get_by_role("button", name="Activate walker-worse").click()
    page.get_by_role("button", name="Activate anyway").click()
    page.wait_for_function("() => document.querySelector('#versions li:nth-child(2) .serving') !== null")
    assert "foot lift" in page.locator("#toast").inner_text()
    page.goto(url)  # the user page's intro lists the active version's attributes
    page.wait_for_function("() => document.body.innerText.includes('foot lift')", timeout=15_000)


def _running_job(db_url: str, domain: str = "walker") -> str:
    """A running job's row as its process would leave it (no process: cancelling it only marks the row)."""
    now = dt.datetime.now(dt.UTC)
    engine = create_engine(db_url)
    with Session(engine) as db:
        job = TrainJob(domain=domain, busy_domain=domain, method="global", rep="onehot", preset="tiny", datasets=[],
                       state="running", stage="ranker[onehot]", step=50, total=200, created_at=now, updated_at=now,
                       heartbeat_at=now)
        db.add(job)
        db.commit()
        job_id = job.id
    engine.dispose()
    return job_id


@pytest.fixture
def own_server(live_server, tmp_path) -> tuple[str, str]:
    """(URL, database URL) of a server with a database of its own (its jobs are this test's)."""
    db_url = f"sqlite:///{tmp_path}/rba.db"
    url = live_server(Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=db_url,
                               cache_dir=tmp_path / "c", warm_start=False, prerender=False, admin_token=TOKEN))
    return url, db_url


def test_cancelling_a_job_asks_first(own_server, page, tmp_path):
    url, db_url = own_server
    httpx.get(f"{url}/api/admin/jobs", headers=AUTH).raise_for_status()  # the app made its tables
    job_id = _running_job(db_url)
    unlock(page, url)
    page.get_by_role("button", name="Cancel").wait_for()
    page.get_by_role("button", name="Cancel").click()
    dialog = page.get_by_role("dialog", name="Stop this training job?")
    dialog.wait_for()
    assert "nothing it made" in dialog.inner_text()
    assert page.evaluate("() => document.activeElement.textContent") == "Keep training"  # the safe choice
    assert axe_violations(page) == []
    page.screenshot(path=str(tmp_path / "admin-confirm-cancel.png"))
    page.keyboard.press("Escape")  # as "Keep training"
    assert dialog.is_hidden()
    assert page.evaluate("() => document.activeElement.id") == "cancel"
    page.get_by_role("button", name="Cancel").click()
    page.get_by_role("button", name="Keep training").click()
    state = httpx.get(f"{url}/api/admin/jobs/{job_id}", headers=AUTH).json()["state"]
    assert state == "running"  # two refusals stopped nothing

    page.get_by_role("button", name="Cancel").click()
    page.get_by_role("button", name="Stop the job").click()
    page.wait_for_function("() => document.getElementById('job-status').textContent.includes('cancelled')")
    assert httpx.get(f"{url}/api/admin/jobs/{job_id}", headers=AUTH).json()["state"] == "cancelled"


def test_lock_forgets_the_token_and_shows_the_token_form(url, page):
    unlock(page, url)
    assert page.evaluate("() => sessionStorage.getItem('rba-admin-token')") == TOKEN
    page.get_by_role("button", name="Lock").click()
    assert page.locator("#admin").is_hidden() and page.locator("#login").is_visible()
    assert page.evaluate("() => sessionStorage.getItem('rba-admin-token')") is None
    assert page.evaluate("() => document.activeElement.id") == "token"
    assert page.locator("#pair .clip-player").count() == 0
    page.reload()  # nothing remembered: the form again, not the panels
    page.locator("#login").wait_for()
    assert page.locator("#admin").is_hidden() and page.locator("#token").input_value() == ""
    unlock(page, url)  # the same tab unlocks again
    assert page.get_by_role("button", name="Lock").is_visible()


def test_the_upload_form_explains_the_format_and_lists_every_problem(url, page, tmp_path):
    unlock(page, url)
    assert "A JSON object with any of these four lists" in page.locator("#label-format").inner_text()
    with page.expect_download() as got:
        page.get_by_role("button", name="Download an example for walker").click()
    example = tmp_path / "example.json"
    got.value.save_as(example)
    assert got.value.suggested_filename == "labels-example-walker.json"
    assert set(json.loads(example.read_text())) == {"new_attributes", "orderings", "comparisons", "local_changes"}

    ids = [c["rollout_id"] for c in httpx.get(f"{url}/api/admin/pairs", params={"domain": "walker"},
                                             headers=AUTH).json()["clips"]]
    broken = {"comparisons": [{"attribute": "step_size", "mroe": ids[0], "less": ids[1]},
                              {"attribute": "zest", "more": ids[0], "less": ids[1]}],
              "orderings": [{"attribute": "softness", "clips": [ids[0], "ghost"]}]}
    page.set_input_files("#upload-labels", {"name": "broken.json", "mimeType": "application/json",
                                            "buffer": json.dumps(broken).encode()})
    page.get_by_role("button", name=re.compile("Upload to walker")).click()
    page.locator("#upload-result .refused").wait_for()
    shown = page.eval_on_selector_all("#upload-result li", "l => l.map((x) => x.textContent)")
    assert any("unknown key 'mroe'" in p for p in shown), shown
    assert any("unknown attribute 'zest'" in p for p in shown), shown
    assert any("clip 'ghost'" in p for p in shown), shown
    assert axe_violations(page) == []

    page.set_input_files("#upload-labels", str(example))  # the example as downloaded is accepted
    page.get_by_role("button", name=re.compile("Upload to walker")).click()
    page.locator("#upload-result .stored").wait_for()
    assert "4 labels" in page.locator("#upload-result").inner_text()


def test_presets_are_described_with_their_typical_duration(url, page):
    unlock(page, url)
    # The presets' descriptions arrive after the unlock: expect() waits for them.
    page.select_option("#preset", "tiny")
    expect(page.locator("#preset-about")).to_have_text(re.compile(r"^tiny: a smoke run.*on 2 CPU cores"))
    page.select_option("#preset", "default")
    expect(page.locator("#preset-about")).to_contain_text("the shipped models' size")
    assert page.locator("#preset").get_attribute("aria-describedby") == "preset-about"
