"""The walker end to end: the tiny CI preset of the whole pipeline, and the shipped artifacts."""

import pytest

from rba.artifacts import load_model
from rba.cli import main
from rba.evaluate import evaluate
from rba.library import SkillLibrary, build_all
from rba.paths import REPO_ROOT
from rba.training import GlobalTrainConfig, train_global


@pytest.mark.slow
def test_tiny_preset_end_to_end(tmp_path):
    data, models = tmp_path / "data", tmp_path / "models"
    build_all("walker", seed=5, sizes={"train": 80, "serve": 160, "test": 12}, root=data, progress=False)
    cfg = GlobalTrainConfig.preset("tiny", seed=0)
    metrics = train_global("walker", "onehot", cfg, data_root=data, models_root=models)
    for name in ("step_size", "softness"):
        assert metrics["ranker"][name]["pairwise_accuracy"] > 0.8, metrics
    result = evaluate("walker", "global", "onehot", targets=6, seed=0, data_root=data, models_root=models)
    assert sum(t.success for t in result.trials) >= 2, [t.feedback_count for t in result.trials]


def test_shipped_artifacts_serve_a_fresh_clone():
    """The committed walker libraries and models load, match each other, and reach targets."""
    data, models = REPO_ROOT / "data", REPO_ROOT / "models"
    serve = SkillLibrary.load("walker", "serve", data)
    assert len(serve) >= 1000
    for rep in ("onehot", "language"):
        for kind in ("ranker", "global_reward"):
            card = load_model("walker", kind, rep, models).card
            assert card["data"]["serve"] == serve.version, f"{kind}-{rep} was trained on another library"
    result = evaluate("walker", "global", "onehot", targets=5, seed=1, data_root=data, models_root=models)
    assert result.success_rate >= 0.8


def test_render_cli_writes_a_browser_playable_mp4(tmp_path, capsys):
    out = tmp_path / "clip.mp4"
    assert main(["render", "walker", "test-00003", str(out), "--width", "160", "--height", "120"]) == 0
    blob = out.read_bytes()
    assert blob[4:8] == b"ftyp" and blob.index(b"moov") < blob.index(b"mdat")
    assert "frames at 30 fps" in capsys.readouterr().out
