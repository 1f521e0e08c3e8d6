"""Feedback in one's own words in a real browser on the walker: the domain's examples, the "Reading…" state with
Interpret and Enter locked while the server reads (the request is held by the test, so no timing decides), the
reading it answers, an error, and two readings to choose from when the server is unsure."""

from __future__ import annotations

import json

import pytest

from tests.browser.conftest import CLIP, PLAYED, PLAYING, axe_violations, new_page
from tests.browser.test_walker_page import feedback_posts, url  # noqa: F401 (url: the walker server)

pytestmark = pytest.mark.slow
INTERPRET = "**/api/domains/walker/interpret"
READING = "() => document.getElementById('words-status').textContent === 'Reading…'"
UNSURE = {"feedback": [{"attribute": "softness", "direction": "more"}], "confidence": 0.45, "low_confidence": True,
          "alternatives": [[{"attribute": "softness", "direction": "more"}],
                           [{"attribute": "softness", "direction": "less"}]]}


def held_requests(page) -> list:
    """Hold every interpret request until the test answers it (``route.continue_()`` or ``route.fulfill``)."""
    held: list = []
    page.route(INTERPRET, lambda route: held.append(route))
    return held


def start_session(page) -> None:
    page.get_by_role("button", name="Start tuning").click()
    page.wait_for_selector("#words:not([hidden])", timeout=90_000)


def test_reading_shows_and_locks_until_the_server_answers(url, browser):  # noqa: F811
    page, errors = new_page(browser, url)
    held = held_requests(page)
    start_session(page)
    box, go = page.get_by_label("Or say it in your own words"), page.get_by_role("button", name="Interpret")
    assert box.get_attribute("placeholder") == "e.g. shorter steps"  # the walker's own, not another domain's
    assert page.locator(".words-example").all_inner_texts() == ["shorter steps", "soft landings"]
    assert page.get_by_role("status").filter(has_text="Reading").count() == 0

    box.fill("softer landings please")
    box.press("Enter")
    page.wait_for_function(READING)
    assert page.locator("#words").get_attribute("aria-busy") == "true"
    assert go.get_attribute("aria-disabled") == "true"
    assert page.locator("#words-status").get_attribute("role") == "status"  # announced by screen readers
    go.click(force=True)  # a person presses again, with the mouse and with Enter
    box.press("Enter")
    held[0].continue_()  # the real server reads it (the first sentence loads the model: no warm start here)
    page.wait_for_selector("#words-confirm:not([hidden])", timeout=120_000)
    assert page.locator("#words-understood").inner_text() == "▲ more softness — right?"
    assert page.locator("#words").get_attribute("aria-busy") == "false"
    assert go.get_attribute("aria-disabled") == "false" and page.locator("#words-status").inner_text() == ""
    assert len(held) == 1  # the presses while it read sent nothing

    page.locator(".words-example", has_text="soft landings").click()  # an example reads itself
    page.wait_for_function(READING)
    assert box.input_value() == "soft landings" and page.locator("#words-confirm").is_hidden()
    held[1].fulfill(status=422, content_type="application/json", body=json.dumps(
        {"detail": "I didn't understand that; the attributes are: step size, softness"}))
    page.wait_for_selector("#words-error:not([hidden])")
    assert page.locator("#words-error").inner_text().startswith("I didn't understand that")
    assert go.get_attribute("aria-disabled") == "false" and page.locator("#words").get_attribute("aria-busy") == "false"
    assert not errors, errors
    page.close()


def test_an_unsure_reading_offers_two_to_choose_from(url, browser):  # noqa: F811
    page, errors = new_page(browser, url)
    page.route(INTERPRET, lambda route: route.fulfill(status=200, content_type="application/json",
                                                       body=json.dumps(UNSURE)))
    posts = feedback_posts(page)
    start_session(page)
    page.wait_for_function(PLAYING, arg="", timeout=90_000)
    first = page.eval_on_selector(CLIP, "p => p.dataset.rolloutId")
    page.wait_for_function(PLAYED, timeout=30_000)
    page.get_by_label("Or say it in your own words").fill("make the landings different")
    page.get_by_role("button", name="Interpret").click()
    page.wait_for_selector("#words-choices:not([hidden])")
    assert page.locator("#words-understood").inner_text() == "Not sure what you meant. Which one?"
    assert page.locator("#words-choices button").all_inner_texts() == ["▲ more softness", "▼ less softness", "Neither"]
    assert page.locator("#words-yes").is_hidden()
    assert axe_violations(page) == []
    page.get_by_role("button", name="▼ less softness").click()
    page.wait_for_function(PLAYING, arg=first, timeout=90_000)
    assert posts == [{"step": 0, "clip": first, "feedback": [{"attribute": "softness", "direction": "less"}]}]
    assert page.locator("#words-confirm").is_hidden() and page.locator("#words-text").input_value() == ""
    assert not errors, errors
    page.close()
