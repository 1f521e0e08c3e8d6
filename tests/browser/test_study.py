"""A study with people, in a real browser: an experimenter sets up a walker study (RBA-Global vs Random) on the admin
page and makes 12 links; 12 simulated participants go through the real participant page (consent, every trial
answered by a simulated user kind from what the page shows, the questionnaire), one withdraws midway. The admin
page's numbers must equal those recomputed from the export, and RBA-Global must beat Random on SR@10 by the
results' stated paired test. Plus the participant page on a phone and under axe-core."""

from __future__ import annotations

import csv
import io
import time
import zipfile
from dataclasses import dataclass, field
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path

import httpx
import numpy as np
import pytest

from rba.data.library import SkillLibrary
from rba.domains import get_domain
from rba.interact.base import SATISFIED
from rba.interact.users import SKIP, SimulatedUser, UserSpec, parse_user
from server.common.app_settings import Settings
from server.ops.study_export import results_from_export
from server.runtime.catalog import Catalog
from tests.browser.conftest import axe_violations

REPO = Path(__file__).resolve().parents[2]
TOKEN = "study-admin-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
PARTICIPANTS = 12
KINDS = ("paper", "mistake:0.1", "skip:0.2")  # cycled over the participants
WITHDRAWS = 5  # this participant withdraws during their second trial
PHONE = 1  # this participant uses a phone-size window
RATE = 40  # clips play this many times faster: they must still play to their end before answers unlock
STATE = """() => {
  const q = (s) => document.querySelector(s);
  const id = (s) => { const e = q(s); return e ? e.dataset.rolloutId || null : null; };
  return { state: document.body.dataset.state, answerable: document.body.dataset.answerable === 'true',
           trial: (q('#h-trial') || {}).textContent || '', target: id('#target [data-rollout-id]'),
           current: id('#current [data-rollout-id]') };
}"""
SHOWN = """(stage) => {  // the clip player in ``stage`` shows its clip: drawn from data, or a decoded MP4 frame
  const p = document.querySelector(`${stage} .clip-player`);
  if (!p || p.dataset.ready !== 'true') return false;
  const v = p.querySelector('video');
  return p.dataset.mode !== 'video' || (v.readyState >= 2 && v.videoWidth > 0);
}"""
BOOT = "() => window.rbaStudy && document.body.dataset.state !== 'loading'"

pytestmark = pytest.mark.slow  # a live server with the walker's models and Chromium: tens of seconds at least


@pytest.fixture(scope="module")
def url(live_server, tmp_path_factory) -> str:
    tmp = tmp_path_factory.mktemp("study")
    settings = Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp}/rba.db",
                        cache_dir=tmp / "clips", warm_start=False, prerender=False, admin_token=TOKEN)
    if ("global", "onehot") not in Catalog(settings).available("walker"):
        pytest.skip("walker artifacts are absent: run `rba build walker` and `rba train walker` first")
    return live_server(settings)


@pytest.fixture(scope="module")
def walker():
    """What the simulated participants know and the agents never see: the true proxies and ε."""
    serve = SkillLibrary.load("walker", "serve", root=REPO / "data")
    test = SkillLibrary.load("walker", "test", root=REPO / "data")
    return serve, test, get_domain("walker").epsilons(serve.proxies, "normal")


def study_body(**changes) -> dict:
    body = {"name": "walker study", "domain": "walker", "task": "target", "targets_per_condition": 1,
            "answer_budget": 10, "precision": "normal", "consent_text": "Consent.\n\nSecond paragraph.", "seed": 3,
            "conditions": [{"method": "global", "rep": "onehot"}, {"method": "random", "rep": None}]}
    return body | changes


def new_links(url: str, count: int, **changes) -> list[str]:
    r = httpx.post(f"{url}/api/admin/studies", json=study_body(**changes), headers=AUTH, timeout=30)
    assert r.status_code == 201, r.text
    r = httpx.post(f"{url}/api/admin/studies/{r.json()['id']}/participants", json={"count": count}, headers=AUTH)
    assert r.status_code == 201, r.text
    return [f"{url}{p['link']}" for p in r.json()["participants"]]


def open_participant(browser, link: str, width: int = 1280, height: int = 800):
    context = browser.new_context(viewport={"width": width, "height": height}, has_touch=width < 500,
                                  is_mobile=width < 500)
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(link)
    page.wait_for_function(BOOT)
    page.evaluate(f"() => {{ window.rbaStudy.rate = {RATE}; }}")
    return page, errors


# ---------------------------------------------------------------- quick checks of the page
def test_participant_page_consent_trial_and_unknown_links(url, browser, tmp_path):
    link = new_links(url, 1)[0]
    page, errors = open_participant(browser, link)
    assert page.evaluate(STATE)["state"] == "consent"
    assert "Second paragraph." in page.locator("#consent-text").inner_text()
    assert axe_violations(page) == []
    posts: list[str] = []
    page.on("request", lambda r: posts.append(r.url) if r.method == "POST" and r.url.endswith("/answer") else None)
    page.evaluate("() => { window.rbaStudy.rate = 0.25; }")  # a slow first play: the answers stay locked meanwhile
    page.get_by_role("button", name="I agree").click()
    page.wait_for_function("() => document.querySelector('#current .clip-player').dataset.ready === 'true'",
                           timeout=60_000)
    assert page.get_by_role("button", name="more step size").get_attribute("aria-disabled") == "true"
    page.get_by_role("button", name="This matches the target").click(force=True)  # clicked anyway: not sent
    page.evaluate(f"() => {{ window.rbaStudy.rate = {RATE}; }}")
    page.wait_for_function("() => document.body.dataset.answerable === 'true'", timeout=60_000)
    assert posts == []
    s = page.evaluate(STATE)
    assert s["target"].startswith("test-") and s["current"].startswith("serve-")
    for stage in ("#target", "#current"):  # both clips show, side by side
        page.wait_for_function(SHOWN, arg=stage, timeout=60_000)
    target, current = page.locator("#target").bounding_box(), page.locator("#current").bounding_box()
    assert target["x"] + target["width"] <= current["x"] and abs(target["y"] - current["y"]) < 2
    assert page.locator("#satisfied").bounding_box()["y"] < 800  # the answers on the same screen
    # the clips' text descriptions name measured values, which would give the target away: none here, nor a loop
    assert page.locator(".cp-desc").all_text_contents() == ["", ""]
    page.locator("#current").get_by_text("Options", exact=True).click()
    assert page.locator("#current").get_by_role("button", name="Description").count() == 0
    assert page.locator("#current").get_by_text("Loop", exact=True).count() == 1  # there, but hidden
    assert not page.locator("#current").get_by_text("Loop", exact=True).is_visible()
    page.locator("#current").get_by_text("Options", exact=True).click()
    page.screenshot(path=str(tmp_path / "study.png"))
    page.reload()  # the link resumes where the participant was: the same trial and clip, to be watched again
    page.wait_for_function(BOOT)
    assert page.evaluate(STATE) | {"answerable": False} == s | {"answerable": False}
    assert page.locator("#progress").inner_text() == "Trial 1 of 2 · 10 answers left"
    page.wait_for_timeout(400)  # the unlocked buttons' colour transition ends
    assert axe_violations(page) == []
    page.get_by_role("button", name="Withdraw from the study").click()
    page.get_by_role("button", name="Stay in the study").click()  # the confirm dialog: nothing happens
    assert page.evaluate(STATE)["state"] == "trial"
    page.goto(f"{url}/study/not-a-token")
    page.wait_for_function("() => document.body.dataset.state === 'gone'")
    assert page.locator("#h-gone").inner_text() == "This study link is not known"
    assert not errors, errors
    page.context.close()


# ---------------------------------------------------------------- the whole study
@dataclass
class Person:
    number: int
    link: str
    spec: UserSpec
    page: object = None
    errors: list = field(default_factory=list)
    user: SimulatedUser | None = None
    trial: str = ""
    trials_seen: int = 0
    answers: int = 0
    skips: int = 0
    state: str = ""
    withdrawn_trial: str | None = None


def act(p: Person, walker, axe_done: list) -> bool:
    """One step of participant ``p`` if the page lets them make one; whether they did."""
    serve, test, eps = walker
    s = p.page.evaluate(STATE)
    p.state = s["state"]
    if s["state"] == "consent":
        p.page.get_by_role("button", name="I agree").click()
        p.page.wait_for_function("() => document.body.dataset.state !== 'consent'")
        return True
    if s["state"] == "trial" and s["answerable"]:
        if s["trial"] != p.trial:  # a new trial: a new simulated user chasing its target
            p.trial = s["trial"]
            p.trials_seen += 1
            if p.number == WITHDRAWS and p.trials_seen == 2:
                api = p.link.replace("/study/", "/api/participate/")
                p.withdrawn_trial = httpx.get(api).json()["trial"]["id"]
                p.page.get_by_role("button", name="Withdraw from the study").click()
                p.page.get_by_role("button", name="Withdraw and delete my answers").click()
                p.page.wait_for_function("() => document.body.dataset.state === 'gone'")
                assert httpx.get(api).status_code == 410
                return True
            target = test.proxies[test.index_of(s["target"])]
            p.user = p.spec.build(target, eps, serve, seed=1000 * p.number + p.trials_seen)
        answer = p.user.respond(serve.index_of(s["current"]))
        if answer == SKIP:  # hesitating: watch the clip again, then answer
            p.skips += 1
            p.page.click("#current-again")
            return True
        p.answers += 1
        if answer == SATISFIED:
            p.page.click("#satisfied")
        else:
            f = answer[0]  # one attribute an answer, as the page's buttons take them
            way = "more" if f.direction > 0 else "less"
            p.page.click(f'#attributes button[data-attr="{f.attribute}"][data-dir="{way}"]')
        return True
    if s["state"] == "questionnaire":
        if not axe_done:
            axe_done.append(axe_violations(p.page))
        rng = np.random.default_rng(p.number)
        for box in ("satisfaction", "usability"):
            for fs in p.page.locator(f"#{box} fieldset").all():
                options = fs.locator("input[type=radio]")
                options.nth(int(rng.integers(options.count()))).check()
        p.page.get_by_role("button", name="Send my answers").click()
        p.page.wait_for_function("() => document.body.dataset.state === 'thanks'")
        return True
    return False


def create_study_on_admin_page(browser, url: str):
    admin = browser.new_page(viewport={"width": 1280, "height": 900})
    admin_errors: list[str] = []
    admin.on("pageerror", lambda e: admin_errors.append(str(e)))
    admin.goto(f"{url}/admin")
    admin.fill("#token", TOKEN)
    admin.get_by_role("button", name="Unlock").click()
    admin.wait_for_function("() => document.getElementById('study-domain').options.length > 0")
    admin.locator("#study-new summary").click()
    admin.fill("#study-name", "Walker: RBA-Global vs Random")
    admin.select_option("#study-domain", "walker")
    for box in admin.locator('#study-conditions input[name="condition"]').all():
        box.set_checked(box.get_attribute("value") in ('{"method":"global","rep":"onehot"}',
                                                       '{"method":"random","rep":null}'))
    admin.select_option("#study-task", "target")
    admin.fill("#study-targets", "3")
    admin.fill("#study-budget", "10")
    admin.select_option("#study-precision", "normal")
    admin.fill("#study-seed", "7")
    admin.get_by_role("button", name="Create the study").click()
    admin.wait_for_function("() => !document.getElementById('study-view').hidden")
    admin.fill("#study-count", str(PARTICIPANTS))
    admin.get_by_role("button", name="Make links").click()
    admin.wait_for_function("() => document.querySelector('#study-links textarea')")
    links = admin.locator("#study-links textarea").input_value().split("\n")
    return admin, admin_errors, links


def test_twelve_participants_through_the_page(url, browser, walker, tmp_path):
    started = time.monotonic()
    admin, admin_errors, links = create_study_on_admin_page(browser, url)
    assert len(links) == PARTICIPANTS and len(set(links)) == PARTICIPANTS
    people = [Person(i, link, parse_user(KINDS[i % len(KINDS)])) for i, link in enumerate(links)]
    for p in people:
        p.page, p.errors = open_participant(browser, p.link, *((390, 844) if p.number == PHONE else (1280, 800)))
    axe_done: list = []
    phone_checked = False
    deadline = time.monotonic() + 480
    while not all(p.state in ("thanks", "gone") for p in people):
        assert time.monotonic() < deadline, [(p.number, p.state, p.trial, p.answers) for p in people]
        moved = [act(p, walker, axe_done) for p in people if p.state not in ("thanks", "gone")]
        if not phone_checked and people[PHONE].state == "trial":
            phone_checked = check_phone(people[PHONE].page, tmp_path)
        if not any(moved):
            time.sleep(0.05)
    assert phone_checked
    assert axe_done == [[]], axe_done  # the questionnaire passes axe-core (WCAG 2 A/AA)
    for p in people:
        assert not p.errors, (p.number, p.errors)
    assert sum(p.skips for p in people) > 0  # the skip kind replayed clips, so replays were counted
    check_results(admin, people, tmp_path)
    assert not admin_errors, admin_errors
    print(f"study of {PARTICIPANTS} participants through the page: {time.monotonic() - started:.0f} s, "
          f"{sum(p.answers for p in people)} answers")


def check_phone(page, tmp_path) -> bool:
    """On a phone the target sits above the agent's clip, both whole on the screen's width and both showing."""
    if not page.evaluate("() => document.body.dataset.answerable === 'true'"):
        return False
    for stage in ("#target", "#current"):
        page.wait_for_function(SHOWN, arg=stage, timeout=60_000)
    target = page.locator("#target").bounding_box()
    current = page.locator("#current").bounding_box()
    for box in (target, current):
        assert box["x"] >= 0 and box["x"] + box["width"] <= 390 and box["height"] > 100, box
    assert current["y"] >= target["y"] + target["height"], (target, current)  # stacked, not overlapping
    for button in ("#satisfied", "#attributes button >> nth=0", "#attributes button >> nth=-1"):  # thumb's reach
        box = page.locator(button).bounding_box()
        assert box["y"] >= 0 and box["y"] + box["height"] <= 844, (button, box)
    page.screenshot(path=str(tmp_path / "study-phone.png"), full_page=True)
    return True


def fixed(v: float | None, digits: int = 2) -> str:
    """JavaScript's ``v.toFixed(digits)`` (ties away from zero, on the float's exact value); "–" for None."""
    if v is None:
        return "–"
    return str(Decimal(v).quantize(Decimal(1).scaleb(-digits), rounding=ROUND_HALF_UP))


def with_ci(e: dict, digits: int = 2) -> str:
    if e["value"] is None:
        return "–"
    return f"{fixed(e['value'], digits)} [{fixed(e['low'], digits)}, {fixed(e['high'], digits)}]"


def check_results(admin, people, tmp_path) -> None:
    """The admin page's live results, once everyone is through, against those recomputed from its export."""
    stayed = [p for p in people if p.state == "thanks"]
    admin.wait_for_function("""(n) => {
      const rows = [...document.querySelectorAll('#study-results .study-progress-table tbody tr')];
      return rows.length === n && rows.every((r) => r.lastElementChild.textContent === 'yes');
    }""", arg=len(stayed), timeout=20_000)
    with admin.expect_download() as got:
        admin.click("#study-export")
    path = tmp_path / "study.zip"
    got.value.save_as(path)
    r = results_from_export(path)
    with zipfile.ZipFile(path) as z:
        trials = list(csv.DictReader(io.StringIO(z.read("trials.csv").decode())))
        answers = list(csv.DictReader(io.StringIO(z.read("answers.csv").decode())))
        participants = list(csv.DictReader(io.StringIO(z.read("participants.csv").decode())))
    gone = people[WITHDRAWS]
    assert gone.state == "gone" and len(participants) == len(stayed) == PARTICIPANTS - 1
    assert gone.withdrawn_trial and not any(t["trial_id"] == gone.withdrawn_trial for t in trials)
    assert not any(a["trial_id"] == gone.withdrawn_trial for a in answers)
    assert len(trials) == len(stayed) * 6 and all(t["ended"] for t in trials)
    assert len(answers) == sum(p.answers for p in stayed)  # every click the page sent, no more
    assert any(int(a["replays"]) > 0 for a in answers) and all(int(a["ms"]) > 0 for a in answers)

    # the page's table, cell by cell, equals the numbers recomputed from the export alone
    rows = admin.locator("#study-results .study-table tbody tr").all()
    shown = [[c.inner_text() for c in row.locator("th, td").all()] for row in rows]
    assert [row[0] for row in shown] == ["RBA-Global", "Random"]
    expected = [[str(c["trials"]), str(c["successes"]), with_ci(c["sr"]), with_ci(c["af"], 1),
                 *[with_ci(c["sr_at"][str(k)]) for k in r["sr_at_k"]], str(c["answers"]),
                 f"{fixed(c['median_ms_per_answer'] / 1000, 1)} s"] for c in r["conditions"]]
    assert [row[1:] for row in shown] == expected
    q = r["questionnaires"]
    assert q["n"] == len(stayed)
    assert (f"satisfaction ({q['satisfaction']['scale']}) {with_ci(q['satisfaction'], 1)}"
            in admin.locator("#study-questionnaires").inner_text())

    # RBA-Global beats Random on SR@10, by the test the results name
    pair = r["comparison"]["pairs"][0]
    assert r["comparison"]["measure"] == "SR@10" and (pair["a"], pair["b"]) == (0, 1)
    global_sr, random_sr = (c["sr_at"]["10"]["value"] for c in r["conditions"])
    line = admin.locator("#study-comparison li").first.inner_text()
    assert pair["test"] in line and f"n = {pair['n']}" in line
    print(f"SR@10 RBA-Global {global_sr:.2f}, Random {random_sr:.2f}; {pair['test']}: p = {pair['p_value']:.2g}, "
          f"n = {pair['n']}, median difference {pair['median_difference']:.2f}")
    assert global_sr > random_sr and pair["median_difference"] > 0 and pair["p_value"] < 0.05, pair
    assert axe_violations(admin) == []  # the Studies panel, its form open and its results drawn
