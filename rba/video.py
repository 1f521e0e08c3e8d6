"""MP4 encoding for browsers: H.264, yuv420p, moov atom first (faststart)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from rba.storage import write_atomic


def write_mp4(frames: Iterable[np.ndarray], path: Path, fps: float) -> int:
    """Encode HxWx3 uint8 frames to ``path`` atomically; returns the number of frames."""
    count: list[int] = []
    write_atomic(Path(path), lambda tmp: count.append(encode_mp4(frames, Path(tmp), fps)))
    return count[0]


def encode_mp4(frames: Iterable[np.ndarray], path: Path, fps: float) -> int:
    """Encode HxWx3 uint8 frames into ``path`` as it is (callers make it atomic); returns the number of frames."""
    import imageio_ffmpeg

    count = 0
    writer = None
    try:
        for frame in frames:
            if writer is None:
                h, w = frame.shape[:2]
                writer = imageio_ffmpeg.write_frames(
                    str(path), (w, h), fps=fps, codec="libx264", pix_fmt_out="yuv420p", quality=None,
                    output_params=["-movflags", "+faststart", "-crf", "23", "-preset", "veryfast", "-f", "mp4"],
                    macro_block_size=2, ffmpeg_log_level="error")
                writer.send(None)
            writer.send(np.ascontiguousarray(frame))
            count += 1
    finally:
        if writer is not None:
            writer.close()
    if count == 0:
        raise ValueError("no frames to encode")
    return count
