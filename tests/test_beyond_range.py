"""benchmarks/beyond_range.py on the toy domain: both modes on the same targets, earlier rows kept."""

import json

import pytest

from tests.benchmark_scripts import load_benchmark

beyond_range = load_benchmark("beyond_range")


def test_measures_both_modes_and_keeps_rows_of_the_same_setting(toy_env, tmp_path, capsys):
    out = tmp_path / "b"
    base = ["--domains", "toy", "--targets", "3", "--out", str(out)]
    assert beyond_range.main(base) == 0
    rows = json.loads(out.with_suffix(".json").read_text())["rows"]
    library, gen = sorted(rows, key=lambda r: r["mode"] != "library")
    assert (library["mode"], gen["mode"]) == ("library", "gen") and library["targets"] == gen["targets"] == 3
    assert library["generation"] is None and gen["generation"]["searches"] >= 0
    assert beyond_range.main([*base, "--modes", "gen"]) == 0  # one row again: the other is kept
    assert [r["mode"] for r in json.loads(out.with_suffix(".json").read_text())["rows"]] == ["library", "gen"]
    assert beyond_range.main([*base, "--modes", "gen", "--share", "0.2"]) == 0  # another setting: not mixed
    assert len(json.loads(out.with_suffix(".json").read_text())["rows"]) == 1
    assert "| toy | gen | 3 |" in out.with_suffix(".md").read_text()
    assert beyond_range.main([*base, "--modes", "gen", "--share", "0.2", "--gen-seconds", "1e-9"]) == 0
    unbounded, bounded = json.loads(out.with_suffix(".json").read_text())["rows"]  # both kept: the bound is the row's
    assert unbounded["bound_s"] is None and bounded["bound_s"] == 1e-9
    assert "| 1e-09 s |" in out.with_suffix(".md").read_text()
    assert bounded["generation"]["simulations"] == 8 * bounded["generation"]["searches"]  # one generation each
    for bad in ("0", "nan"):
        with pytest.raises(SystemExit) as exit_:
            beyond_range.main([*base, "--gen-seconds", bad])
        assert exit_.value.code == 2
        assert f"must be a number of seconds > 0, got {bad}" in capsys.readouterr().err


def test_gen_workers_simulate_elsewhere_and_give_the_same_unbounded_row(toy_env, tmp_path, capsys):
    base = ["--domains", "toy", "--targets", "3", "--modes", "gen", "--precision", "high"]  # long enough to search
    rows = []
    for workers in ("1", "2"):
        out = tmp_path / workers
        assert beyond_range.main([*base, "--gen-workers", workers, "--out", str(out)]) == 0
        (row,) = json.loads(out.with_suffix(".json").read_text())["rows"]
        timeless = {k: v for k, v in row["generation"].items() if not k.startswith("seconds")}
        rows.append({"success_rate": row["success_rate"], "avg_feedback": row["avg_feedback"], **timeless})
    assert rows[0] == rows[1] and rows[0]["simulations"] > 0
    with pytest.raises(SystemExit) as exit_:
        beyond_range.main([*base, "--gen-workers", "0"])
    assert exit_.value.code == 2 and "--gen-workers must be at least 1, got 0" in capsys.readouterr().err
