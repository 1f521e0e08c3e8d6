"""The admin page in a real browser: a wrong token is refused; the right one unlocks it; a label is saved at once."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from server.settings import Settings

REPO = Path(__file__).resolve().parents[2]
RESULTS = REPO / "benchmarks" / "results"
TOKEN = "browser-admin-token"
CLIPS_PLAYING = """() => {
  const v = [...document.querySelectorAll('#pair video')];
  return v.length === 2 && v.every((x) => x.readyState >= 3 && x.currentTime > 0.2);
}"""

pytestmark = pytest.mark.slow


def test_admin_labels_a_pair(live_server, browser, tmp_path):
    settings = Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp_path}/rba.db",
                        cache_dir=tmp_path / "clips", warm_start=False, prerender=False, admin_token=TOKEN)
    url = live_server(settings)
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))

    page.goto(f"{url}/admin")
    page.fill("#token", "not-the-token")
    page.get_by_role("button", name="Unlock").click()
    page.wait_for_function("() => !document.getElementById('toast').hidden")
    assert "wrong admin token" in page.locator("#toast").inner_text()
    assert page.locator("#admin").is_hidden()

    page.fill("#token", TOKEN)
    page.get_by_role("button", name="Unlock").click()
    page.wait_for_function(CLIPS_PLAYING, timeout=90_000)  # both clips render on request
    assert page.locator("#attribute").input_value() == "step_size"
    assert page.locator("#toast").is_hidden()  # the refused token's message went with the unlock
    methods = page.eval_on_selector_all("#train-method option", "o => o.map((x) => [x.value, x.textContent])")
    assert methods == [["global", "RBA-Global"], ["local", "RBA-Local"]]  # from the server's method registry
    assert page.eval_on_selector_all("#preset option", "o => o.map((x) => x.value)") == ["default", "quick", "tiny"]
    shown = page.eval_on_selector_all("#pair figcaption", "c => c.map((x) => x.textContent.split(' · ')[1])")
    page.get_by_role("button", name="Right has more").click()
    page.wait_for_function("() => document.getElementById('label-count').textContent.includes('1 saved')")

    labels = httpx.get(f"{url}/api/admin/labels", params={"domain": "walker"},
                       headers={"Authorization": f"Bearer {TOKEN}"}).json()
    assert [(x["kind"], x["attribute"], x["payload"]["more"], x["payload"]["less"]) for x in labels] == [
        ("comparison", "step_size", shown[1], shown[0])]
    page.wait_for_function(CLIPS_PLAYING, timeout=90_000)  # the next pair
    assert page.locator("#versions li").count() >= 1  # builtin, active
    assert "serving new sessions" in page.locator("#versions").inner_text()
    RESULTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(RESULTS / "screenshot-admin.png"), full_page=True)
    assert not errors, errors
    page.close()
