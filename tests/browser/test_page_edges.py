"""The studio page's edges in a real browser on the real walker: the waiting text stays while the previous clip
loops, the picker offers the four domains (research choices behind "Advanced") and one start button, and a
phone shows the clip, the answers, "This is it" and the measured values without scrolling."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from server.common.app_settings import Settings
from server.runtime.catalog import Catalog
from tests.browser.conftest import PLAYED, PLAYING

REPO = Path(__file__).resolve().parents[2]
OVERLAY_LOG = """() => {  // every change of the overlay's visibility, with the clip the video shows then
  window.overlayLog = [];
  window.loops = [];
  const overlay = document.getElementById('overlay'), video = document.getElementById('video');
  new MutationObserver(() => window.overlayLog.push([overlay.classList.contains('hidden'), video.dataset.rollout]))
    .observe(overlay, { attributes: true, attributeFilter: ['class'] });
  video.addEventListener('seeked', () => window.loops.push(video.dataset.rollout));  // a loop seeks to the start
}"""

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def url(live_server, tmp_path_factory) -> str:
    tmp = tmp_path_factory.mktemp("page-edges")
    settings = Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp}/rba.db",
                        cache_dir=tmp / "clips", warm_start=False, prerender=False)
    if ("global", "onehot") not in Catalog(settings).available("walker"):
        pytest.skip("walker artifacts are absent: run `rba build walker` and `rba train walker` first")
    return live_server(settings)


def new_page(browser, url: str, width: int = 1280, height: int = 800, touch: bool = False):
    page = browser.new_page(viewport={"width": width, "height": height}, has_touch=touch, is_mobile=touch)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    page.wait_for_function("() => document.body.dataset.state === 'idle'")
    return page, errors


def start(page) -> str:
    """Start a session with the one start button; the first clip's rollout id once it has played its second."""
    page.get_by_role("button", name="Start tuning").click()
    page.wait_for_function(PLAYING, arg="", timeout=90_000)
    page.wait_for_function(PLAYED, timeout=30_000)
    return page.eval_on_selector("#video", "v => v.dataset.rollout")


def test_the_waiting_text_stays_until_the_next_clip_plays(url, browser):
    """The answer's response comes late (the previous clip loops meanwhile) and the next clip renders on request:
    the overlay never hides before that clip plays."""
    page, errors = new_page(browser, url)
    first = start(page)
    seconds = page.eval_on_selector("#video", "v => v.duration")

    def late(route) -> None:
        time.sleep(seconds + 1.5)  # the browser runs on: the previous clip loops at least once
        route.continue_()

    page.route("**/feedback", late)
    page.evaluate(OVERLAY_LOG)
    page.get_by_role("button", name="more step size").click()
    page.wait_for_function(PLAYING, arg=first, timeout=90_000)
    log, loops = page.evaluate("[window.overlayLog, window.loops]")
    assert first in loops  # the previous clip looped while the page waited
    assert log[0] == [False, first]  # shown at the answer
    hidden = [rollout for is_hidden, rollout in log if is_hidden]
    assert hidden and first not in hidden, log  # hidden only once the next clip is in the video
    assert not errors, errors
    page.close()
