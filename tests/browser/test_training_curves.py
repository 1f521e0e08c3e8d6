"""The admin page plots a real training job's curves: while it runs (the poll redraws them) and after, as inline SVG
with labelled axes, a text summary and a table of every value, with no serious axe-core violation.

A tiny job of the toy domain (``tiny`` preset: ζσ 200 steps, rθ 120) on own copies of its data and models."""

from __future__ import annotations

import json

import pytest
from playwright.sync_api import expect

from server.common.app_settings import Settings
from tests.browser.conftest import axe_violations
from tests.conftest import own_copy

TOKEN = "curves-admin-token"
pytestmark = pytest.mark.slow
PLOTTED_WHILE_RUNNING = """() => {
  const line = document.querySelector('#curves polyline');
  return Boolean(line) && line.getAttribute('points').split(' ').length >= 2
    && document.getElementById('job-status').textContent.includes(': running');
}"""


@pytest.fixture
def url(live_server, toy_roots, local_compute, tmp_path) -> str:
    data, models = own_copy(toy_roots, tmp_path)
    return live_server(Settings(data_dir=data, models_dir=models, database_url=f"sqlite:///{tmp_path}/rba.db",
                                cache_dir=tmp_path / "clips", warm_start=False, prerender=False, admin_token=TOKEN,
                                train_nice=0), local_compute)


def test_a_training_jobs_curves_are_plotted_while_it_runs_and_after(url, browser, tmp_path):
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"{url}/admin")
    page.fill("#token", TOKEN)
    page.get_by_role("button", name="Unlock").click()
    page.wait_for_function("() => [...document.querySelectorAll('#domain option')].some((o) => o.value === 'toy')")
    page.select_option("#domain", "toy")
    page.wait_for_function("() => document.querySelector('#preset option[value=tiny]') !== null")
    page.select_option("#train-method", "global")
    page.select_option("#preset", "tiny")
    assert page.locator("#curves").is_hidden() and page.locator("#curves-pick").is_hidden()  # no job: nothing
    page.get_by_role("button", name="Train with the labels").click()

    page.wait_for_function(PLOTTED_WHILE_RUNNING, timeout=120_000, polling=200)
    page.screenshot(path=str(tmp_path / "admin-curves-running.png"), full_page=True)
    page.wait_for_function("() => document.getElementById('job-status').textContent.includes('succeeded')",
                           timeout=300_000)
    page.wait_for_function("() => document.querySelectorAll('#curves figure').length === 2")

    figures = page.locator("#curves figure")
    assert [figures.nth(i).get_attribute("data-model") for i in range(2)] == ["global_reward-onehot", "ranker-onehot"]
    ranker = page.locator("#curves figure[data-model='ranker-onehot']")
    loss = ranker.locator("svg[data-chart='loss']")
    assert loss.get_attribute("role") == "img"
    assert loss.locator("title").text_content() == "ranker-onehot: training loss"
    assert [t.text_content() for t in loss.locator(".axis-title").all()] == ["step", "loss"]
    assert len(loss.locator("polyline").get_attribute("points").split(" ")) == 1 + 200 // 5  # step 1, then every 5
    held = ranker.locator("svg[data-chart='held out']")
    assert held.locator("g.series").count() == 2  # the toy's two attributes
    assert 2 <= held.locator("g.series").first.locator("circle").count() <= 10  # measured at most 10 times
    assert "pairwise accuracy/amplitude" in ranker.locator(".legend").inner_text()
    summary = ranker.locator(".curve-summary").inner_text()
    assert summary.startswith("ranker-onehot: loss ") and "at step 200" in summary

    ranker.get_by_text("Show the values").click()
    table = ranker.locator("table")
    assert table.locator("thead th").all_inner_texts() == ["step", "loss", "pairwise accuracy/amplitude",
                                                           "pairwise accuracy/pace"]
    assert table.locator("tbody tr").last.locator("th").inner_text() == "200"
    violations = axe_violations(page)
    assert violations == [], json.dumps(violations, indent=1)
    page.screenshot(path=str(tmp_path / "admin-curves-done.png"), full_page=True)

    # Each job's curves: a second job, cancelled at once, keeps none; picking the first shows its curves again.
    first = page.locator("#curves-job").input_value()
    assert page.locator("#curves-job option").count() == 1 and "succeeded" in page.locator("#curves-job").inner_text()
    page.get_by_role("button", name="Train with the labels").click()
    page.get_by_role("button", name="Cancel").click()
    page.get_by_role("button", name="Stop the job").click()
    page.wait_for_function("() => document.getElementById('job-status').textContent.includes('cancelled')")
    page.wait_for_function("() => document.querySelectorAll('#curves-job option').length === 2")
    assert page.locator("#curves-job").input_value() != first  # the newest job is the one shown
    expect(page.locator("#curves-none")).to_contain_text("No curves for this job")
    expect(page.locator("#curves figure")).to_have_count(0)  # the first job's charts are gone, not just hidden
    page.select_option("#curves-job", first)
    expect(page.locator("#curves figure")).to_have_count(2)
    assert page.locator("#curves-none").is_hidden()
    assert not errors, errors
    page.close()
