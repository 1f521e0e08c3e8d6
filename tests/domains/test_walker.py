"""Walker domain: proxies follow the commanded gait, rollouts are deterministic, render works."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from rba.domains.walker import FRAME_RATE, STATE_EVERY, GaitController, GaitPlan, Walker

BASE = {"step_length": 0.5, "landing_speed": 0.5, "swing_duration": 0.5, "swing_height": 0.08}


@pytest.fixture(scope="module")
def walker() -> Walker:
    return Walker()


def _run(walker: Walker, seed: int = 0, **overrides: float):
    return walker.rollout({**BASE, **overrides}, seed)


def test_contract(walker: Walker) -> None:
    assert walker.attribute_names == ("step_size", "softness")
    params = walker.sample_params(np.random.default_rng(0))
    assert tuple(params) == walker.param_names
    r = walker.rollout(params, 3)
    assert r.id == "" and r.domain == "walker" and r.seed == 3
    assert r.states.dtype == np.float32 and r.states.ndim == 2 and r.states.shape[1] == walker.state_dim
    assert r.replay.dtype == np.float64 and r.replay.shape[1] == 9
    # states every STATE_EVERY physics steps and frames at FRAME_RATE cover the same clip
    expected = FRAME_RATE * STATE_EVERY * walker.physics().timestep()
    assert abs(len(r.replay) / len(r.states) - expected) < 0.05 * expected
    assert set(r.proxies) == {"step_size", "softness"}
    assert all(np.isfinite(v) for v in r.proxies.values())
    assert np.isfinite(r.states).all()


def test_step_size_follows_command(walker: Walker) -> None:
    short, long = _run(walker, step_length=0.2), _run(walker, step_length=0.8)
    assert short.success and long.success
    assert short.proxies["step_size"] == pytest.approx(0.2, abs=0.05)
    assert long.proxies["step_size"] == pytest.approx(0.8, abs=0.05)
    # landing softness barely depends on the step length
    assert abs(short.proxies["softness"] - long.proxies["softness"]) < 0.15


def test_softness_follows_landing_speed(walker: Walker) -> None:
    gentle, stomp = _run(walker, landing_speed=0.15), _run(walker, landing_speed=1.2)
    assert gentle.success and stomp.success
    assert gentle.proxies["softness"] > stomp.proxies["softness"] + 0.6
    assert -gentle.proxies["softness"] == pytest.approx(0.15, abs=0.08)  # landing speed, m/s
    assert abs(gentle.proxies["step_size"] - stomp.proxies["step_size"]) < 0.05


def test_deterministic(walker: Walker) -> None:
    a, b = _run(walker, seed=7), Walker().rollout({**BASE}, 7)
    assert np.array_equal(a.states, b.states) and np.array_equal(a.replay, b.replay)
    assert a.proxies == b.proxies and a.success == b.success
    c = _run(walker, seed=8)  # the seed perturbs the start a little
    assert not np.array_equal(a.states, c.states)


def test_render_frames(walker: Walker) -> None:
    r = _run(walker)
    r.replay = r.replay[::40][:3]  # a few frames keep the test fast
    frames = list(walker.render(r, 96, 64))
    assert len(frames) == len(r.replay)
    for f in frames:
        assert f.dtype == np.uint8 and f.shape == (64, 96, 3)
        assert f.std() > 1.0  # not a constant image
    again = list(walker.render(r, 96, 64))
    assert all(np.array_equal(f, g) for f, g in zip(frames, again, strict=True))


def test_geometry_is_the_models(walker: Walker) -> None:
    """The dimensions come from the MuJoCo model, bit for bit the XML's numbers (the gait depends on every bit)."""
    geo = walker.physics().geometry
    assert (geo.torso_z0, geo.torso_to_hip, geo.thigh, geo.shank, geo.ankle_to_foot) == (1.3, 0.3, 0.45, 0.5, 0.06)
    assert (geo.foot_radius, geo.foot_half, geo.thigh_radius, geo.torso_radius, geo.torso_half) == (
        0.05, 0.1, 0.05, 0.07, 0.3)
    assert geo.joint_low == (math.radians(-20), math.radians(-150), math.radians(-45))
    assert geo.joint_high == (math.radians(100), 0.0, math.radians(45)) and geo.gear == (100.0, 50.0, 20.0)


def test_planar_kinematics_agree_with_mujoco(walker: Walker) -> None:
    """Named getters (hand-written planar kinematics) match MuJoCo's own positions to rounding."""
    physics = walker.physics()
    model, data = physics.model, physics.data
    rng = np.random.default_rng(0)
    foot = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"{side}_foot") for side in ("right", "left")]
    ankle = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{side}_ankle") for side in ("right", "left")]
    thigh = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "right_thigh")
    for _ in range(20):
        data.qpos[:] = rng.normal(0.0, 0.4, model.nq)
        mujoco.mj_kinematics(model, data)
        physics.observe()
        assert physics.torso_height() == pytest.approx(data.xpos[1, 2], abs=1e-12)
        np.testing.assert_allclose(physics.hip_position(), data.xpos[thigh, [0, 2]], atol=1e-12)
        for leg in (0, 1):
            np.testing.assert_allclose(physics.foot_positions()[leg], data.geom_xpos[foot[leg], [0, 2]], atol=1e-12)
            np.testing.assert_allclose(physics.ankle_positions()[leg], data.xanchor[ankle[leg], [0, 2]], atol=1e-12)


def test_controller_commands_stay_in_range(walker: Walker) -> None:
    """The gait controller's motor commands are normalised (the motors' ctrlrange) and the assist is finite."""
    physics = walker.physics()
    plan = GaitPlan.from_params(BASE, physics.geometry)
    physics.reset(np.array(plan.start_pose(physics.geometry)), np.zeros(physics.model.nv))
    controller = GaitController(plan, physics)
    for step in range(800):
        physics.observe()
        command = controller.control(step * physics.timestep(), physics)
        assert len(command.ctrl) == 6 and all(-1.0 <= u <= 1.0 for u in command.ctrl)
        assert all(math.isfinite(f) for f in command.assist)
        physics.act(command.ctrl, command.assist)
    assert len(controller.touchdowns) >= 1  # 2 s in: the first step has landed
