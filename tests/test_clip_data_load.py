"""benchmarks/clip_data_load.py's verdicts: an N holds only if both p95 goals are met without errors, and the
scale is the largest N that held, naming the N that missed."""

import os

from tests.benchmark_scripts import load_benchmark

load_benchmark("api_load")  # the script imports it as a sibling module
load = load_benchmark("clip_data_load")


def result(users: int, feedback_p95: float, next_p95: float, errors: int = 0) -> dict:
    r = {"users": users, "feedback_ms": {"p95": feedback_p95}, "next_clip_drawable_ms": {"p95": next_p95},
         "error_count": errors}
    return {**r, "goals_met": load.holds(r)}


def test_an_n_holds_only_with_both_goals_and_no_errors():
    assert result(50, 100.0, 150.0)["goals_met"]
    assert not result(50, 101.0, 90.0)["goals_met"] and not result(50, 50.0, 151.0)["goals_met"]
    assert not result(50, 50.0, 90.0, errors=1)["goals_met"]  # a refused answer is not a fast one


def test_the_scale_is_the_largest_n_that_held():
    goals = load.judge([result(50, 40.0, 120.0), result(100, 60.0, 140.0), result(200, 300.0, 900.0)])
    assert goals["next clip drawable p95 at N=50"] == "120 ms — met"
    assert goals["scale: largest N at which both hold"] == "100 (N = 200 missed; larger N not run)"
    assert load.judge([result(50, 400.0, 900.0)])["scale: largest N at which both hold"].startswith("none")


def test_the_server_cpu_is_read_for_a_whole_process_group():
    assert load.group_cpu_seconds(os.getpgrp()) > 0  # this test's own group has used some CPU
