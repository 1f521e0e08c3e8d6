"""Off-screen MuJoCo rendering shared by the MuJoCo domains: one renderer per thread and size.

An EGL context belongs to the thread that made it, and making one costs ~0.4 s, so each
thread keeps its renderers. Shadows are off: in software rendering (Mesa) they cost more
than half of each frame, and the floor's reflection still shows where things touch. A domain
whose bodies always lie on the floor can turn the reflection off too (``reflection=False``):
it draws the scene a second time, mirrored, and blends the floor over it.

The skybox (``Sky``) costs even where bodies cover it. Where a domain's camera only slides (its
orientation never changes), the sky, which MuJoCo draws around the camera, is the same image in
every frame of a clip: ``Sky.ONCE`` draws it once per clip and pastes it wherever a frame drew
nothing (depth at the far plane), a quarter of a walker frame in software GL. A camera that never
sees the sky (the snake's, looking down at its floor) need not draw it: ``Sky.HIDDEN``. Both give
the same pixels as drawing it every frame (``Sky.DRAWN``).

Each frame needs only the model's pose, so a replay row is turned into one with
``mj_fwdPosition`` (kinematics, centres of mass, lights, tendons, contacts) instead of a full
``mj_forward``, which also computes velocities, forces and the constraint solution: the frames
are the same pixel for pixel. See ``benchmarks/clip_cost.py`` for what each stage costs.
"""

from __future__ import annotations

import atexit
import threading
import weakref
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from enum import Enum

import mujoco
import numpy as np

_ALL: weakref.WeakSet = weakref.WeakSet()
_registered = threading.Lock()
_at_exit = False


@dataclass(frozen=True)
class Camera:
    """A free camera; ``aim(data)`` (if given) moves what it looks at, frame by frame."""

    distance: float  # m
    elevation: float  # degrees
    lookat: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m
    azimuth: float = 90.0  # degrees: looking along +y, i.e. at the x-z plane
    aim: Callable[[mujoco.MjData], tuple[float, float, float]] | None = None


class Sky(Enum):
    """How a domain's clips get their skybox: all give the same pixels where they apply (module docstring)."""

    DRAWN = "drawn every frame"
    ONCE = "drawn once a clip and pasted in: for a camera that only slides"
    HIDDEN = "not drawn: for a camera that never sees it"


class ThreadRenderers:
    """``get(model, width, height)``: this thread's renderer for that size, made once."""

    def __init__(self, reflection: bool = True, sky: Sky = Sky.DRAWN) -> None:
        self.reflection, self.sky = reflection, sky
        self._local = threading.local()
        self._made: list[mujoco.Renderer] = []
        _ALL.add(self)

    def get(self, model: mujoco.MjModel, width: int, height: int) -> mujoco.Renderer:
        cache = self._local.__dict__.setdefault("by_size", {})
        if (width, height) not in cache:
            model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), width)
            model.vis.global_.offheight = max(int(model.vis.global_.offheight), height)
            model.vis.quality.offsamples = 0  # no multisampling: 2.6x faster, no visible difference at 320x240
            renderer = mujoco.Renderer(model, height=height, width=width)
            renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
            renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = int(self.reflection)
            renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = int(self.sky is Sky.DRAWN)
            _close_at_exit()
            cache[width, height] = renderer
            self._made.append(renderer)
        return cache[width, height]

    def replay(self, model: mujoco.MjModel, qposes: np.ndarray, width: int, height: int,
               camera: Camera) -> Iterator[np.ndarray]:
        """HxWx3 uint8 frames of the model posed at each row of ``qposes``."""
        data = mujoco.MjData(model)
        renderer = self.get(model, int(width), int(height))
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.distance, cam.azimuth, cam.elevation = camera.distance, camera.azimuth, camera.elevation
        cam.lookat[:] = camera.lookat
        sky = None
        for qpos in qposes:
            data.qpos[:] = qpos
            mujoco.mj_fwdPosition(model, data)  # all a frame shows; velocities and forces are not drawn
            if camera.aim is not None:
                cam.lookat[:] = camera.aim(data)
            renderer.update_scene(data, camera=cam)  # update + render with no yield between: safe to interleave
            if self.sky is not Sky.ONCE:
                yield renderer.render()  # a new array each call
                continue
            sky = sky_alone(renderer) if sky is None else sky
            yield render_over_sky(renderer, sky)

    def close(self) -> None:
        for renderer in self._made:
            renderer.close()
        self._made.clear()


@dataclass(frozen=True)
class MujocoView:
    """What a MuJoCo domain's clips show: its model, its camera and how its renderers draw (reflection, sky). The MP4
    renders it (``replay``) and the page's data is read off it (``rba.media.clip_data``): one description, two ways."""

    model: mujoco.MjModel
    camera: Camera
    renderers: ThreadRenderers

    def replay(self, qposes: np.ndarray, width: int, height: int) -> Iterator[np.ndarray]:
        return self.renderers.replay(self.model, qposes, width, height, self.camera)


def sky_alone(renderer: mujoco.Renderer) -> np.ndarray:
    """The skybox alone, as the scene's camera sees it now (the scene keeps its geoms and flags)."""
    scene = renderer.scene
    ngeom, scene.ngeom = scene.ngeom, 0
    scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = 1
    try:
        return renderer.render()
    finally:
        scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = 0
        scene.ngeom = ngeom


def render_over_sky(renderer: mujoco.Renderer, sky: np.ndarray) -> np.ndarray:
    """``renderer.render()`` of a scene drawn without its skybox, ``sky`` pasted where nothing was drawn.

    Colour and depth come from one read-back; depth 0 is the far plane (the Renderer reads depth
    reversed, ``mjDEPTH_ZEROFAR``), where only the cleared background is. No multisampling, so no
    edge pixel is a blend of a body and the background."""
    rgb, depth = np.empty_like(sky), np.empty(sky.shape[:2], np.float32)
    renderer._gl_context.make_current()
    mujoco.mjr_render(renderer._rect, renderer.scene, renderer._mjr_context)
    mujoco.mjr_readPixels(rgb, depth, renderer._rect, renderer._mjr_context)
    frame = np.flipud(rgb).copy()  # GL's rows run bottom up
    np.copyto(frame, sky, where=np.flipud(depth == 0)[..., None])
    return frame


def _close_all() -> None:
    for owner in list(_ALL):
        owner.close()


def _close_at_exit() -> None:
    """Registered after the first renderer, i.e. after MuJoCo's own EGL clean-up: atexit runs
    last-registered first, so ours closes the contexts before EGL is torn down."""
    global _at_exit
    with _registered:
        if not _at_exit:
            atexit.register(_close_all)
            _at_exit = True
