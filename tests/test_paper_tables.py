"""benchmarks/paper_tables.py: a re-measured row replaces the merged one; the others are kept."""

import importlib.util

import pytest

from rba.evaluate import EvalResult
from rba.settings import REPO_ROOT
from rba.storage import save_json

spec = importlib.util.spec_from_file_location("paper_tables", REPO_ROOT / "benchmarks" / "paper_tables.py")
paper_tables = importlib.util.module_from_spec(spec)
spec.loader.exec_module(paper_tables)


def _result(domain: str, precision: str, sr: float) -> EvalResult:
    return EvalResult(domain, "global", "onehot", precision, "paper", 0, sr, 2.0, 1.0, 3.0, [])


def _save(path, rows):
    save_json(path, paper_tables.json_rows([(r.domain, label, r) for label, r in rows]))


def test_merge_keeps_rows_this_run_did_not_measure(tmp_path):
    _save(tmp_path / "t.json", [("RBA-Global", _result(d, p, 0.5))
                                for d, p in (("walker", "normal"), ("walker", "high"), ("snake", "normal"))])
    fresh = [("walker", "RBA-Global", _result("walker", "normal", 1.0))]
    rows = paper_tables.merged(fresh, [tmp_path / "t.json"])
    got = {(d, r.precision): r.success_rate for d, _, r in rows}
    assert got == {("snake", "normal"): 0.5, ("walker", "normal"): 1.0, ("walker", "high"): 0.5}
    text = paper_tables.markdown(rows, ["snake", "walker"], ["normal"], 20, 0, 60.0)
    assert "| walker | RBA-Global | 1.00 / 2.00 (1.00) | 1.00 / 3.75 (1.47) |" in text


def test_report_only_combines_parallel_runs_later_file_wins(tmp_path):
    _save(tmp_path / "a.json", [("RBA-Global", _result("walker", "normal", 0.5)),
                                ("PbRL", _result("snake", "high", 0.25))])
    _save(tmp_path / "b.json", [("RBA-Global", _result("walker", "normal", 0.9))])
    out = tmp_path / "t.md"
    paper_tables.main(["--report-only", "--merge", str(tmp_path / "a.json"), str(tmp_path / "b.json"),
                       "--precisions", "high", "--out", str(out)])
    text = out.read_text()
    assert "| walker | RBA-Global | 0.90 / 2.00 (1.00) |" in text
    assert "| snake | PbRL | 0.25 / 2.00 (1.00) |" in text
    assert "0.50 /" not in text
    assert "## Table 1" in text and "## Table 2" in text  # a merged report shows every precision it has rows for


def test_rows_stored_before_teacher_kinds_merge_with_their_user(tmp_path):
    old = [{**row, "noise": 0.0 if row["domain"] == "walker" else 0.2}
           for row in paper_tables.json_rows([("walker", "RBA-Global", _result("walker", "high", 0.5)),
                                              ("snake", "RBA-Global", _result("snake", "high", 0.5))])]
    for row in old:
        del row["user"]
    save_json(tmp_path / "old.json", old)
    rows = paper_tables.merged([], [tmp_path / "old.json"])
    assert {(d, r.user) for d, _, r in rows} == {("walker", "paper"), ("snake", "mistake:0.2")}


def test_report_only_without_merge_says_what_is_missing(capsys):
    with pytest.raises(SystemExit):
        paper_tables.main(["--report-only"])
    assert "--report-only needs --merge" in capsys.readouterr().err


def test_check_says_which_rows_differ_from_the_report(tmp_path):
    _save(tmp_path / "t.json", [("RBA-Global", _result("walker", "normal", 1.0)),
                                ("RBA-Global", _result("walker", "high", 0.9))])
    rows = [("walker", "RBA-Global", _result("walker", "normal", 1.0)),
            ("walker", "RBA-Global", _result("walker", "high", 0.85)),
            ("snake", "PbRL", _result("snake", "high", 0.5))]
    text, same = paper_tables.check(rows, tmp_path / "t.json")
    assert not same
    assert "| walker | RBA-Global | normal | 1.00 / 2.00 (1.00) | 1.00 / 2.00 (1.00) | yes |" in text
    assert "| walker | RBA-Global | high | 0.90 / 2.00 (1.00) | 0.85 / 2.00 (1.00) | NO |" in text
    assert "| snake | PbRL | high | missing |" in text
    assert paper_tables.check(rows[:1], tmp_path / "t.json")[1]
