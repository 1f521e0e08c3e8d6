"""MP4 encoding: the same frames give the same bytes (in this process and in others), bad input fails loudly."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rba.media.video import concat_mp4, encode_mp4, ffmpeg_command, write_mp4

REPO_ROOT = Path(__file__).resolve().parents[1]


def _frames(n: int = 12, width: int = 32, height: int = 24) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    return [np.roll(base, k, axis=1) for k in range(n)]  # moving content: P and B frames, not only I frames


def _boxes(data: bytes) -> list[bytes]:
    """The top-level MP4 box types, in order."""
    boxes, at = [], 0
    while at + 8 <= len(data):
        size = int.from_bytes(data[at:at + 4], "big")
        boxes.append(data[at + 4:at + 8])
        at += size if size >= 8 else len(data)
    return boxes


def test_the_same_frames_give_the_same_bytes(tmp_path):
    a, b = tmp_path / "a.mp4", tmp_path / "b.mp4"
    assert encode_mp4(_frames(), a, 30.0) == 12
    assert encode_mp4(iter(_frames()), b, 30.0) == 12
    assert a.read_bytes() == b.read_bytes()
    boxes = _boxes(a.read_bytes())
    assert boxes[0] == b"ftyp" and boxes.index(b"moov") < boxes.index(b"mdat")  # faststart: playable while loading


def _decoded(data: bytes, tmp: Path) -> list[bytes]:
    import imageio_ffmpeg

    path = tmp / f"{hashlib.sha256(data).hexdigest()[:12]}.mp4"
    path.write_bytes(data)
    reader = imageio_ffmpeg.read_frames(str(path))
    next(reader)  # the stream's metadata
    return [bytes(frame) for frame in reader]


def test_parts_join_into_one_clip_with_every_frame_of_each(tmp_path):
    """The compute layer encodes a clip's parts on separate workers: joined, they play as one clip, frame for
    frame what each part holds (stream copy: nothing re-encoded), playable while loading, the same bytes again."""
    frames = _frames(12)
    parts = []
    for i, rows in enumerate((slice(0, 5), slice(5, 12))):
        encode_mp4(frames[rows], tmp_path / f"part{i}.mp4", 30.0)
        parts.append((tmp_path / f"part{i}.mp4").read_bytes())
    clip = concat_mp4(parts)
    assert _decoded(clip, tmp_path) == _decoded(parts[0], tmp_path) + _decoded(parts[1], tmp_path)
    assert len(_decoded(clip, tmp_path)) == 12 and concat_mp4(parts) == clip
    boxes = _boxes(clip)
    assert boxes[0] == b"ftyp" and boxes.index(b"moov") < boxes.index(b"mdat")
    assert concat_mp4(parts[:1]) == parts[0]


def test_joining_nothing_or_a_broken_part_fails(tmp_path):
    with pytest.raises(ValueError, match="no parts"):
        concat_mp4([])
    encode_mp4(_frames(3), tmp_path / "ok.mp4", 30.0)
    with pytest.raises(RuntimeError, match="could not join 2 parts"):
        concat_mp4([(tmp_path / "ok.mp4").read_bytes(), b"not an mp4"])


def test_x264_threads_are_fixed_not_the_cpu_count(tmp_path):
    """x264's default thread count follows the CPU count, and the thread count changes the output."""
    cmd = ffmpeg_command(32, 24, 30.0, tmp_path / "x.mp4")
    assert cmd[cmd.index("-threads") + 1] == "1" and cmd[cmd.index("-filter_threads") + 1] == "1"


def test_odd_sizes_are_padded_to_even(tmp_path):
    assert write_mp4(_frames(3, 31, 23), tmp_path / "odd.mp4", 12.0) == 3
    assert (tmp_path / "odd.mp4").stat().st_size > 0


def test_bad_input_fails(tmp_path):
    with pytest.raises(ValueError, match="no frames"):
        encode_mp4([], tmp_path / "none.mp4", 30.0)
    with pytest.raises(ValueError, match="uint8"):
        encode_mp4([np.zeros((24, 32, 3), np.float32)], tmp_path / "float.mp4", 30.0)
    mixed = [_frames(1)[0], np.zeros((24, 30, 3), np.uint8)]
    with pytest.raises(ValueError, match="frame 1"):
        encode_mp4(mixed, tmp_path / "mixed.mp4", 30.0)


def test_a_rendering_error_reaches_the_caller(tmp_path):
    def frames():
        yield from _frames(2)
        raise RuntimeError("renderer died")

    with pytest.raises(RuntimeError, match="renderer died"):
        write_mp4(frames(), tmp_path / "x.mp4", 30.0)
    assert not (tmp_path / "x.mp4").exists()  # atomic: no half-written clip


WALKER_CLIP = """
import hashlib, os, sys, tempfile
if sys.argv[1:] == ["one-cpu"]:  # before anything starts threads: x264 and llvmpipe see one CPU
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
from pathlib import Path
import numpy as np
from rba.domains.base import Rollout
from rba.domains.walker import Walker
from rba.media.video import encode_mp4
walker = Walker()
q0 = walker.physics().model.qpos0.copy()
t = np.linspace(0, 1, 15)[:, None]
replay = q0 + np.concatenate([0.3 * t, np.zeros((15, 2)), 0.4 * np.sin(6 * t) * np.ones((1, 6))], axis=1)
rollout = Rollout("", "walker", {}, 0, np.zeros((2, 1), np.float32), replay, {}, True)
path = Path(tempfile.mkdtemp()) / "clip.mp4"
encode_mp4(walker.render(rollout, 96, 64), path, 30.0)
print(hashlib.sha256(path.read_bytes()).hexdigest())
"""


def test_a_walker_clip_is_byte_identical_in_separate_processes():
    """What a clip's ETag promises: rendering and encoding depend on nothing of the process, not even
    on how many CPUs it may use (x264's default thread count would follow them)."""
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    procs = [subprocess.Popen([sys.executable, "-c", WALKER_CLIP, *arg], env=env, cwd=REPO_ROOT, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE) for arg in ([], ["one-cpu"])]
    outs = [p.communicate(timeout=120) for p in procs]
    assert all(p.returncode == 0 for p in procs), [err[-2000:] for _, err in outs]
    digests = [out.strip().splitlines()[-1] for out, _ in outs]
    assert len(digests[0]) == len(hashlib.sha256().hexdigest()) and digests[0] == digests[1]
