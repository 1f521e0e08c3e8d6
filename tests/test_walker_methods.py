"""benchmarks/walker_methods.py: every registered method, the reference rows included, gets a row."""

import json

from rba.core.settings import REPO_ROOT
from tests.benchmark_scripts import load_benchmark


def test_reference_rows_are_reported_beside_the_methods(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(REPO_ROOT / "benchmarks"))  # it reads the paper's numbers from paper_tables
    walker_methods = load_benchmark("walker_methods")
    out = tmp_path / "walker_methods.md"
    assert walker_methods.main(["--targets", "1", "--methods", "global", "random", "oracle", "--noise",
                                "--note", "a hand note", "--out", str(out)]) == 0
    rows = json.loads(out.with_suffix(".json").read_text())
    assert [r["label"] for r in rows] == ["RBA-Global", "RBA-Global-L", "Random", "Oracle"]
    text = out.read_text()
    assert "| RBA-Global | onehot | paper | 1.00 |" in text and "| 1.00 | 3.75 (1.47) |" in text  # the paper's row
    assert "| Oracle | – | paper |" in text and "- a hand note" in text
    assert "--note …" in text and "a hand note`" not in text  # the note is in the notes, not in the command
