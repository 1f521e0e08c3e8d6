"""MP4 encoding for browsers: H.264, yuv420p, moov atom first (faststart).

The same frames give the same bytes in any process, on any machine with the same ffmpeg: x264's
thread count is fixed (by default it follows the CPU count, and the number of threads changes
the output), the RGB to YUV conversion runs on one thread with swscale's bit-exact paths, and
the muxer leaves out its version tag. One thread is enough: x264 at ``veryfast`` needs about
0.5 ms a 320x240 frame, less than rendering one, and it runs in its own process beside the renderer.

ffmpeg is started directly instead of through ``imageio_ffmpeg.write_frames``, which forks the
whole process (its ``preexec_fn`` rules out vfork) and polls for ffmpeg's exit every 10 ms:
together ~10 ms of each clip. See ``benchmarks/clip_cost.py``.
"""

from __future__ import annotations

import contextlib
import itertools
import subprocess
import tempfile
from collections.abc import Iterable, Iterator
from fractions import Fraction
from pathlib import Path

import numpy as np

from rba.core.fileio import write_atomic

# x264 at crf 23 / veryfast: ~20-60 kB a clip. ultrafast encodes 10-40 ms a clip faster but gives
# 2-5x larger files (no mb-tree), over 150 kB for the walker's starry sky; superfast is bigger and hardly faster
X264 = ("-c:v", "libx264", "-preset", "veryfast", "-crf", "23", "-threads", "1")
BIT_EXACT = ("-filter_threads", "1", "-sws_flags", "bicubic+accurate_rnd+bitexact")


def write_mp4(frames: Iterable[np.ndarray], path: Path, fps: float) -> int:
    """Encode HxWx3 uint8 frames to ``path`` atomically; returns the number of frames."""
    count: list[int] = []
    write_atomic(Path(path), lambda tmp: count.append(encode_mp4(frames, Path(tmp), fps)))
    return count[0]


def ffmpeg_command(width: int, height: int, fps: float, path: Path) -> list[str]:
    """ffmpeg reading rgb24 frames of ``width`` x ``height`` from stdin, writing the MP4 to ``path``.

    yuv420p needs even sides: odd ones are scaled up by a pixel, as imageio-ffmpeg did."""
    import imageio_ffmpeg

    size = ["-vf", f"scale={width + width % 2}:{height + height % 2}"] if width % 2 or height % 2 else []
    return [imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-nostdin", "-loglevel", "error", *BIT_EXACT,
            "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}",
            "-r", str(Fraction(fps).limit_denominator()), "-i", "-",
            "-an", *size, *X264, "-pix_fmt", "yuv420p", "-movflags", "+faststart", "-fflags", "+bitexact",
            "-f", "mp4", "-y", str(path)]


def encode_mp4(frames: Iterable[np.ndarray], path: Path, fps: float) -> int:
    """Encode HxWx3 uint8 frames into ``path`` as it is (callers make it atomic); returns the number of frames.

    Frames are piped to ffmpeg as they come, so encoding overlaps rendering."""
    frames = iter(frames)
    first = next(frames, None)
    if first is None:
        raise ValueError("no frames to encode")
    if first.ndim != 3 or first.shape[2] != 3 or first.dtype != np.uint8:
        raise ValueError(f"frames must be HxWx3 uint8, got {first.shape} {first.dtype}")
    height, width = first.shape[:2]
    with tempfile.TemporaryFile() as errors:  # a file, not a pipe: ffmpeg can never block on it
        proc = subprocess.Popen(ffmpeg_command(width, height, fps, Path(path)), stdin=subprocess.PIPE,
                                stdout=subprocess.DEVNULL, stderr=errors,
                                process_group=0)  # a Ctrl-C in a terminal stops us, not ffmpeg mid-file
        try:
            count = _feed(proc.stdin, first, frames)
        except BrokenPipeError:
            count = 0  # ffmpeg quit early: its exit code and message say why
        except BaseException:
            proc.kill()
            proc.wait()
            raise
        code = proc.wait()
        if code != 0 or count == 0:
            errors.seek(0)
            raise RuntimeError(f"ffmpeg failed ({code}): {errors.read().decode(errors='replace').strip()}")
    return count


def concat_mp4(parts: list[bytes]) -> bytes:
    """One MP4 of ``parts`` (each from ``encode_mp4``, same size and rate) played one after the other.

    Stream copy through ffmpeg's concat demuxer: no re-encoding, a few tens of ms. Each part starts
    on a key frame, so parts encoded in separate processes join into one clip that plays through."""
    import imageio_ffmpeg

    if not parts:
        raise ValueError("no parts to join")
    if len(parts) == 1:
        return parts[0]
    with tempfile.TemporaryDirectory(prefix="rba-clip-join-") as tmp:  # swept as rba-clip-*
        folder = Path(tmp)
        for i, part in enumerate(parts):
            (folder / f"{i}.mp4").write_bytes(part)
        (folder / "parts.txt").write_text("".join(f"file '{i}.mp4'\n" for i in range(len(parts))))
        out = folder / "clip.mp4"
        done = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-nostdin", "-loglevel", "error",
                               "-xerror", "-f", "concat", "-safe", "0", "-i", str(folder / "parts.txt"), "-c", "copy",
                               "-movflags", "+faststart", "-fflags", "+bitexact", "-f", "mp4", "-y", str(out)],
                              capture_output=True, text=True, process_group=0)
        if done.returncode != 0 or done.stderr.strip():  # without -xerror it skipped a broken part and exited 0
            raise RuntimeError(f"ffmpeg could not join {len(parts)} parts ({done.returncode}): {done.stderr.strip()}")
        return out.read_bytes()


def _feed(stdin, first: np.ndarray, rest: Iterator[np.ndarray]) -> int:
    """Write the frames to ffmpeg's stdin and close it; returns how many were written."""
    count = 0
    with contextlib.closing(stdin):
        for frame in itertools.chain((first,), rest):
            if frame.shape != first.shape or frame.dtype != first.dtype:
                raise ValueError(f"frame {count} is {frame.shape} {frame.dtype}, the first {first.shape} {first.dtype}")
            stdin.write(np.ascontiguousarray(frame).data)
            count += 1
    return count
