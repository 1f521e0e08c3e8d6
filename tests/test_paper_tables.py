"""benchmarks/paper_tables.py: a re-measured row replaces the merged one; the others are kept."""

import importlib.util

from rba.evaluate import EvalResult
from rba.paths import REPO_ROOT
from rba.storage import save_json

spec = importlib.util.spec_from_file_location("paper_tables", REPO_ROOT / "benchmarks" / "paper_tables.py")
paper_tables = importlib.util.module_from_spec(spec)
spec.loader.exec_module(paper_tables)


def _result(domain: str, precision: str, sr: float) -> EvalResult:
    return EvalResult(domain, "global", "onehot", precision, 0.0, 0, sr, 2.0, 1.0, 3.0, [])


def test_merge_keeps_rows_this_run_did_not_measure(tmp_path):
    earlier = [{"label": "RBA-Global", **_result(d, p, 0.5).to_json()}
               for d, p in (("walker", "normal"), ("walker", "high"), ("snake", "normal"))]
    save_json(tmp_path / "t.json", [{k: v for k, v in row.items() if k != "trials"} for row in earlier])
    fresh = [("walker", "RBA-Global", 0, _result("walker", "normal", 1.0))]
    rows = paper_tables.merged(fresh, tmp_path / "t.json")
    got = {(d, r.precision): r.success_rate for d, _, _, r in rows}
    assert got == {("snake", "normal"): 0.5, ("walker", "normal"): 1.0, ("walker", "high"): 0.5}
    text = paper_tables.markdown(rows, ["snake", "walker"], ["normal"], 20, 0, 60.0)
    assert "| walker | RBA-Global | 1.00 / 2.00 (1.00) | 1.00 / 3.75 (1.47) |" in text
