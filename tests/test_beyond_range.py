"""benchmarks/beyond_range.py on the toy domain: both modes on the same targets, earlier rows kept."""

import json

import pytest

from tests.benchmark_scripts import load_benchmark

beyond_range = load_benchmark("beyond_range")


def test_measures_both_modes_and_keeps_rows_of_the_same_setting(toy_roots, monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("RBA_DATA_DIR", str(toy_roots[0]))
    monkeypatch.setenv("RBA_MODELS_DIR", str(toy_roots[1]))
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
