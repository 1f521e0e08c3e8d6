"""Screenshots of the pages as people see them, at a laptop's 1280×800 and a phone's 390×844.

Starts the app in this process on a free loopback port (the repository's data and models, a temporary
database and clip cache), drives Debian's Chromium with Playwright through a short session and writes
PNGs to ``benchmarks/results/`` (the browser tests write theirs to a temporary folder). One function
per page; add a page to ``PAGES``.

    python benchmarks/screenshots.py                # every page
    python benchmarks/screenshots.py --pages user --out /tmp/shots
"""

from __future__ import annotations

import argparse
import json
import logging
import tempfile
from collections.abc import Callable
from pathlib import Path

from server.common.app_settings import Settings
from server.main import serve_in_thread

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
OUTPUTS = ("screenshot-*.png",)  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]
ADMIN_TOKEN = "screenshots-admin-token"
LAPTOP = {"width": 1280, "height": 800}
PHONE = {"width": 390, "height": 844}
PLAYED = """(previous) => { const v = document.getElementById('video');
  return Boolean(v.dataset.played) && v.dataset.played === v.dataset.rollout && v.dataset.rollout !== previous; }"""

log = logging.getLogger("screenshots")


def _answer(page, name: str, previous: str) -> str:
    """Press the button called ``name`` once the clip has played; the next clip's id once it has played."""
    page.get_by_role("button", name=name).click()
    page.wait_for_function(PLAYED, arg=previous, timeout=120_000)
    return page.eval_on_selector("#video", "v => v.dataset.rollout")


def user_page(browser, url: str, out: Path) -> list[Path]:
    """The studio page on the walker (the laptop after two answers, the phone's welcome and after a tap) and the
    snake (three attributes, so three path plots; the whole page)."""
    written = []
    page = browser.new_page(viewport=LAPTOP)
    page.goto(url)
    page.wait_for_function("() => document.body.dataset.state === 'idle'")
    page.get_by_role("button", name="Start tuning").click()
    page.wait_for_function(PLAYED, arg="", timeout=120_000)
    clip = page.eval_on_selector("#video", "v => v.dataset.rollout")
    clip = _answer(page, "more step size", clip)
    _answer(page, "more softness", clip)
    page.wait_for_timeout(800)  # the history thumbnails load a frame
    written.append(out / "screenshot-walker.png")
    page.screenshot(path=str(written[-1]))
    page.close()

    snake = browser.new_page(viewport=LAPTOP)  # three attributes: three path plots
    snake.goto(url)
    snake.wait_for_function("() => document.body.dataset.state === 'idle'")
    snake.select_option("#domain", "snake")
    snake.get_by_role("button", name="Start tuning").click()
    snake.wait_for_function(PLAYED, arg="", timeout=120_000)
    _answer(snake, "more speed", snake.eval_on_selector("#video", "v => v.dataset.rollout"))
    written.append(out / "screenshot-snake.png")
    snake.screenshot(path=str(written[-1]), full_page=True)
    snake.close()

    phone = browser.new_page(viewport=PHONE, has_touch=True, is_mobile=True)
    phone.goto(url)
    phone.wait_for_function("() => document.body.dataset.state === 'idle'")
    written.append(out / "screenshot-walker-phone-welcome.png")
    phone.screenshot(path=str(written[-1]))
    phone.get_by_role("button", name="Start tuning").tap()
    phone.wait_for_function(PLAYED, arg="", timeout=120_000)
    clip = phone.eval_on_selector("#video", "v => v.dataset.rollout")
    phone.get_by_role("button", name="more softness").tap()  # on the one screen a session fits on a phone
    phone.wait_for_function(PLAYED, arg=clip, timeout=120_000)
    phone.wait_for_timeout(400)  # the unlocked buttons' colour transition
    written.append(out / "screenshot-walker-phone.png")
    phone.screenshot(path=str(written[-1]))
    phone.close()
    return written


BAD_LABELS = {"orderings": [{"attribute": "step_size", "clips": ["my_walk_1", "my_walk_2"]}]}  # clips it lacks


def _admin_shot(browser, url: str, path: Path, viewport: dict) -> Path:
    """The unlocked admin page once the pair has played and an upload was refused (the form lists the problems)."""
    page = browser.new_page(viewport=viewport)
    page.goto(f"{url}/admin")
    page.fill("#token", ADMIN_TOKEN)
    page.get_by_role("button", name="Unlock").click()
    page.wait_for_function("() => document.getElementById('right-more').getAttribute('aria-disabled') === 'false'",
                           timeout=120_000)
    page.set_input_files("#upload-labels", {"name": "my-labels.json", "mimeType": "application/json",
                                            "buffer": json.dumps(BAD_LABELS).encode()})
    page.locator("#upload").click()
    page.locator("#upload-result .refused").wait_for()
    page.wait_for_function("() => document.querySelectorAll('#versions li').length > 0")
    page.evaluate("() => { for (const v of document.querySelectorAll('#pair video')) v.currentTime = 1.5; }")
    page.evaluate("() => window.scrollTo(0, 0)")  # a sticky top bar is drawn where the page was scrolled to
    page.screenshot(path=str(path), full_page=True)
    page.close()
    return path


def admin_page(browser, url: str, out: Path) -> list[Path]:
    """The admin page at both widths."""
    return [_admin_shot(browser, url, out / "screenshot-admin.png", LAPTOP),
            _admin_shot(browser, url, out / "screenshot-admin-phone.png", PHONE)]


STUDY = {"name": "Walker: which agent listens better?", "domain": "walker", "task": "target", "seed": 1,
         "targets_per_condition": 3, "answer_budget": 10, "precision": "normal",
         "conditions": [{"method": "global", "rep": "onehot"}, {"method": "random", "rep": None}],
         "consent_text": "You are invited to a study of how people tune a simulated walker. You may withdraw at any "
                         "time: everything you answered is then deleted."}


def study_page(browser, url: str, out: Path) -> list[Path]:
    """A study participant's first trial (target above, the agent's clip below on the phone) at both widths."""
    import httpx

    auth = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
    study = httpx.post(f"{url}/api/admin/studies", json=STUDY, headers=auth, timeout=60).raise_for_status().json()
    links = httpx.post(f"{url}/api/admin/studies/{study['id']}/participants", json={"count": 2}, headers=auth,
                       timeout=60).raise_for_status().json()["participants"]
    written = []
    for link, viewport, name in zip(links, (LAPTOP, PHONE), ("screenshot-study.png", "screenshot-study-phone.png"),
                                    strict=True):
        page = browser.new_page(viewport=viewport, is_mobile=viewport is PHONE, has_touch=viewport is PHONE)
        page.goto(f"{url}{link['link']}")
        page.get_by_role("button", name="I agree").click()
        page.wait_for_function("() => document.body.dataset.answerable === 'true'", timeout=120_000)
        page.wait_for_timeout(400)  # the unlocked buttons' colour transition ends
        written.append(out / name)
        page.screenshot(path=str(written[-1]))
        page.close()
    return written


PAGES: dict[str, Callable[[object, str, Path], list[Path]]] = {"user": user_page, "admin": admin_page,
                                                               "study": study_page}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pages", nargs="+", choices=sorted(PAGES), default=sorted(PAGES))
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    from playwright.sync_api import sync_playwright

    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="rba-shots-") as tmp, sync_playwright() as p:
        settings = Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp}/rba.db",
                            cache_dir=Path(tmp) / "clips", warm_start=False, prerender=True, admin_token=ADMIN_TOKEN)
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            with serve_in_thread(settings) as url:
                for name in args.pages:
                    for path in PAGES[name](browser, url, args.out):
                        log.info("wrote %s", path)
        finally:
            browser.close()


if __name__ == "__main__":
    main()
