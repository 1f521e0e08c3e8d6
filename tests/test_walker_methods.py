"""benchmarks/walker_methods.py: every registered method, the reference rows included, gets a row."""

import importlib.util
import json

from rba.settings import REPO_ROOT

spec = importlib.util.spec_from_file_location("walker_methods", REPO_ROOT / "benchmarks" / "walker_methods.py")
walker_methods = importlib.util.module_from_spec(spec)
spec.loader.exec_module(walker_methods)


def test_reference_rows_are_reported_beside_the_methods(tmp_path):
    out = tmp_path / "walker_methods.md"
    assert walker_methods.main(["--targets", "1", "--methods", "global", "random", "oracle", "--noise",
                                "--note", "a hand note", "--out", str(out)]) == 0
    rows = json.loads(out.with_suffix(".json").read_text())
    assert [r["label"] for r in rows] == ["RBA-Global", "RBA-Global-L", "Random", "Oracle"]
    text = out.read_text()
    assert "| Oracle | – | paper |" in text and "- a hand note" in text
    assert "--note …" in text and "a hand note`" not in text  # the note is in the notes, not in the command
