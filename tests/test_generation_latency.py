"""benchmarks/generation_latency.py's options: ``--search-seconds default`` runs the server at its own per-domain
bounds (Domain.generate_seconds), and the report says which bounds a table was measured at."""

import argparse

import pytest

from rba.domains import get_domain
from tests.benchmark_scripts import load_benchmark

load_benchmark("api_load")  # the script imports it as a sibling module
latency = load_benchmark("generation_latency")


def test_search_seconds_are_seconds_or_the_servers_default():
    assert latency.parse_args([]).search_seconds == [None]  # the server's own bounds
    assert latency.parse_args(["--search-seconds", "default", "2"]).search_seconds == [None, 2.0]
    for bad in ("0", "-1", "inf", "soon"):
        with pytest.raises(argparse.ArgumentTypeError):
            latency.bound_arg(bad)


def test_a_table_names_the_bounds_it_was_measured_at():
    assert latency.bound_text(2.0, ["walker"]) == "2 s (`RBA_GENERATE_SECONDS`)"
    default = latency.bound_text(None, list(latency.DOMAINS))
    assert all(f"{d} {get_domain(d).generate_seconds:g} s" in default for d in latency.DOMAINS)
    assert "walker 1 s" in default and "snake 1.25 s" in default and "lane_change 2 s" in default


def test_answers_whose_search_fell_short_and_pooled_clips_have_their_own_columns():
    run = latency.DomainRun("snake", [latency.Answer(1.5, True, True, 1.2), latency.Answer(2.5, True, False, 2.4),
                                      latency.Answer(0.1, False, False), latency.Answer(0.7, False, True)],
                            sessions=1)
    row = latency.domain_report(run)
    assert row["searched"]["answers"] == 2 and row["fell_short"] == latency.summary([run.answers[1]])
    assert row["generated_shown"] == 1 and row["other"]["answers"] == 1
    assert row["pooled"] == latency.summary([run.answers[3]])  # a made clip shown without a search
    made = latency.summary([run.answers[0], run.answers[3]])
    report = {"command": "x", "date": "d", "machine": "m", "load": [0.0, 0.0],
              "bounds": [{"bound_s": 1.5, "domains": [row], "all_searched": row["searched"], "all_made": made}]}
    text = latency.markdown(report)
    assert "| snake | 1 (0) | 2, " in text
    assert f"| 1 | 1, {row['fell_short']['p95_s']} | 1, {row['pooled']['p95_s']} | 1, " in text
    assert f"showed a made clip (searched or pooled): n = 2, p95 {made['p95_s']} s" in text


def test_clip_data_answers_wait_for_the_data_and_have_their_own_report_and_goal():
    assert latency.parse_args([]).out.name == "generation_latency"
    data = latency.parse_args(["--clip", "data"])
    assert data.out.name == "generation_latency_data" and latency.LINK[data.clip] == "data_url"
    row = latency.domain_report(latency.DomainRun("walker", [latency.Answer(0.8, True, True, 0.5)], sessions=1))
    report = {"command": "x", "date": "d", "machine": "m", "load": [0.0, 0.0], "args": {"clip": "data"},
              "bounds": [{"bound_s": 1.0, "domains": [row], "all_searched": row["searched"],
                          "all_made": row["searched"]}]}
    text = latency.markdown(report)
    assert "answer to drawable clip" in text and "(goal ≤ 1 s: met)" in text and "data JSON" in text
