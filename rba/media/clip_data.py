"""A clip as data the page draws itself: a domain's scene once, then each clip's per-frame poses (architecture §4).

What the MP4 renderer draws is read off the same description (a domain's ``clip_view``): for a MuJoCo domain,
``mjv_updateScene`` with the renderer's options lists the visual geoms (type, size, colour, material, texture,
mesh) and each frame's pose is the geom's after ``mj_fwdPosition`` of that replay row, as the renderer poses it;
the camera's look-at follows its ``aim``. For highway-env's road, the view, lanes and cars are placed as its
pygame renderer places them. Frame i of the data is frame i of the MP4.

Both are compact JSON (little-endian float32 arrays in base64), gzip-compressed with a fixed header so equal
data gives equal bytes. Field names are the contract with the page's player (``docs/architecture.md``).
"""

from __future__ import annotations

import base64
import gzip
import hashlib
import json
from collections.abc import Mapping
from typing import Any

import numpy as np

from rba.domains import Domain, Rollout
from rba.domains.base import Overlay

FORMAT = 1
# Part of every clip data key (``rba.media.clip_cache.ClipKey``): bump it when what the data says changes.
DATA_VERSION = 1
SCENE_URL = "/api/clips/{domain}/scene.json"  # the route serving a domain's scene; clips name it with ``?v=``
# per-frame arrays are rounded to powers of two, so float32's trailing mantissa bits are zeros gzip packs away
# (walker 25 -> 17 KB, snake 35 -> 20 KB): 1/16384 m (0.06 mm, a pixel is some mm) and 1/32768 of a quaternion
POSITION_STEP, QUATERNION_STEP = 2.0 ** -14, 2.0 ** -15
_GEOM_TYPES = {0: "plane", 2: "sphere", 3: "capsule", 4: "ellipsoid", 5: "cylinder", 6: "box", 7: "mesh"}


class NoClipData(LookupError):
    """The domain's clips exist only as MP4s (it defines no ``clip_view``)."""


def scene(domain: Domain, width: int, height: int) -> dict[str, Any]:
    """The domain's scene: what every clip of it shares, with ``version`` a digest of the rest."""
    view = _view(domain, None)
    body = {"format": FORMAT, "domain": domain.name, "frame_rate": float(domain.frame_rate), "width": int(width),
            "height": int(height), "agent": domain.description}
    body |= _mujoco_scene(view) if _is_mujoco(view) else _road_scene(view, width, height)
    return {**body, "version": version(body)}


def version(scene_body: Mapping[str, Any]) -> str:
    return hashlib.sha256(json.dumps(scene_body, sort_keys=True).encode()).hexdigest()[:16]


def clip(domain: Domain, rollout: Rollout, scene_version: str) -> dict[str, Any]:
    """One clip's data: per-frame poses, overlays and a text description."""
    view = _view(domain, rollout)
    frames = len(rollout.replay)
    body: dict[str, Any] = {
        "format": FORMAT, "domain": domain.name, "rollout_id": rollout.id,
        "scene_url": f"{SCENE_URL.format(domain=domain.name)}?v={scene_version}",
        "frames": frames, "frame_rate": float(domain.frame_rate)}
    if _is_mujoco(view):
        poses, track = _mujoco_frames(view, rollout.replay)
        body |= poses
    else:
        body["vehicles"] = _b64(view.poses(rollout.replay), POSITION_STEP)
        track = {}
    body["description"] = description(domain, rollout)
    body["overlays"] = [_overlay(o) for o in domain.clip_overlays(rollout, track)]
    return body


def description(domain: Domain, rollout: Rollout) -> str:
    """One or two sentences for people who cannot see the clip: the scene, then each attribute's reading."""
    parts = []
    for spec in domain.attributes:
        if spec.name not in rollout.proxies:
            continue
        value = rollout.proxies[spec.name]
        if spec.reading is not None:
            parts.append(f"{spec.reading.label} {spec.reading.sign * value:.3g} {spec.unit} ({spec.reading.note})")
        else:
            parts.append(f"{spec.name.replace('_', ' ')} {value:.3g} {spec.unit}")
    return f"{domain.description} In this clip: {'; '.join(parts)}." if parts else domain.description


def encode(obj: Mapping[str, Any]) -> bytes:
    """Compact JSON, gzip-compressed with no timestamp: equal data, equal bytes (the ETag is the key's anyway)."""
    return gzip.compress(json.dumps(obj, separators=(",", ":")).encode(), compresslevel=6, mtime=0)


def decode(data: bytes) -> dict[str, Any]:
    return json.loads(gzip.decompress(data))


def floats(text: str, *shape: int) -> np.ndarray:
    """A base64 float32 array of the data, shaped (tests and benchmarks; the page decodes it itself)."""
    return np.frombuffer(base64.b64decode(text), dtype="<f4").reshape(shape)


def mat_to_quat(mats: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) of rotation matrices float[..., 9] (row-major, MuJoCo's ``xmat``)."""
    m = mats.reshape(*mats.shape[:-1], 3, 3)
    d0, d1, d2 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    q = 0.5 * np.sqrt(np.maximum(0.0, np.stack([1 + d0 + d1 + d2, 1 + d0 - d1 - d2, 1 - d0 + d1 - d2,
                                                 1 - d0 - d1 + d2], -1)))
    q[..., 1] = np.copysign(q[..., 1], m[..., 2, 1] - m[..., 1, 2])
    q[..., 2] = np.copysign(q[..., 2], m[..., 0, 2] - m[..., 2, 0])
    q[..., 3] = np.copysign(q[..., 3], m[..., 1, 0] - m[..., 0, 1])
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _view(domain: Domain, rollout: Rollout | None):
    view = domain.clip_view(rollout)
    if view is None:
        raise NoClipData(f"domain {domain.name!r} has no clip data: its clips are MP4s only")
    return view


def _is_mujoco(view: object) -> bool:
    from rba.domains.mujoco_render import MujocoView

    return isinstance(view, MujocoView)


def _b64(array: np.ndarray, step: float | None = None) -> str:
    """Little-endian float32 in base64, rounded to multiples of ``step`` (a power of two) when given."""
    values = np.asarray(array, dtype=np.float64)
    if step is not None:
        values = np.round(values / step) * step
    return base64.b64encode(np.ascontiguousarray(values, dtype="<f4").tobytes()).decode()


def _rounded(values) -> list[float]:
    return [round(float(v), 6) for v in values]


def _overlay(o: Overlay) -> dict[str, Any]:
    return {"attribute": o.attribute, "label": o.label,
            "markers": [{"frame": m.frame, "pos": _rounded(m.pos), "text": m.text} for m in o.markers],
            "path": None if o.path is None else [_rounded(p) for p in o.path]}


# ---------------------------------------------------------------- MuJoCo


def _mjv_scene(view):
    """The visual scene of the model at its reference pose, as the renderer's ``update_scene`` makes it (default
    ``MjvOption``, every category), its visible geoms (alpha > 0) and the lights but the headlight."""
    import mujoco

    model = view.model
    data = mujoco.MjData(model)
    mujoco.mj_fwdPosition(model, data)
    scn = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom))
    mujoco.mjv_updateScene(model, data, mujoco.MjvOption(), None, _free_camera(view.camera, data),
                           mujoco.mjtCatBit.mjCAT_ALL, scn)
    geoms = [g for g in scn.geoms[: scn.ngeom] if g.rgba[3] > 0]
    other = [g for g in geoms if g.objtype != mujoco.mjtObj.mjOBJ_GEOM]
    if other:
        raise NotImplementedError(f"visual geoms of object types {sorted({g.objtype for g in other})} (not model "
                                  "geoms) have no per-frame pose here yet")
    return geoms, [light for light in scn.lights[: scn.nlight] if not light.headlight]


def _free_camera(camera, data):
    import mujoco

    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.distance, cam.azimuth, cam.elevation = camera.distance, camera.azimuth, camera.elevation
    cam.lookat[:] = camera.aim(data) if camera.aim is not None else camera.lookat
    return cam


def _mujoco_scene(view) -> dict[str, Any]:
    from rba.domains.mujoco_render import Sky

    model, camera = view.model, view.camera
    geoms, lights = _mjv_scene(view)
    meshes: dict[int, int] = {}  # model mesh id -> its index in the scene's list
    out = []
    for g in geoms:
        mesh = None
        if g.type == 7:
            mesh = meshes.setdefault(int(model.geom_dataid[g.objid]), len(meshes))
        out.append({"type": _GEOM_TYPES[int(g.type)], "size": _rounded(g.size), "rgba": _rounded(g.rgba),
                    "mesh": mesh, "texture": _texture(model, int(g.texid), g),
                    "emission": float(g.emission), "specular": float(g.specular),
                    "shininess": float(g.shininess), "reflectance": float(g.reflectance),
                    "agent": bool(model.geom_bodyid[g.objid] != 0)})
    head = model.vis.headlight
    extent = float(model.stat.extent)
    return {
        "kind": "mujoco",
        "camera": {"fovy": float(model.vis.global_.fovy), "distance": camera.distance,
                   "elevation": camera.elevation, "azimuth": camera.azimuth,
                   "znear": float(model.vis.map.znear) * extent, "zfar": float(model.vis.map.zfar) * extent},
        "sky": _sky(model) if view.renderers.sky is not Sky.HIDDEN else None,
        "ambient": _rounded(head.ambient),
        "headlight": {"diffuse": _rounded(head.diffuse), "specular": _rounded(head.specular),
                      "active": bool(head.active)},
        "lights": [{"pos": _rounded(light.pos), "dir": _rounded(light.dir), "diffuse": _rounded(light.diffuse),
                    "ambient": _rounded(light.ambient), "specular": _rounded(light.specular),
                    "directional": int(light.type) == 1, "cutoff": float(light.cutoff),
                    "exponent": float(light.exponent), "attenuation": _rounded(light.attenuation)}
                   for light in lights],
        "reflection": bool(view.renderers.reflection),
        "meshes": [_mesh(model, m) for m in meshes],
        "geoms": out,
    }


def _mujoco_frames(view, replay: np.ndarray) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Per frame, every visual geom's position and orientation, the camera's look-at and the lights' positions
    (a light may follow a body); and each named geom's centre x, y and lowest z per frame (the overlays' track:
    where it meets the floor)."""
    import mujoco

    model, camera = view.model, view.camera
    geoms, lights = _mjv_scene(view)
    ids = np.array([g.objid for g in geoms], dtype=np.int64)
    light_ids = np.array([light.id for light in lights], dtype=np.int64)
    frames = len(replay)
    pos, mats = np.empty((frames, len(ids), 3)), np.empty((frames, len(ids), 9))
    lookat, light_pos = np.empty((frames, 3)), np.empty((frames, len(light_ids), 3))
    data = mujoco.MjData(model)
    for i, qpos in enumerate(replay):
        data.qpos[:] = qpos
        mujoco.mj_fwdPosition(model, data)  # as ThreadRenderers.replay poses each frame
        pos[i], mats[i] = data.geom_xpos[ids], data.geom_xmat[ids]
        lookat[i] = camera.aim(data) if camera.aim is not None else camera.lookat
        light_pos[i] = data.light_xpos[light_ids]
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, int(g)) for g in ids]
    ground = np.concatenate([pos[..., :2], _lowest(pos, mats, geoms)[..., None]], -1)
    track = {name: ground[:, j] for j, name in enumerate(names) if name}
    return {"geoms": len(ids), "pos": _b64(pos, POSITION_STEP), "quat": _b64(mat_to_quat(mats), QUATERNION_STEP),
            "lookat": _b64(lookat, POSITION_STEP), "light_pos": _b64(light_pos, POSITION_STEP)}, track


def _lowest(pos: np.ndarray, mats: np.ndarray, geoms: list) -> np.ndarray:
    """float[F, G]: each geom's lowest z (a sphere's, capsule's or box's; a plane's or mesh's centre)."""
    up = np.abs(mats[..., 6:9])  # |world z| of each local axis: the matrix's last row
    size = np.array([g.size for g in geoms])
    kind = np.array([int(g.type) for g in geoms])
    reach = np.zeros(pos.shape[:2])
    reach = np.where(kind == 2, size[:, 0], reach)  # sphere
    reach = np.where(kind == 3, up[..., 2] * size[:, 2] + size[:, 0], reach)  # capsule: along local z, then r
    reach = np.where(kind == 6, (up * size).sum(-1), reach)  # box
    return pos[..., 2] - reach


def _texels(model, texid: int) -> np.ndarray:
    h, w, c = int(model.tex_height[texid]), int(model.tex_width[texid]), int(model.tex_nchannel[texid])
    adr = int(model.tex_adr[texid])
    return model.tex_data[adr: adr + h * w * c].reshape(h, w, c)[..., :3].astype(np.float64) / 255.0


def _texture(model, texid: int, geom) -> dict[str, Any] | None:
    """A 2-D texture as the page can draw it: a checker's two colours (read off its texels), else its mean colour
    (``"kind": "flat"``); ``repeat`` and ``uniform`` as the material gives them."""
    if texid < 0:
        return None
    tex = _texels(model, texid)
    h, w = tex.shape[:2]
    q = [np.median(tex[r * h // 2 + h // 8: r * h // 2 + 3 * h // 8, c * w // 2 + w // 8: c * w // 2 + 3 * w // 8]
                   .reshape(-1, 3), axis=0) for r in (0, 1) for c in (0, 1)]
    checker = np.allclose(q[0], q[3], atol=1 / 255) and np.allclose(q[1], q[2], atol=1 / 255) and \
        not np.allclose(q[0], q[1], atol=1 / 255)
    kind = {"kind": "checker", "rgb1": _rounded(q[0]), "rgb2": _rounded(q[1])} if checker else \
        {"kind": "flat", "rgb1": _rounded(tex.reshape(-1, 3).mean(0)), "rgb2": None}
    return {**kind, "repeat": _rounded(geom.texrepeat), "uniform": bool(geom.texuniform)}


def _sky(model) -> dict[str, Any] | None:
    """The skybox's gradient: the median colour around the centre of its top face (rgb1) and of its bottom face
    (rgb2), where a gradient texture has its two colours (the median passes over a random texture's stars)."""
    skies = [t for t in range(model.ntex) if int(model.tex_type[t]) == 2]
    if not skies:
        return None
    faces = _texels(model, skies[0])
    side = faces.shape[1]
    lo, hi = side // 2 - max(1, side // 20), side // 2 + max(1, side // 20)

    def centre(face: int) -> list[float]:  # MuJoCo's faces: +x, -x, +y, -y, +z, -z, stacked
        return _rounded(np.median(faces[face * side + lo: face * side + hi, lo:hi].reshape(-1, 3), 0))

    return {"rgb1": centre(2), "rgb2": centre(3)}


def _mesh(model, mesh: int) -> dict[str, str]:
    va, vn = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    fa, fn = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
    faces = np.ascontiguousarray(model.mesh_face[fa: fa + fn], dtype="<i4")
    return {"vertices": _b64(model.mesh_vert[va: va + vn]), "faces": base64.b64encode(faces.tobytes()).decode()}


# ---------------------------------------------------------------- highway-env's road


def _road_scene(view, width: int, height: int) -> dict[str, Any]:
    ppm = width / view.view_metres
    return {
        "kind": "plane2d",
        "view": {"pixels_per_metre": ppm, "centre_on": view.centre_on,
                 "offset": [view.centring[0] * width / ppm, view.centring[1] * height / ppm]},
        "lanes": {"count": len(view.lines) - 1, "width": view.lane_width, "y0": 0.0,
                  "lines": [{"y": y, "kind": kind} for y, kind in view.lines],
                  "stripe": {"length": view.stripe[0], "spacing": view.stripe[1]},
                  "line_rgb": list(view.line_rgb), "road_rgb": list(view.road_rgb)},
        "background_rgb": list(view.road_rgb),
        "vehicles": [{"length": c.length, "width": c.width, "rgb": list(c.rgb), "agent": c.agent}
                     for c in view.cars],
    }
