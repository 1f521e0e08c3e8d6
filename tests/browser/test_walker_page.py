"""The page in a real browser on the real walker, as a person uses it: answers only about a clip that has played,
meters on the library's scale, the phone layout, keyboard and screen-reader basics (axe-core), the address bar,
and feedback in one's own words. Screenshots go to a temporary folder (benchmarks/screenshots.py writes the
tracked ones)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from rba.data.export_zip import read_export
from server.common.app_settings import Settings
from server.runtime.catalog import Catalog
from tests.browser.conftest import CLIP, PLAYED, PLAYING, axe_violations, new_page

REPO = Path(__file__).resolve().parents[2]
WATCH = """() => {  // what a person saw while waiting: overlay texts, and (dimmed?, clip shown) pairs
  window.seen = { texts: [], dimmed: [] };
  const player = document.getElementById('player'), clip = document.querySelector('#clip .clip-player');
  new MutationObserver(() => window.seen.texts.push(document.getElementById('overlay').innerText))
    .observe(document.getElementById('overlay'), { subtree: true, childList: true, characterData: true });
  new MutationObserver(() => window.seen.dimmed.push([player.classList.contains('waiting'), clip.dataset.rolloutId]))
    .observe(player, { attributes: true, attributeFilter: ['class'] });
}"""

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def url(live_server, tmp_path_factory) -> str:
    tmp = tmp_path_factory.mktemp("walker-page")
    settings = Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp}/rba.db",
                        cache_dir=tmp / "clips", warm_start=False, prerender=True)
    if ("global", "onehot") not in Catalog(settings).available("walker"):
        pytest.skip("walker artifacts are absent: run `rba build walker` and `rba train walker` first "
                    f"(looked for {REPO / 'data' / 'walker'}/serve.* and {REPO / 'models' / 'walker'}/*-onehot.*)")
    return live_server(settings)


def start(page) -> str:
    """Start a walker session from the welcome card; the first clip's rollout id once it plays."""
    page.get_by_role("button", name="Start tuning").click()
    page.wait_for_function(PLAYING, arg="", timeout=90_000)  # the first clip renders on request
    return page.eval_on_selector(CLIP, "p => p.dataset.rolloutId")


def feedback_posts(page) -> list[dict]:
    posts: list[dict] = []
    page.on("request", lambda r: posts.append(json.loads(r.post_data or "{}"))
            if r.method == "POST" and r.url.endswith("/feedback") else None)
    return posts


def test_answers_unlock_once_the_clip_has_played_and_name_that_clip(url, browser, tmp_path):
    page, errors = new_page(browser, url)
    posts = feedback_posts(page)
    more_step = page.get_by_role("button", name="more step size")
    page.evaluate(WATCH)
    page.get_by_role("button", name="Start tuning").click()
    page.wait_for_function("() => document.querySelector('#clip .clip-player').dataset.rolloutId", timeout=90_000)
    assert more_step.get_attribute("aria-disabled") == "true"  # before its first second, nothing can be answered
    assert more_step.is_disabled()  # Playwright reads aria-disabled as a person's assistive technology does
    more_step.click(force=True)  # a person clicks it anyway
    page.keyboard.press("1")
    page.wait_for_function(PLAYED, timeout=90_000)
    assert posts == []  # neither the click nor the key went through
    first = page.eval_on_selector(CLIP, "p => p.dataset.rolloutId")
    assert more_step.get_attribute("aria-disabled") == "false"

    more_step.focus()
    page.keyboard.press("Enter")
    page.keyboard.press("Enter")  # a second press while the next clip comes: refused, not an answer about it
    page.wait_for_function(PLAYING, arg=first, timeout=90_000)
    focused = page.evaluate("[document.activeElement.dataset.attr, document.activeElement.dataset.dir]")
    assert focused == ["step_size", "more"]  # focus stayed on the button, not on the body
    assert len(posts) == 1 and posts[0]["clip"] == first and posts[0]["step"] == 0
    seen = page.evaluate("window.seen")
    assert any(("Rendering the clip" in t or "Waiting for a free renderer" in t)  # the 1st: an MP4's render,
               or "Loading the clip" in t for t in seen["texts"])  # or its data
    assert any("Choosing a new behaviour" in t for t in seen["texts"])
    assert [True, first] in seen["dimmed"]  # the previous clip stayed, dimmed, while the next one came
    assert more_step.get_attribute("aria-disabled") == "true"  # the new clip has not played its second yet
    page.wait_for_function(PLAYED, timeout=30_000)
    assert more_step.get_attribute("aria-disabled") == "false"

    # meters: the library's range at the ends, softness as a landing speed, the agent's target, the path plot
    measured = page.locator("#measured").inner_text()
    assert "landing speed · lower is softer" in measured and "−" not in measured and "-0." not in measured
    assert re.search(r"\d\.\d\d m/s", measured) and re.search(r"\d\.\d\d m\b", measured)
    assert page.locator("#measured .scale-band").count() == 2 and page.locator("#measured .scale-dot").count() >= 1
    assert page.locator("#path-plots svg").count() == 1 and page.locator("#path-plots circle").count() == 2
    assert "serve-" not in page.locator("main").inner_text().replace(page.locator("#details").inner_text(), "")
    assert page.locator("#announce").inner_text().startswith("Clip 2: step size")  # read out by screen readers
    page.screenshot(path=str(tmp_path / "walker.png"))

    page.reload()  # the session is in the URL and the database: it resumes
    page.wait_for_function(PLAYING, arg="", timeout=60_000)
    second = page.eval_on_selector(CLIP, "p => p.dataset.rolloutId")
    assert second != first and page.locator("#history .hist").count() == 1
    assert not errors, errors
    page.close()


def test_phone_keeps_the_clip_in_view_after_a_tap(url, browser):
    page, errors = new_page(browser, url, 390, 844, touch=True)
    heading = page.locator("#welcome h2").bounding_box()
    card = page.locator("#player").bounding_box()
    assert heading["y"] >= card["y"] and heading["y"] + heading["height"] <= card["y"] + card["height"]  # not cut
    first = start(page)
    page.wait_for_function(PLAYED, timeout=30_000)
    button = page.get_by_role("button", name="more softness")
    button.evaluate("b => b.scrollIntoView({ block: 'center' })")  # as a thumb brings it to mid-screen
    assert page.evaluate("window.scrollY") > 300  # far enough that a clip scrolling along would be gone
    button.tap()
    page.wait_for_function(PLAYING, arg=first, timeout=90_000)
    box = page.locator(CLIP).bounding_box()
    assert box["y"] >= 0 and box["y"] + box["height"] <= 844, box  # the result of the tap is on screen
    button_box = button.bounding_box()  # and the button is still there to tap again, not under the clip
    assert button_box["y"] >= box["y"] + box["height"] and button_box["y"] + button_box["height"] <= 844
    assert page.evaluate("document.documentElement.scrollWidth") <= 390  # nothing overflows sideways
    assert page.locator("#satisfied kbd").is_hidden()  # no key hints on a phone
    page.get_by_label("Domain").select_option("snake")  # long units ("fraction of body length") wrap
    page.get_by_role("button", name="New session").click()
    page.wait_for_function("() => document.querySelector('#measured').textContent.includes('fraction of body')",
                           timeout=90_000)
    assert page.evaluate("document.documentElement.scrollWidth") <= 390
    assert not errors, errors
    page.close()


def test_no_serious_accessibility_violations(url, browser):
    page, errors = new_page(browser, url)
    assert page.locator("h1").count() == 1 and page.locator("h1").is_visible()
    assert axe_violations(page) == []
    start(page)
    page.wait_for_function(PLAYED, timeout=30_000)
    page.wait_for_timeout(400)  # the unlocked buttons' colour transition (0.15 s): axe reads colours mid-way
    assert page.locator("h1").is_visible()
    violations = axe_violations(page)
    assert violations == [], json.dumps(violations, indent=1)
    kbd = page.locator("#satisfied kbd")
    assert kbd.evaluate("k => parseFloat(getComputedStyle(k).fontSize)") >= 12
    assert kbd.evaluate("k => getComputedStyle(k).opacity") == "1"
    page.get_by_role("button", name="more step size").focus()
    ring = page.evaluate("getComputedStyle(document.activeElement).outlineWidth")
    assert ring == "3px"
    assert not errors, errors
    page.close()


def test_the_address_bar_and_the_finished_screen(url, browser, tmp_path):
    page, errors = new_page(browser, url)
    first = start(page)
    one = page.evaluate("location.hash")
    other = page.request.post(f"{url}/api/sessions", data={"domain": "walker", "method": "global", "rep": "onehot"})
    assert other.status == 201
    other_id = other.json()["id"]
    page.evaluate("id => { location.hash = 'session=' + id; }", other_id)  # no reload: hashchange
    page.wait_for_function("id => document.querySelector('#session-meta').textContent.includes(id)", arg=other_id)
    page.evaluate("() => { location.hash = 'session=not-a-session'; }")
    page.wait_for_function("() => !document.getElementById('toast').hidden")
    assert "“not-a-session” in the address is not a session id" in page.locator("#toast-text").inner_text()
    assert page.evaluate("location.hash") == f"#session={other_id}"  # the page stays on the session it shows
    page.evaluate("h => { location.hash = h; }", one)
    page.wait_for_function(PLAYING, arg="", timeout=60_000)
    page.wait_for_function(PLAYED, timeout=30_000)
    assert page.eval_on_selector(CLIP, "p => p.dataset.rolloutId") == first
    page.get_by_role("button", name="less step size").click()  # with the mouse: the button lets go of the focus
    page.wait_for_function(PLAYING, arg=first, timeout=90_000)
    page.wait_for_function(PLAYED, timeout=30_000)
    page.keyboard.press("Enter")  # so Enter is "This is it" (the green button's hint), not "less step size" again
    page.wait_for_selector("#done:not([hidden])")
    assert page.locator("#done-text").inner_text() == "You chose clip 2 after 1 round of feedback."
    assert page.locator("#attributes").is_hidden()  # no dead answer buttons to tab through before the download
    assert page.locator("#step-badge").inner_text() == "✓ Chosen after 1 round"
    assert page.locator("#history-count").inner_text() == "1 round of feedback · chosen"
    link = page.get_by_role("link", name="Download this behaviour (.zip)")  # the finished screen's export
    session_id = one.removeprefix("#session=")
    assert link.is_visible() and link.get_attribute("href") == f"/api/sessions/{session_id}/export"
    with page.expect_download() as download:
        link.click()
    assert download.value.suggested_filename == f"rba-walker-{session_id}.zip"
    download.value.save_as(tmp_path / "export.zip")
    profile = read_export(tmp_path / "export.zip").profile
    assert profile.rollout_id == page.eval_on_selector(CLIP, "p => p.dataset.rolloutId") != first
    assert page.request.get(f"{url}/favicon.ico").status == 200
    assert not errors, errors
    page.close()


def test_back_returns_to_the_session_a_new_one_replaced(url, browser):
    page, errors = new_page(browser, url)
    start(page)
    sessions = [page.evaluate("location.hash")]
    for _ in range(2):  # "New session" twice, as "Tune another" would
        page.get_by_role("button", name="New session").click()
        page.wait_for_function("h => location.hash !== h", arg=sessions[-1])
        sessions.append(page.evaluate("location.hash"))
    page.go_back()
    session_id = sessions[1].removeprefix("#session=")
    page.wait_for_function("id => document.querySelector('#session-meta').textContent.includes(id)", arg=session_id)
    assert page.evaluate("location.hash") == sessions[1]
    assert not errors, errors
    page.close()


def test_a_badly_encoded_address_falls_back_to_the_welcome(url, browser):
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"{url}/#session=%E0%A4%A")  # not valid percent-encoding: decodeURIComponent throws
    page.wait_for_function("() => document.body.dataset.state === 'idle'")
    assert page.locator("#welcome").is_visible() and page.get_by_role("button", name="Start tuning").is_visible()
    assert "“%E0%A4%A” in the address is not a session id" in page.locator("#toast-text").inner_text()
    assert not errors, errors
    page.close()


def test_the_make_new_behaviours_box_is_off_for_a_method_that_cannot(url, browser):
    page, errors = new_page(browser, url)
    box = page.get_by_label("Make new behaviours")
    page.get_by_label("Method").select_option(label="RBA-Global")
    box.check()
    page.get_by_label("Method").select_option(label="RBA-Local")
    assert box.is_disabled() and not box.is_checked()  # not ticked while it cannot apply
    page.get_by_label("Advanced").check()  # the research views are listed apart, behind it
    views = page.locator("#domain optgroup[label='Research views: raw or image states'] option")
    assert "walker raw" in views.all_inner_texts() and "walker" not in views.all_inner_texts()  # listed apart
    page.get_by_label("Method").select_option(label="RBA-Global")
    assert box.is_enabled() and not box.is_checked()  # the server's default again (RBA_GENERATE is off here)
    assert not errors, errors
    page.close()


def test_feedback_in_your_own_words(url, browser):
    """The interpret route is mocked here (its own tests cover it): the page shows what it understood, sends it
    on "yes" as the buttons would, and shows the server's message when nothing was understood."""
    page, errors = new_page(browser, url)
    asked: list[dict] = []

    def interpret(route) -> None:
        body = json.loads(route.request.post_data)
        asked.append(body)
        if "purple" in body["text"]:
            route.fulfill(status=422, content_type="application/json", body=json.dumps(
                {"detail": "I didn't understand that; the attributes are: step size, softness"}))
        else:
            route.fulfill(status=200, content_type="application/json", body=json.dumps(
                {"feedback": [{"attribute": "softness", "direction": "more"}], "confidence": 0.83}))

    page.route("**/api/domains/walker/interpret", interpret)
    posts = feedback_posts(page)
    first = start(page)
    page.wait_for_function(PLAYED, timeout=30_000)
    page.get_by_label("Or say it in your own words").fill("make it purple")
    page.get_by_role("button", name="Interpret").click()
    page.wait_for_selector("#words-error:not([hidden])")
    assert page.locator("#words-error").inner_text() == ("I didn't understand that; "
                                                         "the attributes are: step size, softness")
    page.get_by_label("Or say it in your own words").fill("land more gently")
    page.get_by_label("Or say it in your own words").press("Enter")
    page.wait_for_selector("#words-confirm:not([hidden])")
    assert page.locator("#words-understood").inner_text() == "▲ more softness — right?"
    assert page.locator("#words-error").is_hidden()
    page.get_by_role("button", name="Yes, send it").click()
    page.wait_for_function(PLAYING, arg=first, timeout=90_000)
    assert asked == [{"text": "make it purple"}, {"text": "land more gently"}]
    assert posts == [{"step": 0, "clip": first, "feedback": [{"attribute": "softness", "direction": "more"}]}]
    assert "more softness" in page.locator("#history").inner_text()
    assert page.locator("#words-confirm").is_hidden() and page.locator("#words-text").input_value() == ""
    assert not errors, errors
    page.close()


def test_feedback_in_your_own_words_through_the_real_model(url, browser):
    """Unmocked: the server's sentence model reads a negated antonym, the page shows it, "yes" sends it."""
    page, errors = new_page(browser, url)
    posts = feedback_posts(page)
    first = start(page)
    page.wait_for_function(PLAYED, timeout=30_000)
    page.get_by_label("Or say it in your own words").fill("stomp less")
    page.get_by_role("button", name="Interpret").click()
    page.wait_for_selector("#words-confirm:not([hidden])", timeout=60_000)  # the first sentence loads the model
    assert page.locator("#words-understood").inner_text() == "▲ more softness — right?"
    page.get_by_role("button", name="Yes, send it").click()
    page.wait_for_function(PLAYING, arg=first, timeout=90_000)
    assert posts == [{"step": 0, "clip": first, "feedback": [{"attribute": "softness", "direction": "more"}]}]
    assert not errors, errors
    page.close()


def test_another_domain_in_the_page(live_server, browser, tmp_path):
    """Lane change through the same page: pick it, start, press "more sharpness", a new clip plays."""
    settings = Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp_path}/rba.db",
                        cache_dir=tmp_path / "clips", warm_start=False, prerender=False)
    assert ("global", "onehot") in Catalog(settings).available("lane_change"), "lane_change artifacts are missing"
    page, errors = new_page(browser, live_server(settings))
    assert page.locator("#domain option").count() >= 4  # walker, lane_change, manipulator, snake
    page.select_option("#domain", "lane_change")
    page.select_option("#method", "global/onehot")
    page.get_by_role("button", name="Start tuning").click()
    page.wait_for_function(PLAYING, arg="", timeout=90_000)
    first = page.eval_on_selector(CLIP, "p => p.dataset.rolloutId")
    page.wait_for_function(PLAYED, timeout=30_000)
    page.get_by_role("button", name="more sharpness").click()
    page.wait_for_function(PLAYING, arg=first, timeout=90_000)
    assert "more sharpness" in page.locator("#history").inner_text()
    page.screenshot(path=str(tmp_path / "lane-change.png"))
    assert not errors, errors
    page.close()
