"""A live uvicorn server on 127.0.0.1 (a free port) and headless Debian Chromium, never a downloaded browser."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from server.main import serve_in_thread

CHROMIUM = Path("/usr/bin/chromium")
# The studio page's clip player (frontend/player.js): its element names the clip it shows (data-rollout-id)
CLIP = "#clip .clip-player"
# page.wait_for_function predicates of the studio page: a new clip (not ``previous``) plays; it has played through
PLAYING = """(previous) => {
  const p = document.querySelector('#clip .clip-player'), v = p && p.querySelector('video');
  if (!p || !p.dataset.rolloutId || p.dataset.rolloutId === previous || p.dataset.ready !== 'true') return false;
  return p.dataset.mode === 'video' ? v.readyState >= 3 && v.currentTime > 0.25 : Number(p.dataset.frame) > 3;
}"""
PLAYED = """() => { const p = document.querySelector('#clip .clip-player');
  return Boolean(p && p.dataset.played) && p.dataset.played === p.dataset.rolloutId; }"""
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]


def new_page(browser, url: str, width: int = 1280, height: int = 800, touch: bool = False):
    """A page at ``url`` once the studio is idle, and the list its uncaught script errors go to."""
    page = browser.new_page(viewport={"width": width, "height": height}, has_touch=touch, is_mobile=touch)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    page.wait_for_function("() => document.body.dataset.state === 'idle'")
    return page, errors


@pytest.fixture(scope="module")
def live_server() -> Iterator[Callable[..., str]]:
    """``start(settings, compute=None)`` -> base URL of a server running in a thread; all stop at module end."""
    with contextlib.ExitStack() as servers:
        yield lambda settings, compute=None: servers.enter_context(serve_in_thread(settings, timeout=15,
                                                                                   compute=compute))


@pytest.fixture(scope="module")
def browser():
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is missing (apt-get install -y chromium; .ci/run does it)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield b
        b.close()


AXE = Path(__file__).resolve().parent / "vendor" / "axe.min.js"  # axe-core 4.14.1 from npm (MPL-2.0, beside it)


def axe_violations(page, impacts: tuple[str, ...] = ("serious", "critical")) -> list:
    """Run the vendored axe-core on ``page`` (WCAG 2 A/AA rules); its violations of ``impacts``, each as
    ``{"id", "impact", "help", "targets"}`` (each target with axe's reason) so a failing assert says what and where."""
    if not page.evaluate("() => Boolean(window.axe)"):
        page.add_script_tag(content=AXE.read_text(encoding="utf-8"))
    result = page.evaluate("""async () => {
      const tags = ['wcag2a', 'wcag2aa', 'wcag21a', 'wcag21aa'];
      const r = await axe.run(document, { runOnly: { type: 'tag', values: tags } });
      return r.violations.map((v) => ({ id: v.id, impact: v.impact, help: v.help,
                                        targets: v.nodes.map((n) => `${n.target.join(' ')}: ${n.failureSummary}`) }));
    }""")
    return [v for v in result if v["impact"] in impacts]
