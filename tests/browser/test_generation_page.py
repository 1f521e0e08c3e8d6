"""The page while the agent makes a new behaviour: progress over the dimmed clip, the buttons locked with the
reason, no serious accessibility violation; then the made clip plays and the history marks it.

The toy domain with a gap in its serve library (``gap_roots``) and generation on; candidates are simulated in
the test's process a second a generation (``InProcessCompute``), clips rendered for real on the local pools.
"""

from __future__ import annotations

import json
import re

import pytest

from server.common.app_settings import Settings
from tests.browser.conftest import CLIP, PLAYED, PLAYING, axe_violations
from tests.fakes import InProcessCompute


@pytest.fixture(scope="module")
def url(live_server, gap_roots, local_compute, tmp_path_factory) -> str:
    tmp = tmp_path_factory.mktemp("generation-page")
    data, models = gap_roots
    settings = Settings(data_dir=data, models_dir=models, database_url=f"sqlite:///{tmp}/rba.db",
                        cache_dir=tmp / "clips", warm_start=False, prerender=False, generate=True,
                        generate_spread=0.0,  # the first answer searches
                        generate_seconds=60.0)  # for its whole budget: the progress stays long enough to see
    return live_server(settings, InProcessCompute(delay=1.0, renders=local_compute))


def test_making_a_new_behaviour_shows_progress_and_locks_the_answers(url, browser):
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    page.wait_for_function("() => document.body.dataset.state === 'idle'")
    assert page.get_by_label("Make new behaviours").is_checked()  # the server's RBA_GENERATE
    page.get_by_role("button", name="Start tuning").click()
    page.wait_for_function(PLAYING, arg="", timeout=60_000)
    page.wait_for_function(PLAYED, timeout=30_000)
    first = page.eval_on_selector(CLIP, "p => p.dataset.rolloutId")

    less = page.get_by_role("button", name="less amplitude")
    less.click()
    page.wait_for_function("() => document.body.dataset.state === 'searching'", timeout=10_000)
    page.wait_for_function("() => document.getElementById('progress-text').textContent.includes('generation')",
                           timeout=10_000)
    assert page.locator("#overlay-text").inner_text() == "Making a new behaviour for you…"
    text = page.locator("#progress-text").inner_text()
    assert re.search(r"search generation \d \(up to 6\) · \d+\.\d s of at most 60 s", text), text  # the bound
    assert page.get_by_role("progressbar", name="Search progress").is_visible()
    assert less.get_attribute("aria-disabled") == "true" and less.is_disabled()
    assert "the agent is making a new behaviour" in page.locator("#controls-hint").inner_text()
    violations = axe_violations(page)
    assert violations == [], json.dumps(violations, indent=1)

    page.wait_for_function(PLAYING, arg=first, timeout=60_000)
    made = page.eval_on_selector(CLIP, "p => p.dataset.rolloutId")
    assert made.startswith("gen-")
    assert page.locator("#step-badge").inner_text() == "Clip 2 · new behaviour"
    page.wait_for_function(PLAYED, timeout=30_000)
    assert less.get_attribute("aria-disabled") == "false"

    page.get_by_role("button", name="more pace").click()
    page.wait_for_function(PLAYING, arg=made, timeout=60_000)
    marked = page.locator('#history .hist[data-generated="true"]')
    assert marked.count() == 1 and marked.get_attribute("aria-label") == \
        "Re-watch clip 2, a new behaviour made for you"
    assert marked.locator(".hist-new").inner_text() == "new"
    assert not errors, errors
    page.close()
