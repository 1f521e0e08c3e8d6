"""The page in a real browser on the real walker: start a session, press "more step size", see the new clip play."""

from __future__ import annotations

from pathlib import Path

import pytest

from server.catalog import Catalog
from server.settings import Settings

REPO = Path(__file__).resolve().parents[2]
RESULTS = REPO / "benchmarks" / "results"
PLAYING = """(previous) => {
  const v = document.getElementById('video');
  return v.dataset.rollout && v.dataset.rollout !== previous && v.readyState >= 3 && v.currentTime > 0.25;
}"""

pytestmark = pytest.mark.slow


def current_time(page) -> float:
    return page.eval_on_selector("#video", "v => v.currentTime")


def test_more_step_size_shows_a_new_clip(live_server, browser, tmp_path):
    settings = Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp_path}/rba.db",
                        cache_dir=tmp_path / "clips", warm_start=False, prerender=True)
    if ("global", "onehot") not in Catalog(settings).available("walker"):
        pytest.skip("walker artifacts are absent: run `rba build walker` and `rba train walker` first "
                    f"(looked for {REPO / 'data' / 'walker'}/serve.* and {REPO / 'models' / 'walker'}/*-onehot.*)")
    url = live_server(settings)
    page = browser.new_page(viewport={"width": 1280, "height": 800})  # a laptop
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))

    page.goto(url)
    page.wait_for_function("() => document.body.dataset.state === 'idle'")
    assert page.locator("#domain").input_value() == "walker"
    assert page.locator("#method").input_value() == "global/onehot"
    page.get_by_role("button", name="Start tuning").click()
    page.wait_for_function(PLAYING, arg="", timeout=90_000)  # the first clip renders on request
    first = page.eval_on_selector("#video", "v => v.dataset.rollout")
    assert page.get_by_role("button", name="less softness").is_enabled()

    page.get_by_role("button", name="more step size").click()
    page.wait_for_function(PLAYING, arg=first, timeout=90_000)
    t0 = current_time(page)
    page.wait_for_timeout(700)
    assert current_time(page) != t0  # it plays (and loops), not a still frame
    second = page.eval_on_selector("#video", "v => v.dataset.rollout")
    assert second != first
    assert "more step size" in page.locator("#history").inner_text()
    assert page.locator("#measured").inner_text().count("m") >= 1
    assert page.locator("#history .hist").count() == 1
    page.wait_for_timeout(600)  # let the history thumbnail load its frame
    RESULTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(RESULTS / "screenshot-walker.png"))

    page.set_viewport_size({"width": 390, "height": 844})  # a phone
    page.wait_for_timeout(300)
    assert page.evaluate("document.documentElement.scrollWidth") <= 390  # nothing overflows sideways
    page.screenshot(path=str(RESULTS / "screenshot-walker-phone.png"), full_page=True)

    page.reload()  # the session is in the URL and the database: it resumes
    page.wait_for_function(PLAYING, arg="", timeout=60_000)
    assert page.eval_on_selector("#video", "v => v.dataset.rollout") == second
    assert not errors, errors
    page.close()


def test_another_domain_in_the_page(live_server, browser, tmp_path):
    """Lane change through the same page: pick it, start, press "more sharpness", a new clip plays."""
    settings = Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp_path}/rba.db",
                        cache_dir=tmp_path / "clips", warm_start=False, prerender=False)
    assert ("global", "onehot") in Catalog(settings).available("lane_change"), "lane_change artifacts are missing"
    url = live_server(settings)
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    page.wait_for_function("() => document.body.dataset.state === 'idle'")
    assert page.locator("#domain option").count() >= 4  # walker, lane_change, manipulator, snake
    page.select_option("#domain", "lane_change")
    page.select_option("#method", "global/onehot")
    page.get_by_role("button", name="New session").click()
    page.wait_for_function(PLAYING, arg="", timeout=90_000)
    first = page.eval_on_selector("#video", "v => v.dataset.rollout")
    page.get_by_role("button", name="more sharpness").click()
    page.wait_for_function(PLAYING, arg=first, timeout=90_000)
    assert "more sharpness" in page.locator("#history").inner_text()
    page.screenshot(path=str(RESULTS / "screenshot-lane-change.png"))
    assert not errors, errors
    page.close()
