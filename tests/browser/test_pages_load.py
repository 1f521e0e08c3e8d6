"""Both pages load their module and the shared frontend/common.js it imports, and wire their first controls.

A module whose import fails never runs and raises no pageerror, so each test checks the scripts the page fetched
and something only the running module does (the studio page reaching "idle", the admin page's toast).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from server.common.app_settings import Settings

REPO = Path(__file__).resolve().parents[2]
TOKEN = "pages-admin-token"
PLAYER = {"/static/player.js", "/static/vendor/three-0.187.0/three.module.min.js"}  # the ClipPlayer and its three.js
SCRIPTS = {"/": {"/static/app.js", "/static/common.js", "/static/meters.js", *PLAYER},
           "/admin": {"/static/admin.js", "/static/common.js", "/static/curves.js", "/static/studies.js", *PLAYER}}


@pytest.fixture(scope="module")
def url(live_server, tmp_path_factory) -> str:
    tmp = tmp_path_factory.mktemp("pages")
    return live_server(Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp}/rba.db",
                                cache_dir=tmp / "clips", warm_start=False, prerender=False, admin_token=TOKEN))


def open_page(browser, url: str, path: str):
    """The page at ``path``, checked to have fetched its scripts and run them without an error; returns it and
    the list later errors go to."""
    page = browser.new_page()
    scripts: dict[str, int] = {}
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("response", lambda r: scripts.update({r.url.removeprefix(url): r.status})
            if r.request.resource_type == "script" else None)
    page.goto(f"{url}{path}")  # the load event: module scripts are fetched and run by then
    assert scripts == {s: 200 for s in SCRIPTS[path]}
    assert not errors, errors
    return page, errors


def test_studio_page_loads_the_shared_module(url, browser):
    page, errors = open_page(browser, url, "/")
    page.wait_for_function("() => document.body.dataset.state === 'idle'", timeout=10_000)
    assert page.locator("#domain option").count() >= 4  # built by el() from api("/api/domains")
    assert "walker" in page.locator("#domain").inner_text()
    assert page.locator("#welcome").is_visible()
    assert not errors, errors
    page.close()


def test_admin_page_loads_the_shared_module(url, browser):
    page, errors = open_page(browser, url, "/admin")
    page.fill("#token", "not-the-token")
    page.get_by_role("button", name="Unlock").click()
    page.wait_for_function("() => !document.getElementById('toast').hidden", timeout=10_000)
    assert "wrong admin token" in page.locator("#toast-text").inner_text()  # api() and toast() from common.js
    assert page.locator("#admin").is_hidden()
    assert not errors, errors
    page.close()
