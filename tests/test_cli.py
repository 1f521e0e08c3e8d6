"""The CLI: bad input is one line naming the valid choices, exit status 2."""

import json

import pytest

from rba.cli import main


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["build", "atlantis"], "unknown domain 'atlantis'; valid: walker"),
        (["eval", "--domain", "walker", "--method", "magic"], "invalid choice: 'magic'"),
        (["eval", "--domain", "walker", "--user", "grumpy"],
         "unknown user kind 'grumpy'; valid: paper, mistake, skip, equal, myopic, boundary, inconsistent"),
        (["eval", "--domain", "walker", "--user", "mistake:0.7"],
         "user kind 'mistake' takes a flip probability in [0, 0.5), got 0.7"),
        (["eval", "--domain", "walker", "--user", "skip:often"], "user kind 'skip' takes a number"),
        (["eval", "--domain", "walker", "--user", "paper:1"], "user kind 'paper' takes no parameter"),
        (["train", "walker", "--rep", "braille"], "invalid choice: 'braille'"),
    ],
)
def test_bad_arguments_exit_2(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_user_specs_parse_to_teacher_kinds():
    from rba.cli import build_parser
    from rba.interact.users import UserSpec

    assert build_parser().parse_args(["eval", "--domain", "walker", "--user", "equal:3"]).user == UserSpec("equal", 3.0)
    assert build_parser().parse_args(["eval", "--domain", "walker"]).user == UserSpec("paper", None)


def test_unknown_rollout_id_exits_2(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("RBA_DATA_DIR", str(tmp_path))
    assert main(["render", "walker", "../../etc/passwd", str(tmp_path / "x.mp4")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rba: error: unknown rollout id '../../etc/passwd'") and err.count("\n") == 1


def test_states_pick_the_registered_view(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("RBA_DATA_DIR", str(tmp_path))
    assert main(["eval", "--domain", "walker", "--states", "image"]) == 2
    assert capsys.readouterr().err == "rba: error: domain 'walker' has no 'image' states; valid: kinematic, raw\n"
    assert main(["eval", "--domain", "lane_change", "--states", "colour"]) == 2
    assert "valid: kinematic, image, raw" in capsys.readouterr().err
    # --states image reaches the lane_change_image domain (whose library this empty data dir lacks)
    assert main(["render", "lane_change", "serve-00001", str(tmp_path / "x.mp4"), "--states", "image"]) == 2
    assert "run `rba build lane_change_image`" in capsys.readouterr().err


def test_missing_library_exits_2(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("RBA_DATA_DIR", str(tmp_path))
    assert main(["render", "walker", "serve-00001", str(tmp_path / "x.mp4")]) == 2
    assert "run `rba build walker`" in capsys.readouterr().err


def test_eval_and_render_on_toy(toy_roots, tmp_path, monkeypatch, capsys):
    data, models, _ = toy_roots
    monkeypatch.setenv("RBA_DATA_DIR", str(data))
    monkeypatch.setenv("RBA_MODELS_DIR", str(models))
    out = tmp_path / "r.json"
    assert main(["eval", "--domain", "toy", "--targets", "3", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert set(result) >= {"success_rate", "avg_feedback", "std_feedback", "trials"}
    assert len(result["trials"]) == 3 and "shown" in result["trials"][0]
    assert "| toy | global | onehot | normal |" in capsys.readouterr().out
    clip = tmp_path / "c.mp4"
    assert main(["render", "toy", "serve-00003", str(clip)]) == 0
    head = clip.read_bytes()[:64]
    assert b"ftyp" in head and b"moov" in clip.read_bytes()[:4096]  # faststart: moov before mdat


def test_cache_renders_every_clip_once(toy_roots, tmp_path, monkeypatch, capsys):
    from rba.cli import main

    data, _, _ = toy_roots
    monkeypatch.setenv("RBA_DATA_DIR", str(data))
    monkeypatch.setenv("RBA_CACHE_DIR", str(tmp_path / "clips"))
    assert main(["cache", "toy", "--split", "test", "--width", "64", "--height", "48"]) == 0
    assert len(list((tmp_path / "clips").rglob("*.mp4"))) == 40
    assert "40 rendered" in capsys.readouterr().out
    assert main(["cache", "toy", "--split", "test", "--width", "64", "--height", "48"]) == 0
    out = capsys.readouterr().out
    assert "0 rendered" in out and "40 were cached already" in out
