"""MuJoCo clip rendering: the shortcuts (position pass, the sky drawn once) draw what the full render draws."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from rba.domains import get_domain
from rba.domains.mujoco_render import Sky, ThreadRenderers


@pytest.mark.parametrize("name", ["walker", "manipulator", "snake"])
def test_the_position_pass_draws_what_a_full_forward_draws(name, monkeypatch):
    domain = get_domain(name)
    r = domain.rollout(domain.sample_params(np.random.default_rng(1)), seed=0)
    r.replay = r.replay[:: max(len(r.replay) // 4, 1)][:4]  # start, middle, end: a few frames keep it fast
    fast = list(domain.render(r, 64, 48))
    monkeypatch.setattr(mujoco, "mj_fwdPosition", mujoco.mj_forward)
    full = list(domain.render(r, 64, 48))
    assert len(fast) == len(full) == len(r.replay)
    for f, g in zip(fast, full, strict=True):
        np.testing.assert_array_equal(f, g)


def test_only_the_snake_turns_the_floor_reflection_off():
    """The walker's and the arm's reflections show where they touch the floor; the snake always lies on it."""
    assert get_domain("walker")._renderers.reflection and get_domain("manipulator")._renderers.reflection
    snake = get_domain("snake")
    assert not snake._renderers.reflection
    renderer = snake._renderers.get(snake._physics(), 64, 48)
    assert renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] == 0


def test_the_walkers_sky_pasted_in_is_the_sky_drawn_every_frame(monkeypatch):
    """The camera slides with the torso; the sky drawn once a clip must look as if drawn in every frame."""
    walker = get_domain("walker")
    assert walker._renderers.sky is Sky.ONCE
    r = walker.rollout(walker.sample_params(np.random.default_rng(2)), seed=0)
    r.replay = r.replay[::8]  # the whole walk, a frame in eight: the camera slides the whole way
    pasted = list(walker.render(r, 96, 64))
    monkeypatch.setattr(walker, "_renderers", ThreadRenderers())
    drawn = list(walker.render(r, 96, 64))
    assert len(pasted) == len(drawn) == len(r.replay)
    for f, g in zip(pasted, drawn, strict=True):
        np.testing.assert_array_equal(f, g)


def test_the_snake_never_sees_the_sky_it_does_not_draw(monkeypatch):
    snake = get_domain("snake")
    assert snake._renderers.sky is Sky.HIDDEN
    r = snake.rollout(snake.sample_params(np.random.default_rng(3)), seed=0)
    r.replay = r.replay[::10]
    hidden = list(snake.render(r, 96, 64))
    monkeypatch.setattr(snake, "_renderers", ThreadRenderers(reflection=False))
    for f, g in zip(hidden, snake.render(r, 96, 64), strict=True):
        np.testing.assert_array_equal(f, g)
