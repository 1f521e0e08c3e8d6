"""The walker from the command line: rendering a clip a browser plays."""


from rba.cli import main


def test_render_cli_writes_a_browser_playable_mp4(tmp_path, capsys):
    out = tmp_path / "clip.mp4"
    assert main(["render", "walker", "test-00003", str(out), "--width", "160", "--height", "120"]) == 0
    blob = out.read_bytes()
    assert blob[4:8] == b"ftyp" and blob.index(b"moov") < blob.index(b"mdat")
    assert "frames at 30 fps" in capsys.readouterr().out
