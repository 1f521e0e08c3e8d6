"""The agent's pixels in a clip's MP4 frames, to check a drawing of the same frames against (the page's player).

For a MuJoCo domain: MuJoCo's segmentation rendering of the frame through the clip view's camera, a pixel being the
agent's where it shows a geom of a body other than the world's (without the floor's reflection: a mirror image is
not the agent). For the road: the pixels of the rendered frame in the agent car's colour.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from rba.domains import Domain, Rollout

CAR_TOLERANCE = 40  # 0..255 per channel: the agent car's fill, not the grey road or the other car


def agent_masks(domain: Domain, rollout: Rollout, frames: Sequence[int], width: int, height: int) -> list[np.ndarray]:
    """bool[height, width] per frame of ``frames``: where the agent is in the MP4's frame."""
    view = domain.clip_view(rollout)
    if view is None:
        raise ValueError(f"domain {domain.name!r} has no clip view: its clips are MP4s only")
    if not hasattr(view, "model"):  # the road
        ego = next(c for c in view.cars if c.agent)
        shots = domain.render(rollout, width, height, frames=np.asarray(frames))
        return [np.all(np.abs(s.astype(int) - np.array(ego.rgb)) <= CAR_TOLERANCE, axis=-1) for s in shots]
    model = view.model
    renderer = mujoco.Renderer(model, height=height, width=width)
    renderer.enable_segmentation_rendering()
    renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
    data = mujoco.MjData(model)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.distance, cam.azimuth, cam.elevation = view.camera.distance, view.camera.azimuth, view.camera.elevation
    masks = []
    try:
        for f in frames:
            data.qpos[:] = rollout.replay[f]
            mujoco.mj_fwdPosition(model, data)  # as the MP4's frames are posed
            cam.lookat[:] = view.camera.aim(data) if view.camera.aim is not None else view.camera.lookat
            renderer.update_scene(data, camera=cam)
            seg = renderer.render()
            ids, types = seg[..., 0], seg[..., 1]
            geom = (types == mujoco.mjtObj.mjOBJ_GEOM) & (ids >= 0)
            masks.append(geom & (model.geom_bodyid[np.clip(ids, 0, None)] != 0))
    finally:
        renderer.close()
    return masks


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two masks (1 when both are empty)."""
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0
