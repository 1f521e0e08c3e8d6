"""benchmarks/ideal_oracle.py: bisection that shows exactly its estimate, on hand-made cases and the toy domain."""

import json

import numpy as np
import pytest

from rba.interact.bisection import kernel_prior
from rba.interact.users import SimulatedUser
from tests.benchmark_scripts import load_benchmark

ideal_oracle = load_benchmark("ideal_oracle")
GRID = np.linspace(0.0, 1.0, 401)


def user(target, eps) -> SimulatedUser:
    names = tuple(f"a{i}" for i in range(len(target)))
    return SimulatedUser(np.array(target), np.array(eps), names, np.empty((0, len(target))))


def test_plain_bisection_halves_until_within():
    # 0.5 (less) -> 0.25 (more) -> 0.375 (less) -> 0.3125: within 0.02 of 0.3, after three answers
    assert ideal_oracle.ideal_trial(user([0.3], [0.02]), GRID[None], ideal_oracle.PURE) == (True, 3)


def test_a_prior_where_behaviours_lie_starts_the_bisection_there():
    prior = kernel_prior(GRID, np.full(50, 0.3), width=0.01, floor=ideal_oracle.PRIOR_FLOOR)
    assert ideal_oracle.ideal_trial(user([0.3], [0.02]), GRID[None], ideal_oracle.PURE, prior[None]) == (True, 0)
    far = ideal_oracle.ideal_trial(user([0.9], [0.02]), GRID[None], ideal_oracle.PURE, prior[None])
    uniform = ideal_oracle.ideal_trial(user([0.9], [0.02]), GRID[None], ideal_oracle.PURE)
    assert far[0] and far[1] > uniform[1]  # reached, but a target where no behaviour lies costs more (12 against 4)


def test_a_silent_attribute_costs_nothing_and_an_unreachable_target_fails_at_the_budget():
    ok, feedbacks = ideal_oracle.ideal_trial(user([0.5, 0.3], [0.02, 0.02]), np.stack([GRID, GRID]),
                                             ideal_oracle.PURE)
    assert (ok, feedbacks) == (True, 3)  # the first attribute starts within ε and is never answered about
    assert ideal_oracle.ideal_trial(user([1.5], [0.02]), GRID[None], 0.1, budget=20) == (False, 20)


def test_toy_domain_report_and_bad_targets(toy_env, tmp_path, capsys):
    out = tmp_path / "ideal"
    assert ideal_oracle.main(["--domains", "toy", "--targets", "4", "--split", "val", "--out", str(out)]) == 0
    report = json.loads(out.with_suffix(".json").read_text())
    assert [(r["domain"], r["precision"], r["targets"]) for r in report["rows"]] == [("toy", "high", 4),
                                                                                  ("toy", "normal", 4)]
    for row in report["rows"]:
        for kind in ("ideal", "ideal_pure", "ideal_prior", "ideal_prior_pure"):
            assert row[kind]["success_rate"] == 1.0 and row[kind]["avg_feedback"] >= 0
        assert set(row["oracle_library"]) == {"success_rate", "avg_feedback", "std_feedback"}
    assert "| toy | high |" in out.with_suffix(".md").read_text()
    with pytest.raises(SystemExit) as exit_:
        ideal_oracle.main(["--targets", "0", "--out", str(out)])
    assert exit_.value.code == 2 and "--targets must be at least 1, got 0" in capsys.readouterr().err


def test_a_reading_error_costs_answers_and_none_changes_nothing():
    target, eps = [0.3, 0.6], [0.01, 0.01]
    grids = np.stack([GRID, GRID])
    exact = ideal_oracle.ideal_trial(user(target, eps), grids, 0.1)
    assert ideal_oracle.ideal_trial(user(target, eps), grids, 0.1, reading=np.zeros(2)) == exact
    noisy = [ideal_oracle.ideal_trial(user(target, eps), grids, 0.1, reading=np.full(2, 0.03),
                                      rng=np.random.default_rng(r)) for r in range(10)]
    assert all(ok for ok, _ in noisy)  # the soft step still homes in ...
    assert np.mean([n for _, n in noisy]) > 2 * exact[1]  # ... but clips landing 3 ε off take many more answers


def test_reading_table_and_bad_options(toy_env, tmp_path, capsys):
    out = tmp_path / "ideal"
    argv = ["--domains", "toy", "--precisions", "high", "--targets", "3", "--split", "val", "--out", str(out)]
    assert ideal_oracle.main([*argv, "--reading", "0", "2", "--repeats", "2"]) == 0
    (row,) = json.loads(out.with_suffix(".json").read_text())["rows"]
    assert row["reading"]["0"] == row["ideal_prior"]  # no error: the prior's bisection itself
    assert row["reading"]["2"]["avg_feedback"] > row["reading"]["0"]["avg_feedback"]
    assert "| s = 0 | s = 2 |" in out.with_suffix(".md").read_text()
    with pytest.raises(SystemExit) as exit_:
        ideal_oracle.main([*argv, "--reading", "-1"])
    assert exit_.value.code == 2 and "--reading at least 0, got 5 and [-1.0]" in capsys.readouterr().err
