"""A clip as data (``rba.media.clip_data``): for every registered domain the data has the MP4's frames and decodes;
MuJoCo poses are the renderer's; lane change cars sit where highway-env draws them."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from rba.compute import DataJob
from rba.compute.tasks import describe
from rba.data.library import SkillLibrary
from rba.domains import domain_names, domain_target, get_domain, load_domain
from rba.domains.mujoco_render import MujocoView
from rba.media import clip_data
from tests.example_domain import example_target

SMALL = (32, 24)  # frames counted at a size that renders fast


def _rollout(name: str):
    """A stored rollout where the domain has a serve library (every shipped one), else a short simulated one."""
    try:
        return SkillLibrary.load(name, "serve").rollout(0)
    except FileNotFoundError:
        domain = get_domain(name)
        return domain.rollout(domain.sample_params(np.random.default_rng(0)), 0)


def _decode(target: str, rollout) -> tuple[dict, dict]:
    scene = clip_data.decode(describe(target, 320, 240))
    return scene, clip_data.decode(describe(target, 320, 240, rollout))


@pytest.mark.parametrize("name", domain_names())
def test_every_domain_s_clip_data_has_the_mp4_s_frames_or_is_refused_clearly(name):
    domain, rollout = get_domain(name), _rollout(name)
    if not domain.draws_clips:
        with pytest.raises(clip_data.NoClipData, match="MP4s only"):
            describe(domain_target(name), 320, 240, rollout)
        return
    scene, clip = _decode(domain_target(name), rollout)
    frames = sum(1 for _ in domain.render(rollout, *SMALL))
    assert clip["frames"] == frames == len(rollout.replay) and clip["frame_rate"] == domain.frame_rate
    assert clip["scene_url"] == f"/api/clips/{name}/scene.json?v={scene['version']}"
    assert scene["domain"] == name and scene["kind"] in ("mujoco", "plane2d")
    if scene["kind"] == "mujoco":
        g = clip["geoms"]
        assert g == len(scene["geoms"]) and any(s["agent"] for s in scene["geoms"])
        assert any(not s["agent"] for s in scene["geoms"])  # the floor
        for field, width in (("pos", 3), ("quat", 4)):
            assert np.isfinite(clip_data.floats(clip[field], frames, g, width)).all()
        assert clip_data.floats(clip["lookat"], frames, 3).shape == (frames, 3)
    else:
        assert clip_data.floats(clip["vehicles"], frames, len(scene["vehicles"]), 3).shape[0] == frames
    assert {o["attribute"] for o in clip["overlays"]} == set(domain.attribute_names)
    assert all(0 <= m["frame"] < frames for o in clip["overlays"] for m in o["markers"])
    assert domain.description in clip["description"]


def test_the_toy_domain_has_no_clip_data():
    toy = get_domain("toy")
    assert not toy.draws_clips
    with pytest.raises(clip_data.NoClipData):
        describe(domain_target("toy"), 320, 240)


@pytest.mark.parametrize("name", ["walker", "manipulator", "snake"])
def test_geom_poses_are_the_renderer_s(name):
    """Every frame's geoms where the MP4's renderer poses them: mj_fwdPosition of the replay row, then the scene
    mjv_updateScene makes of it (what mujoco.Renderer draws)."""
    domain, rollout = get_domain(name), _rollout(name)
    scene, clip = _decode(domain_target(name), rollout)
    frames, g = clip["frames"], clip["geoms"]
    pos = clip_data.floats(clip["pos"], frames, g, 3)
    quat = clip_data.floats(clip["quat"], frames, g, 4)
    lookat = clip_data.floats(clip["lookat"], frames, 3)
    view: MujocoView = domain.clip_view(rollout)
    data, scn = mujoco.MjData(view.model), mujoco.MjvScene(view.model, maxgeom=1000)
    for i in (0, frames // 2, frames - 1):
        data.qpos[:] = rollout.replay[i]
        mujoco.mj_fwdPosition(view.model, data)
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = view.camera.aim(data) if view.camera.aim else view.camera.lookat
        mujoco.mjv_updateScene(view.model, data, mujoco.MjvOption(), None, cam, mujoco.mjtCatBit.mjCAT_ALL, scn)
        drawn = [geom for geom in scn.geoms[: scn.ngeom] if geom.rgba[3] > 0]
        assert len(drawn) == g
        np.testing.assert_allclose(lookat[i], cam.lookat, atol=1e-4)  # 0.06 mm steps (clip_data.POSITION_STEP)
        for j, geom in enumerate(drawn):
            assert scene["geoms"][j]["type"] == clip_data._GEOM_TYPES[int(geom.type)]
            np.testing.assert_allclose(pos[i, j], geom.pos, atol=1e-4)
            mat = np.empty(9)
            q = quat[i, j].astype(np.float64)
            mujoco.mju_quat2Mat(mat, q / np.linalg.norm(q))
            np.testing.assert_allclose(mat, geom.mat.reshape(-1), atol=2e-4)


def test_mat_to_quat_matches_mujoco():
    rng = np.random.default_rng(0)
    quats = rng.standard_normal((200, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    mats = np.empty((200, 9))
    for q, m in zip(quats, mats, strict=True):
        mujoco.mju_quat2Mat(m, q)
    mine = clip_data.mat_to_quat(mats)
    assert np.allclose(np.abs((mine * quats).sum(1)), 1.0, atol=1e-9)  # q and -q are one rotation


def test_lane_change_cars_follow_the_rollout_where_highway_env_draws_them():
    domain, rollout = get_domain("lane_change"), _rollout("lane_change")
    scene, clip = _decode(domain_target("lane_change"), rollout)
    frames, cars = clip["frames"], scene["vehicles"]
    poses = clip_data.floats(clip["vehicles"], frames, len(cars), 3)
    np.testing.assert_allclose(poses, rollout.replay.reshape(frames, 2, 3), atol=1e-4)
    view, ppm = scene["view"], scene["view"]["pixels_per_metre"]
    for i in (0, frames // 2, frames - 1):
        image = next(domain.render(rollout, 320, 240, slice(i, i + 1)))
        centre = poses[i, view["centre_on"], :2]
        for car, (x, y, _) in zip(cars, poses[i], strict=True):
            px = int((x - centre[0] + view["offset"][0]) * ppm)
            py = int((y - centre[1] + view["offset"][1]) * ppm)
            if car["agent"] or 0 <= px < 320:  # the ego is always in view; the follower may drop behind it
                assert tuple(image[py, px]) == tuple(car["rgb"]), (i, car)  # the car's body at its centre
    assert scene["lanes"]["count"] == 2 and [line["kind"] for line in scene["lanes"]["lines"]] == [
        "continuous", "striped", "continuous"]


def test_walker_overlays_read_what_the_proxies_measure():
    """Footprints at the three touchdowns; the later two strides' mean is the step size proxy (within the frames'
    resolution), and the description says both attributes' readings."""
    lib = SkillLibrary.load("walker", "serve")
    for i in (0, 1, 2):
        rollout = lib.rollout(i)
        clip = clip_data.decode(describe(domain_target("walker"), 320, 240, rollout))
        steps = next(o for o in clip["overlays"] if o["attribute"] == "step_size")
        strides = [float(m["text"].split()[0]) for m in steps["markers"]]
        assert len(strides) == 3 and abs(np.mean(strides[1:]) - rollout.proxies["step_size"]) < 0.05
        assert f"landing speed {-rollout.proxies['softness']:.3g} m/s" in clip["description"]


def test_a_gym_mujoco_plugin_domain_has_clip_data_without_code_of_its_own():
    cheetah = load_domain(example_target())
    rollout = cheetah.rollout(cheetah.sample_params(np.random.default_rng(0)), 0)
    assert cheetah.draws_clips
    scene, clip = _decode(example_target(), rollout)
    assert scene["kind"] == "mujoco" and clip["frames"] == len(rollout.replay)
    assert any(g["agent"] for g in scene["geoms"]) and scene["sky"] is not None


def test_a_compute_worker_makes_the_same_bytes_as_this_process(local_compute):
    """What the app stores comes from a worker (``Compute.clip_data``): the same bytes as ``describe`` here, so a
    clip's data, like its MP4, does not depend on where it was made."""
    rollout = _rollout("walker")
    for job in (DataJob.of("walker", rollout, 320, 240), DataJob.of("walker", None, 320, 240)):
        made = local_compute.clip_data(job, urgent=False).future.result(120)
        assert made == describe(job.target, 320, 240, job.rollout)
