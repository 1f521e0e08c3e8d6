"""The clip player (frontend/player.js) in Chromium with software WebGL: the frame it draws from a clip's data matches
the MP4's frame (the agent's silhouette), it plays on the clip's own clock, and its controls work.

The clip data is made here with ``rba.media.clip_data`` (the server's own code) and handed to the page by
Playwright, so these tests read no cache and wait for no render; the player and its three.js come from a live
server's /static.
"""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
import pytest

from rba.data.library import SkillLibrary
from rba.domains import get_domain
from rba.media import clip_data
from rba.media.silhouette import agent_masks, iou
from server.common.app_settings import Settings
from tests.browser.conftest import axe_violations

REPO = Path(__file__).resolve().parents[2]
WIDTH, HEIGHT = 320, 240  # the MP4's size (Settings.clip_width / clip_height)
CLIPS, FRAMES = 5, 3
DOMAINS = ("walker", "manipulator", "snake", "lane_change")
# The studio page's clip box at its default layout: a laptop's and a phone's (4:3 beside the answers / full width)
SIZES = {"laptop": ((1280, 800), (740, 555)), "phone": ((390, 844), (360, 270))}
PAGE = """<!doctype html><html lang="en"><head><meta charset="utf-8"><title>Clip player</title></head>
<body><main><h1>Clip player</h1><div id="box" style="width:{w}px;height:{h}px"></div></main>
<script type="module">
import {{ ClipPlayer, webglAvailable }} from "/static/player.js";
window.player = new ClipPlayer(document.getElementById("box"), {{ label: "Current clip" }});
window.webgl = webglAvailable();
window.played = 0;
player.addEventListener("playedonce", () => {{ window.played += 1; }});
</script></body></html>"""

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def url(live_server, tmp_path_factory) -> str:
    tmp = tmp_path_factory.mktemp("player")
    return live_server(Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp}/rba.db",
                                cache_dir=tmp / "clips", warm_start=False, prerender=False))


class ClipServer:
    """The clip data routes as the page sees them, answered from ``rba.media.clip_data`` made in this process."""

    def __init__(self) -> None:
        self.bodies: dict[str, dict] = {}

    def add(self, domain: str, n: int) -> list:
        dom = get_domain(domain)
        lib = SkillLibrary.load(domain, "serve", REPO / "data")
        scene = clip_data.scene(dom, WIDTH, HEIGHT)
        self.bodies[f"/api/clips/{domain}/scene.json"] = scene
        rollouts = [lib.rollout(i) for i in range(n)]
        for r in rollouts:
            self.bodies[f"/api/clips/{domain}/{r.id}.json"] = clip_data.clip(dom, r, scene["version"])
        return rollouts

    def route(self, page, url: str, size: tuple[int, int]) -> None:
        page.route(f"{url}/player", lambda r: r.fulfill(content_type="text/html",
                                                          body=PAGE.format(w=size[0], h=size[1])))

        def answer(route) -> None:
            path = route.request.url.removeprefix(url).split("?")[0]
            if path in self.bodies:
                route.fulfill(content_type="application/json", body=json.dumps(self.bodies[path]))
            else:
                route.continue_()

        page.route("**/api/clips/**", answer)


def open_player(browser, url: str, server: ClipServer, size: str = "laptop"):
    viewport, box = SIZES[size]
    page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    server.route(page, url, box)
    page.goto(f"{url}/player")
    page.wait_for_function("() => window.player !== undefined")
    return page, errors


def show(page, domain: str, rollout_id: str) -> None:
    page.evaluate("""([d, id]) => player.show({ data_url: `/api/clips/${d}/${id}.json`,
                                               url: `/api/clips/${d}/${id}.mp4`, rollout_id: id })""",
                  [domain, rollout_id])


def drawn(page, frame: int) -> np.ndarray:
    raw = base64.b64decode(page.evaluate("f => player.silhouette(f)", frame))
    return np.frombuffer(raw, dtype=np.uint8).reshape(HEIGHT, WIDTH).astype(bool)


def silhouette_ious(page, server: ClipServer, domain: str) -> list[float]:
    """IoU of the drawn and the MP4's agent silhouettes: ``CLIPS`` clips x ``FRAMES`` frames (first, middle, last)."""
    scores = []
    for rollout in server.add(domain, CLIPS):
        show(page, domain, rollout.id)
        assert page.evaluate("player.mode") == ("canvas" if domain == "lane_change" else "webgl")
        n = len(rollout.replay)
        frames = [0, n // 2, n - 1][:FRAMES]
        for f, ref in zip(frames, agent_masks(get_domain(domain), rollout, frames, WIDTH, HEIGHT), strict=True):
            assert ref.sum() > 50, (domain, rollout.id, f)  # the agent is in view
            scores.append(iou(drawn(page, f), ref))
    return scores


@pytest.mark.parametrize("domain", DOMAINS)
def test_the_drawn_frame_matches_the_mp4s(url, browser, domain):
    server = ClipServer()
    page, errors = open_player(browser, url, server)
    assert page.evaluate("window.webgl")
    scores = silhouette_ious(page, server, domain)
    assert len(scores) == CLIPS * FRAMES
    assert min(scores) >= 0.9, (domain, [round(s, 3) for s in scores])
    assert not errors, errors
    page.close()


def play_through(page, timeout_ms: int = 60_000) -> dict:
    """Play the shown clip once at 1x from its first frame: the player's counts of drawn and skipped frames."""
    page.evaluate("() => { player.pause(); player.seek(0); player.loop = false; player.rate = 1; "
                  "player.stats = { drawn: 0, dropped: 0, ms: 0 }; window.played = 0; "
                  "window.t0 = performance.now(); player.play(); }")
    page.wait_for_function("() => player.paused", timeout=timeout_ms)
    return page.evaluate("({ ...player.stats, frames: player.clip.frames, rate: player.clip.rate, "
                         "elapsed: performance.now() - window.t0 })")


@pytest.mark.parametrize("size", list(SIZES))
def test_it_plays_on_the_clips_clock(url, browser, size):
    """Every frame is due once and a play lasts the clip's length (frames are skipped, never slowed, when drawing
    falls behind). How many are skipped is a speed goal: ``benchmarks/clip_player.py`` measures it."""
    server = ClipServer()
    page, errors = open_player(browser, url, server, size)
    rollout = server.add("walker", 1)[0]
    show(page, "walker", rollout.id)
    stats = play_through(page)
    shown = stats["drawn"] + stats["dropped"]
    assert shown >= stats["frames"] - 2 and stats["drawn"] > 0, stats
    assert stats["elapsed"] >= 0.95 * 1000 * (stats["frames"] - 1) / stats["rate"], stats
    assert page.evaluate("window.played") == 1
    assert not errors, errors
    page.close()


def test_the_controls(url, browser):
    server = ClipServer()
    page, errors = open_player(browser, url, server)
    first, second = server.add("walker", 2)
    show(page, "walker", first.id)
    player = page.locator(".clip-player")
    assert player.get_attribute("data-rollout-id") == first.id and page.evaluate("player.mode") == "webgl"
    page.wait_for_function("() => Number(document.querySelector('.clip-player').dataset.frame) > 2")
    page.get_by_role("button", name="Pause").click()
    frame = int(player.get_attribute("data-frame"))
    page.wait_for_timeout(300)
    assert int(player.get_attribute("data-frame")) == frame  # paused
    page.get_by_role("button", name="One frame on").click()
    assert int(player.get_attribute("data-frame")) == frame + 1
    page.get_by_role("button", name="One frame back").click()
    page.get_by_role("button", name="One frame back").click()
    assert int(player.get_attribute("data-frame")) == frame - 1
    page.get_by_role("slider", name="Frame").evaluate(  # the scrub bar, as a drag leaves it
        "s => { s.value = '40'; s.dispatchEvent(new Event('input', { bubbles: true })); }")
    assert player.get_attribute("data-frame") == "40"
    page.get_by_label("Speed", exact=True).select_option("0.25")
    assert page.evaluate("player.rate") == 0.25
    # keys, with the focus in the player: → a frame on, Home the first, ] faster, space plays
    page.get_by_role("button", name="Play").focus()
    page.keyboard.press("ArrowRight")
    assert player.get_attribute("data-frame") == "41"
    page.keyboard.press("Home")
    assert player.get_attribute("data-frame") == "0"
    page.keyboard.press("]")
    assert page.evaluate("player.rate") == 0.5
    page.keyboard.press("d")
    assert page.locator(".cp-desc").is_visible() and "In this clip" in page.locator(".cp-desc").inner_text()
    page.keyboard.press("d")
    page.keyboard.press("l")
    assert page.evaluate("player.loop") is False
    # played once: the event fires once a whole clip's length has played, not before; scrubbing to the end and
    # playing its last frames is not watching it
    page.get_by_role("slider", name="Frame").evaluate(
        "s => { s.value = String(Number(s.max) - 2); s.dispatchEvent(new Event('input', { bubbles: true })); }")
    page.get_by_role("button", name="Play").click()
    page.wait_for_function("() => !player.playing && player.frame === player.clip.frames - 1")
    assert page.evaluate("window.played") == 0
    page.keyboard.press("Home")
    page.evaluate("player.rate = 8")
    page.keyboard.press("Space")
    page.wait_for_function("() => window.played === 1", timeout=30_000)
    assert player.get_attribute("data-played") == first.id
    # overlays: one toggle per attribute, off by default, under "Options"
    page.get_by_text("Options", exact=True).click()
    boxes = page.locator(".cp-overlays input[type=checkbox]")
    assert boxes.count() >= 1 and not any(b.is_checked() for b in boxes.all())
    boxes.first.check()
    assert page.evaluate("player.shownOverlays.size") == 1
    # compare: the next clip beside the previous one, then ghosted over it
    show(page, "walker", second.id)
    page.evaluate("([d, id]) => player.compare({ data_url: `/api/clips/${d}/${id}.json` })", ["walker", first.id])
    page.get_by_label("Compare with the previous clip").select_option("beside")
    assert player.get_attribute("data-compare") == "beside"
    page.get_by_label("Compare with the previous clip").select_option("ghost")
    assert player.get_attribute("data-compare") == "ghost"
    # camera: a drag turns it, reset brings it back
    box = page.locator(".cp-canvas").bounding_box()
    page.mouse.move(box["x"] + 100, box["y"] + 100)
    page.mouse.down()
    page.mouse.move(box["x"] + 200, box["y"] + 120)
    page.mouse.up()
    assert page.evaluate("player.orbit.azimuth") != 0
    page.get_by_role("button", name="Reset the camera").click()
    assert page.evaluate("player.orbit.azimuth") == 0
    assert axe_violations(page) == []
    assert not errors, errors
    page.close()


def test_without_webgl_it_plays_the_mp4(url, browser):
    server = ClipServer()
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    page.add_init_script("""(() => { const get = HTMLCanvasElement.prototype.getContext;
      HTMLCanvasElement.prototype.getContext = function (kind, ...rest) {
        return /webgl/.test(kind) ? null : get.call(this, kind, ...rest); }; })()""")
    server.route(page, url, SIZES["laptop"][1])
    page.goto(f"{url}/player")
    page.wait_for_function("() => window.player !== undefined")
    first, second = server.add("walker", 2)
    assert page.evaluate("window.webgl") is False
    page.evaluate("player.rate = 4")  # the video plays at the player's rate too
    show(page, "walker", first.id)
    assert page.evaluate("player.mode") == "video"
    page.wait_for_function("() => document.querySelector('.clip-player video').currentTime > 0.2", timeout=60_000)
    assert page.locator(".clip-player video").is_visible()
    page.wait_for_function("() => window.played === 1", timeout=60_000)
    # the next clip in the same player unlocks only once it has played through too (its src resets the time to 0)
    show(page, "walker", second.id)
    page.wait_for_function("() => document.querySelector('.clip-player video').currentTime > 0.2", timeout=60_000)
    assert page.evaluate("window.played") == 1
    page.wait_for_function("() => window.played === 2", timeout=60_000)
    assert page.locator(".clip-player").get_attribute("data-played") == second.id
    page.close()


def test_reduced_motion_starts_paused_with_a_play_button(url, browser):
    server = ClipServer()
    viewport, box = SIZES["laptop"]
    context = browser.new_context(viewport={"width": viewport[0], "height": viewport[1]}, reduced_motion="reduce")
    page = context.new_page()
    server.route(page, url, box)
    page.goto(f"{url}/player")
    page.wait_for_function("() => window.player !== undefined")
    rollout = server.add("lane_change", 1)[0]
    show(page, "lane_change", rollout.id)
    assert page.evaluate("player.mode") == "canvas"
    page.wait_for_timeout(300)
    assert page.evaluate("player.paused") and page.locator(".clip-player").get_attribute("data-frame") == "0"
    assert page.evaluate("player.loop") is False
    page.get_by_role("button", name="Play the clip").click()
    page.wait_for_function("() => Number(document.querySelector('.clip-player').dataset.frame) > 0")
    context.close()
