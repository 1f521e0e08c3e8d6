"""Screenshots of the admin page as an admin sees it, at 1280×800 and at phone width 390×844.

Starts the app on a free loopback port (the shipped data and models, a fresh SQLite database and clip cache in a
temporary folder, no prerendering), unlocks the page in Debian's Chromium, waits until both clips of the pair have
played their first second (the answers unlock), uploads a label file that names clips the library does not have (so
the form shows the server's problems), and writes full-page PNGs:

    benchmarks/results/screenshot-admin.png        1280×800
    benchmarks/results/screenshot-admin-phone.png  390×844

    python benchmarks/screenshots_admin.py [--out DIR]

The browser tests write their screenshots to a temporary folder; only this script writes here.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import socket
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
CHROMIUM = "/usr/bin/chromium"
TOKEN = "screenshot-admin-token"
SIZES = {"screenshot-admin.png": (1280, 800), "screenshot-admin-phone.png": (390, 844)}
BAD_LABELS = {"orderings": [{"attribute": "step_size", "clips": ["my_walk_1", "my_walk_2"]}]}

log = logging.getLogger("screenshots_admin")


@contextlib.contextmanager
def serve(tmp: Path) -> Iterator[str]:
    """The app in a thread on a free port; yields its base URL and stops it after."""
    import uvicorn

    from server.main import create_app
    from server.settings import Settings

    settings = Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp}/rba.db",
                        cache_dir=tmp / "clips", warm_start=False, prerender=False, admin_token=TOKEN)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            raise RuntimeError("the server did not start within 30 s")
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(30)


def admin_page(browser, url: str, path: Path, width: int, height: int) -> None:
    """One screenshot of the unlocked admin page at ``width``×``height``, after the pair played and an upload failed."""
    page = browser.new_page(viewport={"width": width, "height": height})
    page.goto(f"{url}/admin")
    page.fill("#token", TOKEN)
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
    log.info("wrote %s (%d×%d)", path, width, height)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=RESULTS, help="folder for the PNGs (default: benchmarks/results)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    from playwright.sync_api import sync_playwright

    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="rba-screens-") as tmp, serve(Path(tmp)) as url, sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--headless", "--no-sandbox", "--disable-gpu"])
        try:
            for name, (width, height) in SIZES.items():
                admin_page(browser, url, args.out / name, width, height)
        finally:
            browser.close()


if __name__ == "__main__":
    main()
