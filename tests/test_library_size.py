"""benchmarks/library_size.py on the toy domain: both modes per size, rows of other runs kept, bad sizes refused."""

import json

import pytest

from tests.benchmark_scripts import load_benchmark

library_size = load_benchmark("library_size")


def test_measures_each_size_alone_and_generating_and_keeps_other_rows(toy_env, tmp_path, capsys):
    out = tmp_path / "size"
    base = ["--domains", "toy", "--precision", "high", "--out", str(out)]
    assert library_size.main([*base, "--targets", "3", "--sizes", "20", "300"]) == 0
    rows = json.loads(out.with_suffix(".json").read_text())["rows"]
    assert [(r["size"], r["mode"]) for r in rows] == [(20, "library"), (20, "gen"), (300, "library"), (300, "gen")]
    small, small_gen = rows[0], rows[1]
    assert small["generation"] is None and small_gen["generation"]["searches"] > 0  # 20 clips: targets need making
    for r in rows:  # answers in all: the successes' answers, and the whole budget for each failure
        hits = round(r["success_rate"] * r["targets"])
        assert r["answers"] == pytest.approx((r["avg_feedback"] or 0.0) * hits + 500 * (r["targets"] - hits))
    assert library_size.main([*base, "--targets", "3", "--sizes", "20", "--modes", "gen"]) == 0  # the others kept
    again = json.loads(out.with_suffix(".json").read_text())["rows"]
    assert len(again) == 4 and {(r["size"], r["mode"]) for r in again} == {(r["size"], r["mode"]) for r in rows}
    assert "| toy | 20 | gen | 3 |" in out.with_suffix(".md").read_text()
    for other in (["--split", "val"], ["--targets", "2"]):  # another setting: its rows are not mixed with these
        assert library_size.main([*base, "--targets", "3", "--sizes", "20", "--modes", "gen", *other]) == 0
        assert len(json.loads(out.with_suffix(".json").read_text())["rows"]) == 1
    for bad, says in ((["--sizes", "1"], "--sizes are numbers of serve clips (at least 2), got 1"),
                      (["--gen-workers", "0"], "--gen-workers must be at least 1, got 0")):
        with pytest.raises(SystemExit) as exit_:
            library_size.main([*base, *bad])
        assert exit_.value.code == 2 and says in capsys.readouterr().err
