"""Clip cost: where a clip's time goes (replay, rendering, encoding), per domain, before and after.

For each domain a fixed spread of ``--clips`` rollouts of the serve library is rendered at the
clip size (320x240 by default) under each configuration, in one run, the configurations taking
turns clip by clip so that a change in machine load hits them alike:

* ``before``: the renderer before its per-frame savings (commit 0c32c5c), mirrored here: a full
  ``mj_forward`` per frame, a copy of every frame, the skybox drawn in every frame, the floor's
  reflection in every MuJoCo domain,
  the snake's floor drawn with quads 0.1 m apart, highway-env's column-major read-back, and
  ``imageio_ffmpeg.write_frames`` with x264 ``veryfast`` / crf 23 and x264's default threads;
* ``after``: the production code (``rba.media.video.encode_mp4``, ``rba.domains.mujoco_render``, the
  domains' render functions);
* options not taken, measured for the report: ``no-sky`` (``after`` without the skybox) and
  ``ultrafast`` (``after`` with x264's ``ultrafast`` preset).

Stages, each timed on its own: *replay* = posing the model (setting qpos, the MuJoCo position
pass, the camera's aim, ``update_scene``; for the lane change, placing the cars); *render* = the
GL render and read-back (``Renderer.render``; for the lane change, highway-env's drawing and
the read-back); *encode* = piping the frames, already in memory, through ffmpeg to an MP4. The
stage loop mirrors ``ThreadRenderers.replay`` (and the lane change's render) with timers; for
``after`` its frames are checked against the production ``render``. *streamed* is the clip in one
process, frames piped to ffmpeg as they are rendered (so encoding overlaps rendering), as a compute
worker makes each part of a clip (the parts run on separate workers: ``clip_parts.py``).
A warm-up clip per configuration comes first; the renderer's creation (EGL context, MuJoCo's GL
context; highway-env's environment) is timed on its own. Writes
``benchmarks/results/clip_cost.md`` and ``.json``.

    python benchmarks/clip_cost.py                                # 4 domains, 8 clips, before and after
    python benchmarks/clip_cost.py --domains walker --clips 3     # a quick look
    python benchmarks/clip_cost.py --configs after no-sky ultrafast --out benchmarks/results/clip_cost_options
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import json
import logging
import os
import platform
import resource
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import mujoco
import numpy as np

from rba.core.fileio import report_path, save_markdown, save_text
from rba.core.settings import LibrarySettings
from rba.data.library import SkillLibrary
from rba.domains import get_domain
from rba.domains import lane_change as lane
from rba.domains.base import Domain, Rollout
from rba.domains.mujoco_render import Camera, Sky, ThreadRenderers, render_over_sky, sky_alone
from rba.media import video

log = logging.getLogger("clip_cost")

RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "clip_cost.json", "clip_cost.md",
)
DOMAINS = ("walker", "manipulator", "snake", "lane_change")
Encoder = Callable[[Iterable[np.ndarray], Path, float], int]


# ---------------------------------------------------------------- the configurations

def encode_main(frames: Iterable[np.ndarray], path: Path, fps: float) -> int:
    """``rba.media.video.encode_mp4`` as it was on main before this change (imageio-ffmpeg, x264's default threads)."""
    import imageio_ffmpeg

    count, writer = 0, None
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
    return count


def encode_preset(preset: str) -> Encoder:
    """The production encoder with another x264 preset."""
    def encode(frames: Iterable[np.ndarray], path: Path, fps: float) -> int:
        saved = video.X264
        video.X264 = tuple(preset if i and saved[i - 1] == "-preset" else a for i, a in enumerate(saved))
        try:
            return video.encode_mp4(frames, path, fps)
        finally:
            video.X264 = saved
    return encode


def lane_frame_main(env) -> np.ndarray:
    """The lane change's read-back on main: highway-env's column-major ``surfarray``, then a transposed copy."""
    return np.ascontiguousarray(env.render())


@dataclass(frozen=True)
class Config:
    name: str
    about: str
    production: bool  # the streamed clip is the production ``domain.render`` (else this mirror)
    pose: Callable[[mujoco.MjModel, mujoco.MjData], None]
    copy_frames: bool
    reflection: Callable[[Domain], bool]
    sky: Callable[[Domain], Sky]  # how the skybox is drawn (``ThreadRenderers``)
    skybox: bool
    floor_spacing: dict[str, float]  # domain -> the floor plane's third size to render with
    lane_frame: Callable[..., np.ndarray]
    encode: Encoder


BEFORE = Config("before", "main at 0c32c5c: mj_forward, frame copy, reflections, snake floor quads 0.1 m, "
                "surfarray read-back, imageio-ffmpeg, x264 veryfast crf 23, default threads", False,
                mujoco.mj_forward, True, lambda domain: True, lambda domain: Sky.DRAWN, True, {"snake": 0.1},
                lane_frame_main, encode_main)
AFTER = Config("after", "production: mj_fwdPosition, no copy, the walker's sky drawn once a clip, no snake "
               "reflection or sky, snake floor quads 1 m, tobytes read-back, ffmpeg piped directly, x264 veryfast "
               "crf 23, 1 thread, bit-exact", True, mujoco.mj_fwdPosition, False,
               lambda domain: domain._renderers.reflection, lambda domain: domain._renderers.sky, True, {},
               lane._draw, video.encode_mp4)
CONFIGS = {c.name: c for c in (
    BEFORE, AFTER,
    replace(AFTER, name="no-sky", about="after without the skybox (black above the horizon)", production=False,
            sky=lambda domain: Sky.DRAWN, skybox=False),
    replace(AFTER, name="ultrafast", about="after with x264 preset ultrafast", production=False,
            encode=encode_preset("ultrafast")),
)}


# ---------------------------------------------------------------- timing

@dataclass
class Totals:
    """Seconds summed over the measured clips of one domain and configuration."""

    clips: int = 0
    frames: int = 0
    replay: float = 0.0
    render: float = 0.0
    encode: float = 0.0
    replay_cpu: float = 0.0  # this process's CPU time (all threads: llvmpipe's too)
    render_cpu: float = 0.0
    encode_cpu: float = 0.0  # ffmpeg's user + system time
    streamed: float = 0.0
    sizes: list[int] = field(default_factory=list)  # MP4 bytes
    hashes: list[str] = field(default_factory=list)  # sha256 of each MP4
    stream_same_bytes: bool = True  # the streamed MP4 is byte-identical to the one from frames in memory
    mirror_is_production: bool | None = None  # after: the stage loop's frames are the production render's

    def add(self, clip: Clip) -> None:
        self.clips, self.frames = self.clips + 1, self.frames + len(clip.frames)
        for k, v in clip.times.items():
            setattr(self, k, getattr(self, k) + v)
        self.sizes.append(len(clip.mp4))
        self.hashes.append(hashlib.sha256(clip.mp4).hexdigest())
        self.stream_same_bytes &= clip.stream_same_bytes
        if clip.mirror_is_production is not None:
            self.mirror_is_production = clip.mirror_is_production and self.mirror_is_production is not False

    def row(self) -> dict:
        n, f = max(self.clips, 1), max(self.frames, 1)
        stages = {"replay": self.replay, "render": self.render, "encode": self.encode}
        return {"clips": self.clips, "frames_per_clip": round(self.frames / n, 1),
                **{f"{k}_ms_per_clip": round(v / n * 1000, 1) for k, v in stages.items()},
                "stages_ms_per_clip": round(sum(stages.values()) / n * 1000, 1),
                **{f"{k}_ms_per_frame": round(v / f * 1000, 3) for k, v in stages.items()},
                "replay_cpu_ms_per_clip": round(self.replay_cpu / n * 1000, 1),
                "render_cpu_ms_per_clip": round(self.render_cpu / n * 1000, 1),
                "cpu_ms_per_clip": round((self.replay_cpu + self.render_cpu + self.encode_cpu) / n * 1000, 1),
                "encode_cpu_ms_per_clip": round(self.encode_cpu / n * 1000, 1),
                "streamed_ms_per_clip": round(self.streamed / n * 1000, 1),
                "mp4_kb_mean": round(sum(self.sizes) / n / 1024, 1),
                "mp4_kb_max": round(max(self.sizes, default=0) / 1024, 1),
                "stream_same_bytes": self.stream_same_bytes, "mirror_is_production": self.mirror_is_production,
                "mp4_sha256": self.hashes}


def frames_digest(frames: Iterable[np.ndarray]) -> str:
    h = hashlib.sha256()
    for frame in frames:
        h.update(np.ascontiguousarray(frame).tobytes())
    return h.hexdigest()


class Stopwatch:
    """Wall time and this process's CPU time (all threads: llvmpipe rasterises on its own), summed per stage.

    Under other load the CPU times stay put while the wall times grow: compare both."""

    def __init__(self) -> None:
        self.sums: dict[str, float] = {}
        self.restart()

    def restart(self) -> None:
        self._wall, self._cpu = time.perf_counter(), time.process_time()

    def lap(self, stage: str) -> None:
        wall, cpu = time.perf_counter(), time.process_time()
        self.sums[stage] = self.sums.get(stage, 0.0) + wall - self._wall
        self.sums[stage + "_cpu"] = self.sums.get(stage + "_cpu", 0.0) + cpu - self._cpu
        self._wall, self._cpu = wall, cpu

    def add_to(self, times: dict[str, float] | None) -> None:
        if times is not None:
            for k, v in self.sums.items():
                times[k] = times.get(k, 0.0) + v


class _Capture:
    """Stands in for a MuJoCo domain's ``ThreadRenderers`` to learn the model and camera its render uses."""

    def replay(self, model, qposes, width, height, camera):
        self.model, self.camera = model, camera
        return iter(())


def mujoco_view(domain: Domain, rollout: Rollout, width: int, height: int) -> tuple[mujoco.MjModel, Camera]:
    real, domain._renderers = domain._renderers, _Capture()
    try:
        list(domain.render(rollout, width, height))
        return domain._renderers.model, domain._renderers.camera
    finally:
        domain._renderers = real


class MujocoScene:
    """A configuration's renderer for one MuJoCo domain, and the stage loop of ``ThreadRenderers.replay``."""

    def __init__(self, config: Config, domain: Domain, rollout: Rollout, width: int, height: int) -> None:
        self.config, self.domain, self.size = config, domain, (width, height)
        model, _ = mujoco_view(domain, rollout, width, height)
        if domain.name in config.floor_spacing:  # on a copy: the domain's model stays as it is
            model = copy.copy(model)
            planes = model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE
            model.geom_size[planes, 2] = config.floor_spacing[domain.name]
        self.model = model
        start = time.perf_counter()
        self.sky = config.sky(domain)
        renderers = ThreadRenderers(reflection=config.reflection(domain), sky=self.sky)
        self.renderer = renderers.get(model, width, height)
        self.created = time.perf_counter() - start
        if not config.skybox:
            self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = 0
        self.gl = gl_renderer()  # the new renderer's context is current

    def frames(self, rollout: Rollout, times: dict[str, float] | None) -> Iterator[np.ndarray]:
        _, camera = mujoco_view(self.domain, rollout, *self.size)
        model, renderer, pose = self.model, self.renderer, self.config.pose
        watch = Stopwatch()
        data = mujoco.MjData(model)
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.distance, cam.azimuth, cam.elevation = camera.distance, camera.azimuth, camera.elevation
        cam.lookat[:] = camera.lookat
        watch.lap("replay")
        sky = None
        for qpos in rollout.replay:
            watch.restart()  # what the consumer did with the last frame is not ours
            data.qpos[:] = qpos
            pose(model, data)
            if camera.aim is not None:
                cam.lookat[:] = camera.aim(data)
            renderer.update_scene(data, camera=cam)
            watch.lap("replay")
            if self.sky is Sky.ONCE:
                sky = sky_alone(renderer) if sky is None else sky
                frame = render_over_sky(renderer, sky)
            else:
                frame = renderer.render()
            frame = frame.copy() if self.config.copy_frames else frame
            watch.lap("render")
            yield frame
        watch.add_to(times)


class LaneScene:
    """A configuration's highway-env environment, and the stage loop of ``LaneChange.render``."""

    def __init__(self, config: Config, domain: Domain, rollout: Rollout, width: int, height: int) -> None:
        self.config, self.domain = config, domain
        import highway_env  # noqa: F401  (imported before the clock starts: only the first scene would pay)

        start = time.perf_counter()
        # after: the domain's own (thread-local) environment, which its render uses too; before: one of its own
        self.env = (domain._env(width, height) if config.production else lane._make_env(width, height))
        self.created = time.perf_counter() - start
        self.gl = "pygame (software)"

    def frames(self, rollout: Rollout, times: dict[str, float] | None) -> Iterator[np.ndarray]:
        watch = Stopwatch()
        ego, follower = lane._scene(self.env, 10.0)
        watch.lap("replay")
        for ex, ey, eh, fx, fy, fh in rollout.replay:
            watch.restart()
            ego.position, ego.heading = np.array([ex, ey]), float(eh)
            follower.position, follower.heading = np.array([fx, fy]), float(fh)
            watch.lap("replay")
            frame = self.config.lane_frame(self.env)
            watch.lap("render")
            yield frame
        watch.add_to(times)


# ---------------------------------------------------------------- one clip, one domain

def _encode_timed(config: Config, frames: Iterable[np.ndarray], path: Path, fps: float) -> tuple[float, float]:
    """(wall, ffmpeg cpu) seconds of encoding ``frames``; ffmpeg has exited (and been reaped) on return."""
    before, start = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    config.encode(frames, path, fps)
    wall, after = time.perf_counter() - start, resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)


@dataclass
class Clip:
    """One measurement of one clip: seconds per stage, its frames and MP4, and the checks."""

    times: dict[str, float]
    frames: list[np.ndarray]
    mp4: bytes
    stream_same_bytes: bool
    mirror_is_production: bool | None


def measure_clip(config: Config, scene, rollout: Rollout, tmp: Path) -> Clip:
    """Stage by stage (frames kept in memory, then encoded), then streamed as the app does."""
    domain, times = scene.domain, {}
    frames = list(scene.frames(rollout, times))
    times["encode"], times["encode_cpu"] = _encode_timed(config, frames, tmp / "clip.mp4", domain.frame_rate)
    mp4 = (tmp / "clip.mp4").read_bytes()
    seen: list[np.ndarray] = []
    height, width = frames[0].shape[:2]
    stream = domain.render(rollout, width, height) if config.production else scene.frames(rollout, None)
    times["streamed"], _ = _encode_timed(config, _keep(stream, seen), tmp / "streamed.mp4", domain.frame_rate)
    same_frames = frames_digest(seen) == frames_digest(frames)
    mirror = same_frames if config.production else None
    if mirror is False:
        log.warning("%s: the stage loop's frames differ from the production render's", domain.name)
    same_bytes = (tmp / "streamed.mp4").read_bytes() == mp4
    if not same_bytes:
        log.warning("%s %s %s: the streamed MP4 differs from the one encoded from memory (%s frames)",
                    config.name, domain.name, rollout.id, "same" if same_frames else "different")
    return Clip(times, frames, mp4, same_bytes, mirror)


def fastest(clips: list[Clip]) -> Clip:
    """The repeats of one clip as one: each stage's fastest time (other work only ever adds time)."""
    best = clips[0]
    best.times = {k: min(c.times[k] for c in clips) for k in best.times}
    best.stream_same_bytes = all(c.stream_same_bytes and c.mp4 == best.mp4 for c in clips)
    if any(c.mp4 != best.mp4 for c in clips):
        log.warning("the repeats of one clip gave different MP4s (frames %s)",
                    "the same" if len({frames_digest(c.frames) for c in clips}) == 1 else "different")
    return best


def _keep(frames: Iterable[np.ndarray], into: list[np.ndarray]) -> Iterator[np.ndarray]:
    for frame in frames:
        into.append(frame)
        yield frame


def compare(a: list[np.ndarray], b: list[np.ndarray]) -> dict:
    """How far two renders of one clip are apart, in 8-bit levels."""
    if len(a) != len(b):
        return {"identical": False, "frames": [len(a), len(b)]}
    diffs = [np.abs(x.astype(np.int16) - y) for x, y in zip(a, b, strict=True)]
    return {"identical": all(not d.any() for d in diffs), "max_diff": int(max(d.max() for d in diffs)),
            "mean_diff": round(float(np.mean([d.mean() for d in diffs])), 4)}


def measure_domain(name: str, configs: list[Config], clips: int, repeat: int, size: tuple[int, int],
                   tmp: Path) -> dict:
    domain, library = get_domain(name), SkillLibrary.load(name, "serve")
    ids = np.unique(np.linspace(0, len(library) - 1, clips).astype(int))
    rollouts = [library.rollout(int(i)) for i in ids]
    scene_type = LaneScene if name == "lane_change" else MujocoScene
    scenes = {c.name: scene_type(c, domain, rollouts[0], *size) for c in configs}
    warm = {c.name: Totals() for c in configs}
    for c in configs:  # the warm-up clip: first use of the renderer (and of the domain's own, for after)
        warm[c.name].add(measure_clip(c, scenes[c.name], rollouts[0], tmp))
    totals = {c.name: Totals() for c in configs}
    diffs: dict[str, list[dict]] = {c.name: [] for c in configs[1:]}
    for rollout in rollouts:
        runs: dict[str, list[Clip]] = {c.name: [] for c in configs}
        for _ in range(repeat):  # the configurations take turns
            for c in configs:
                runs[c.name].append(measure_clip(c, scenes[c.name], rollout, tmp))
        best = {k: fastest(v) for k, v in runs.items()}
        for c in configs:
            totals[c.name].add(best[c.name])
        for c in configs[1:]:
            diffs[c.name].append(compare(best[configs[0].name].frames, best[c.name].frames))
        log.info("%s %s (%d frames): %s", name, rollout.id, len(rollout.replay),
                 ", ".join(f"{k} {1000 * sum(v.times[s] for s in ('replay', 'render', 'encode')):.0f} ms"
                           for k, v in best.items()))
    return {"domain": name, "frame_rate": domain.frame_rate, "rollouts": [r.id for r in rollouts],
            "renderer": next(iter(scenes.values())).gl,
            "renderer_creation_ms": {k: round(s.created * 1000, 1) for k, s in scenes.items()},
            "warm_up_clip_ms": {k: round((t.replay + t.render + t.streamed) * 1000, 1) for k, t in warm.items()},
            "configs": {k: t.row() for k, t in totals.items()},
            "frames_vs_" + configs[0].name: {k: _summary(v) for k, v in diffs.items()}}


def _summary(diffs: list[dict]) -> dict:
    return {"identical_clips": sum(d["identical"] for d in diffs), "clips": len(diffs),
            "max_diff": max((d.get("max_diff", 255) for d in diffs), default=0),
            "mean_diff": round(float(np.mean([d.get("mean_diff", 255) for d in diffs])), 4) if diffs else 0.0}


# ---------------------------------------------------------------- report

def gl_renderer() -> str:
    try:
        from OpenGL import GL

        return GL.glGetString(GL.GL_RENDERER).decode()
    except Exception:  # only for the report
        return "unknown"


NOTES = """\
## What changed, what was left alone

Changed (the *after* configuration, now production):

- **Encoding** (`rba/media/video.py`): ffmpeg is started directly. `imageio_ffmpeg.write_frames` forked the whole
  process (a `preexec_fn` rules out vfork) and polled for ffmpeg's exit every 10 ms: ~10 ms of every clip.
  x264 runs on **one thread** (`-threads 1`): its default follows the CPU count, and the thread count
  changes the bytes, so on main the same clip gave other bytes on a machine (or cgroup) with another
  number of CPUs (`tests/test_video.py` renders a walker clip in two processes, one limited to one CPU,
  and compares the bytes). The RGB to YUV conversion runs single-threaded with swscale's bit-exact paths and
  the muxer drops its version tag. Preset (`veryfast`) and crf (23) are unchanged: the clips stay 20-60 kB.
  Twice, in runs of this benchmark under heavy load, main's encoder even gave other bytes for the same
  walker frames in the same process (logged: "the streamed MP4 differs from the one encoded from memory
  (same frames)"); the one-thread encoder never has.
- **MuJoCo replay** (`rba/domains/mujoco_render.py`): `mj_fwdPosition` instead of `mj_forward`: a frame
  needs only positions (kinematics, centres of mass for the snake's camera, lights, tendons); the frames
  are identical pixel for pixel (walker and manipulator above: every clip identical; and
  `tests/domains/test_mujoco_render.py`). The frame copy after `Renderer.render` is gone (it returns a
  new array). Both are small: the replay stage was ~2-3 % of a clip.
- **The skybox** (`ThreadRenderers(sky=...)`): MuJoCo draws it every frame, and it costs even where the
  scene covers it. The walker's camera only slides along x, and MuJoCo draws the sky around the camera,
  so the sky (three quarters of the frame) is one image for the whole clip: `Sky.ONCE` draws it once per
  clip and pastes it wherever a frame drew nothing (depth at the far plane, read back with the colour).
  The snake's camera looks down at its floor and never sees the sky: `Sky.HIDDEN` does not draw it
  (`no-sky` gave the snake identical frames). Both identical pixel for pixel (above; and the tests). The
  manipulator keeps drawing it: its backdrop hides all but a corner, and pasting cost more than it saved.
- **Snake** (`assets/snake.xml`, `snake.py`): the floor plane was drawn as 200 x 200 quads (MuJoCo's cap;
  its third size, 0.1 m, only spaces them for drawing), twice with the reflection: quads 1 m apart look the
  same under its directional light (at most 1 level of 255 apart) and the physics is bit-identical
  (`tests/test_resimulate.py`). Its floor reflection is off: the snake lies flat, so the reflection was a
  hairline under the body (mean difference 0.08 levels) and ~40 % of what was left of each frame.
  (That, and the floor's quads, are the only pixel changes: the *frames vs before* column.)
- **Lane change** (`lane_change.py`): the frame is read from the pygame surface with `pygame.image.tobytes`
  (row-major, one pass) instead of highway-env's column-major `surfarray` plus a transposed copy: same pixels.

Left alone:

- **Frame rate.** A clip's frame rate is its domain's replay rate, and it is about what the attribute is:
  walker *softness* is the foot's speed at touchdown, and at 1.4 m/s the last 5 cm take ~35 ms, one frame
  at 30 fps; at 15 fps a stomp and a soft landing would be one frame apart. The manipulator's *tremor* is
  held 40 ms (25 Hz), which 33 fps barely samples and half that would alias away. The snake (8-50 mm/s)
  would survive 12.5 fps, but the encoder's rate comes from `domain.frame_rate`, which `rba/media/clip_cache.py` and
  `rba/cli.py` pass on (not changed here); the lane change is at 15 fps already.
- **Resolution**: 320x240, the settings' default.
- **No skybox at all** (`no-sky` in `clip_cost_options.md`): MuJoCo then clears to black, a look change
  for the walker (black above the horizon) and a black corner for the manipulator, and clip caches are
  keyed by library version, not by renderer, so old and new clips would mix in one session. With the
  walker's sky pasted in, what is left to gain is small.
- **The walker's and the manipulator's reflections**: they show where feet touch down and the ball lifts off.
- **x264 `ultrafast` / `superfast`** (`ultrafast` in `clip_cost_options.md`): 10-40 ms a clip faster, but
  without mb-tree the files are 2-5x larger (the walker's starry sky over 150 kB at `ultrafast`).
  `me=dia:subme=1` saves ~10 ms at +20 % size; `-tune zerolatency` or `animation` were slower or bigger.
  Encoding overlaps rendering anyway (compare *stages* and *streamed*).
- **Renderers**: already one per thread and size (`ThreadRenderers`), one highway-env per thread and view;
  the creation column shows what the warm-up clip pays once.
"""


def _stage_table(report: dict) -> list[str]:
    lines = ["| domain | config | frames | replay | render | encode | **stages** | streamed "
             "| CPU: replay + render + ffmpeg = total | MP4 kB mean / max |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for d in report["domains"]:
        for name in report["configs"]:
            r = d["configs"][name]
            lines.append(
                f"| {d['domain']} | {name} | {r['frames_per_clip']:g} | {r['replay_ms_per_clip']:.1f} "
                f"({r['replay_ms_per_frame']:.3f}) | {r['render_ms_per_clip']:.0f} ({r['render_ms_per_frame']:.2f}) | "
                f"{r['encode_ms_per_clip']:.0f} ({r['encode_ms_per_frame']:.2f}) | **{r['stages_ms_per_clip']:.0f}** | "
                f"{r['streamed_ms_per_clip']:.0f} | {r['replay_cpu_ms_per_clip']:.0f} + "
                f"{r['render_cpu_ms_per_clip']:.0f} + {r['encode_cpu_ms_per_clip']:.0f} = "
                f"**{r['cpu_ms_per_clip']:.0f}** | {r['mp4_kb_mean']:.1f} / {r['mp4_kb_max']:.1f} |")
    return lines


def _change(a: dict, b: dict, key: str) -> str:
    return f"{a[key]:.0f} → {b[key]:.0f} ({b[key] / a[key] - 1:+.0%})"


def _change_table(report: dict) -> list[str]:
    first, rest = report["configs"][0], report["configs"][1:]
    lines = ["| domain | " + " | ".join(f"{first} → {n}: stages · streamed · CPU (ms per clip)" for n in rest) + " |",
             "|---|" + "---|" * len(rest)]
    for d in report["domains"]:
        a = d["configs"][first]
        cells = [" · ".join(_change(a, d["configs"][n], k) for k in
                            ("stages_ms_per_clip", "streamed_ms_per_clip", "cpu_ms_per_clip")) for n in rest]
        lines.append(f"| {d['domain']} | " + " | ".join(cells) + " |")
    return lines


def _check_table(report: dict) -> list[str]:
    names = report["configs"]
    lines = ["| domain | renderer creation, ms (" + " / ".join(names) + ") | warm-up clip, ms | frames vs "
             + names[0] + " (identical clips; max / mean level difference) | streamed MP4 = MP4 from memory "
             "| stage loop = production render |", "|---|---|---|---|---|---|"]
    for d in report["domains"]:
        vs = d["frames_vs_" + names[0]]
        lines.append(f"| {d['domain']} | {' / '.join(str(d['renderer_creation_ms'][n]) for n in names)} | "
                     f"{' / '.join(str(d['warm_up_clip_ms'][n]) for n in names)} | "
                     + "; ".join(f"{k}: {v['identical_clips']}/{v['clips']}; {v['max_diff']} / {v['mean_diff']}"
                                 for k, v in vs.items())
                     + f" | {all(d['configs'][n]['stream_same_bytes'] for n in names)} | "
                     + ", ".join(str(d["configs"][n]["mirror_is_production"]) for n in names
                                 if d["configs"][n]["mirror_is_production"] is not None) + " |")
    return lines


def markdown(report: dict) -> str:
    lines = ["# Clip cost", "", f"`{report['command']}`  ",
             f"{report['date']} · {report['machine']} · load average (1 min) {report['load_before']} → "
             f"{report['load_after']} · clips {report['size']} · {report['clips']} clips per domain, each stage "
             f"the fastest of {report['repeat']} run(s), configurations taking turns", "",
             "ms per clip (per frame in brackets). *stages* = replay + render + encode, each timed on its own "
             "(encode: frames already in memory); *streamed* = the clip in one process, frames piped to "
             "ffmpeg as they are rendered, so encoding overlaps rendering (a compute worker makes each part of a "
             "clip so; the parts run on separate workers, `clip_parts.md`); *CPU* = this process's CPU time in "
             "replay and render (every thread: llvmpipe rasterises on its own) and ffmpeg's user + system time, "
             "what a clip costs a busy server, and what moves least when other work shares the machine.",
             "", *_stage_table(report), "", *_change_table(report), "", *_check_table(report),
             "", "Configurations:", "", *[f"- **{n}**: {report['config_about'][n]}" for n in report["configs"]],
             "", f"Rendering: {report['gl']}; MuJoCo {report['mujoco']}; ffmpeg {report['ffmpeg']}.", ""]
    if report["configs"] == ["before", "after"]:
        lines += [NOTES]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--domains", nargs="+", default=list(DOMAINS), choices=DOMAINS, help="domains to measure")
    p.add_argument("--clips", type=int, default=8, help="rollouts per domain, spread evenly over the serve library")
    p.add_argument("--configs", nargs="+", default=["before", "after"], choices=list(CONFIGS),
                   help="configurations to compare; the first is the reference for pixel differences")
    p.add_argument("--repeat", type=int, default=1,
                   help="measure each clip this many times and keep each stage's fastest (robust to other load)")
    p.add_argument("--width", type=int, default=None, help="clip width in pixels (default: the settings' clip_width)")
    p.add_argument("--height", type=int, default=None, help="clip height (default: the settings' clip_height)")
    p.add_argument("--out", type=Path, default=RESULTS / "clip_cost", help="writes <out>.json and <out>.md")
    args = p.parse_args(argv)
    if not 1 <= args.clips <= 100 or not 1 <= args.repeat <= 10:
        p.error("--clips must be in 1..100 and --repeat in 1..10")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    settings = LibrarySettings()
    width, height = args.width or settings.clip_width, args.height or settings.clip_height
    configs = [CONFIGS[n] for n in dict.fromkeys(args.configs)]
    load_before = round(os.getloadavg()[0], 2)  # other work on the machine skews every number below
    with tempfile.TemporaryDirectory(prefix="clip_cost-") as tmp:
        domains = [measure_domain(d, configs, args.clips, args.repeat, (width, height), Path(tmp))
                   for d in args.domains]
    import imageio_ffmpeg

    report = {
        "command": "python benchmarks/clip_cost.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "date": time.strftime("%Y-%m-%d %H:%M"), "load_before": load_before, "load_after": round(os.getloadavg()[0], 2),
        "machine": f"{os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}",
        "gl": next((d["renderer"] for d in domains if "pygame" not in d["renderer"]), "none"),
        "mujoco": mujoco.__version__, "ffmpeg": imageio_ffmpeg.get_ffmpeg_version(),
        "size": f"{width}x{height}", "clips": args.clips, "repeat": args.repeat, "configs": [c.name for c in configs],
        "config_about": {c.name: c.about for c in configs}, "domains": domains,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_text(report_path(args.out, ".json"), json.dumps(report, indent=2) + "\n")
    text = markdown(report)
    save_markdown(report_path(args.out, ".md"), text)
    print(text)
    log.info("wrote %s.json and %s.md", args.out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
