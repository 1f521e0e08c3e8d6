"""benchmarks/clip_parts.py, tiny: both ways measured on the same clips, every frame counted in the joined clips."""

import json
import sys

import pytest

from rba.core.settings import REPO_ROOT
from tests.benchmark_scripts import load_benchmark


@pytest.fixture
def clip_parts(monkeypatch):
    monkeypatch.syspath_prepend(str(REPO_ROOT / "benchmarks"))  # it imports api_load's helpers, as when run
    yield load_benchmark("clip_parts")
    sys.modules.pop("api_load", None)


def test_measures_whole_and_parts_on_the_same_clips(clip_parts, tmp_path, capsys):
    out = tmp_path / "parts"
    assert clip_parts.main(["--domains", "lane_change", "--clips", "2", "--out", str(out)]) == 0
    (row,) = json.loads(out.with_suffix(".json").read_text())["domains"]
    assert row["domain"] == "lane_change" and row["clips"] == 2 and row["all_frames_in_parts"] is True
    assert row["whole"]["mean_ms"] > 0 and row["parts"]["mean_ms"] > 0 and row["parts"]["kb_mean"] > 1
    assert "| lane_change | 2 |" in out.with_suffix(".md").read_text()
    with pytest.raises(SystemExit) as exit_:
        clip_parts.main(["--clips", "1"])
    assert exit_.value.code == 2 and "--clips must be in 2..200, got 1" in capsys.readouterr().err
