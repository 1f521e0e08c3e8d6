"""The studio page's edges in a real browser on the real walker: the waiting text stays while the previous clip
loops, the picker offers the four domains (research choices behind "Advanced") and one start button, and a
phone shows the clip, the answers, "This is it" and the measured values without scrolling."""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest

from rba.core.methods import get_method
from rba.domains import get_domain
from server.common.app_settings import Settings
from server.runtime.catalog import Catalog
from tests.browser.conftest import CLIP, PLAYED, PLAYING, new_page

REPO = Path(__file__).resolve().parents[2]
OVERLAY_LOG = """() => {  // every change of the overlay's visibility, with the clip the player shows then
  window.overlayLog = [];
  window.loops = [];
  const overlay = document.getElementById('overlay'), clip = document.querySelector('#clip .clip-player');
  new MutationObserver(() => window.overlayLog.push([overlay.classList.contains('hidden'), clip.dataset.rolloutId]))
    .observe(overlay, { attributes: true, attributeFilter: ['class'] });
  let frame = -1;  // a loop starts the clip again: its frame goes back (drawn), or its video seeks (fallback)
  new MutationObserver(() => {
    const f = Number(clip.dataset.frame);
    if (f < frame) window.loops.push(clip.dataset.rolloutId);
    frame = f;
  }).observe(clip, { attributes: true, attributeFilter: ['data-frame'] });
  clip.querySelector('video').addEventListener('seeked', () => window.loops.push(clip.dataset.rolloutId));
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


def start(page) -> str:
    """Start a session with the one start button; the first clip's rollout id once it has played its second."""
    page.get_by_role("button", name="Start tuning").click()
    page.wait_for_function(PLAYING, arg="", timeout=90_000)
    page.wait_for_function(PLAYED, timeout=30_000)
    return page.eval_on_selector(CLIP, "p => p.dataset.rolloutId")


def test_the_waiting_text_stays_until_the_next_clip_plays(url, browser):
    """The answer's response comes late (the previous clip loops meanwhile) and the next clip renders on request:
    the overlay never hides before that clip plays."""
    page, errors = new_page(browser, url)
    first = start(page)
    seconds = page.eval_on_selector(CLIP, "p => Number(p.dataset.duration)")

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


def start_buttons(page):
    return page.get_by_role("button", name=re.compile(r"start|new session", re.IGNORECASE))


def test_the_picker_offers_the_domains_with_their_lines_research_behind_advanced(url, browser):
    """The four domains and their methods, each with its line from GET /api/domains (an option's title, the
    chosen pair's line beside the pickers); "Advanced" reveals the research views and the language variants;
    one start button, before and during a session."""
    page, errors = new_page(browser, url)
    domains = page.eval_on_selector_all("#domain option", "os => os.map((o) => [o.value, o.title])")
    assert [n for n, _ in domains if n != "toy"] == ["walker", "lane_change", "manipulator", "snake"]  # toy: tests'
    assert all(title == get_domain(n).description != "" for n, title in domains)
    assert page.locator("#domain optgroup").count() == 0
    methods = page.eval_on_selector_all("#method option", "os => os.map((o) => [o.value, o.title])")
    assert [m for m, _ in methods] == ["global/onehot", "local/onehot"]
    assert all(title == get_method(m.split("/")[0]).description != "" for m, title in methods)
    about = page.locator("#setup-about").inner_text()
    assert get_domain("walker").description in about and get_method("global").description in about
    assert start_buttons(page).count() == 1 and page.locator("#welcome button").count() == 0

    page.get_by_label("Advanced").check()
    views = page.locator("#domain optgroup[label='Research views: raw or image states'] option")
    assert "walker_raw" in [o.get_attribute("value") for o in views.all()]
    assert all("Research view:" in o.get_attribute("title") for o in views.all())
    assert "global/language" in page.eval_on_selector_all("#method option", "os => os.map((o) => o.value)")
    page.get_by_label("Domain").select_option("walker_raw")
    assert "Research view:" in page.locator("#setup-about").inner_text()
    page.get_by_label("Advanced").uncheck()
    assert page.get_by_label("Domain").input_value() == "walker"  # a hidden choice is not kept
    assert page.locator("#domain optgroup").count() == 0

    start(page)
    assert start_buttons(page).count() == 1 and start_buttons(page).inner_text() == "New session"
    raw = page.request.post(f"{url}/api/sessions", data={"domain": "walker_raw", "method": "global", "rep": "onehot"})
    assert raw.status == 201
    page.evaluate("id => { location.hash = 'session=' + id; }", raw.json()["id"])  # a research session, by address
    page.wait_for_function("() => document.getElementById('domain').value === 'walker_raw'")
    assert page.get_by_label("Advanced").is_checked()
    assert not errors, errors
    page.close()


@pytest.mark.parametrize(("domain", "answer"), [("walker", "more step size"), ("snake", "more speed")])
def test_a_phone_shows_the_clip_the_answers_and_the_values_without_scrolling(url, browser, domain, answer):
    """At 390x844, after an answer (the meters then carry the agent's target and the path plots appear): the clip,
    every answer button, "This is it" and every measured value lie inside the window, the page not scrolled; with
    two attributes and with three (the snake's, one of them in a long unit)."""
    page, errors = new_page(browser, url, 390, 844, touch=True)
    page.get_by_label("Domain").select_option(domain)
    page.get_by_role("button", name="Start tuning").tap()
    page.wait_for_function(PLAYING, arg="", timeout=90_000)
    page.wait_for_function(PLAYED, timeout=30_000)
    first = page.eval_on_selector(CLIP, "p => p.dataset.rolloutId")
    page.get_by_role("button", name=answer).tap()
    page.wait_for_function(PLAYING, arg=first, timeout=90_000)
    page.wait_for_function(PLAYED, timeout=30_000)
    assert page.evaluate("window.scrollY") == 0
    parts = [CLIP, "#attributes .btn-less", "#attributes .btn-more", "#satisfied", "#measured .meter"]
    for selector in parts:
        boxes = [b.bounding_box() for b in page.locator(selector).all()]
        assert boxes, selector
        for box in boxes:
            assert box["x"] >= 0 and box["x"] + box["width"] <= 390, (selector, box)
            assert box["y"] >= 0 and box["y"] + box["height"] <= 844, (selector, box)
    assert page.evaluate("document.documentElement.scrollWidth") <= 390  # nothing overflows sideways
    assert not errors, errors
    page.close()


def test_a_busy_server_is_waited_out_not_shown_as_an_error(url, browser):
    """The server refuses an answer it has no room for (429 with Retry-After, before doing any of its work): the page
    says it is busy, sends the answer again after the wait, and the session goes on."""
    page, errors = new_page(browser, url)
    first = start(page)
    refused: list[str] = []

    def busy_once(route) -> None:
        if refused:
            route.continue_()
            return
        refused.append(route.request.method)
        route.fulfill(status=429, headers={"Retry-After": "1", "Content-Type": "application/json"},
                      body='{"detail": "too many heavy requests from this client at once"}')

    page.route("**/feedback", busy_once)
    page.get_by_role("button", name="more step size").click()
    page.wait_for_function("() => document.getElementById('toast-text').textContent.includes('busy')",
                           timeout=10_000)
    page.wait_for_function(PLAYING, arg=first, timeout=90_000)
    assert refused == ["POST"]
    assert "too many heavy requests" not in page.inner_text("#toast-text")
    assert not errors, errors
    page.close()
