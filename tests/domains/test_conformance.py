"""One contract test over every registered domain (dm_control suite style), and the example plugin domain
(``examples/halfcheetah``) where it is not installed."""

import numpy as np
import pytest

from rba.domains import domain_names, get_domain, load_domain
from tests.example_domain import NAME, example_target

EXAMPLE = [] if NAME in domain_names() else [NAME]  # installed: registered through its entry point


@pytest.fixture(params=[*domain_names(), *EXAMPLE])
def domain(request):
    return load_domain(example_target()) if request.param in EXAMPLE else get_domain(request.param)


def test_attributes_are_well_formed(domain):
    assert len(domain.attributes) >= 2
    for a in domain.attributes:
        assert a.name.isidentifier() and a.name == a.name.lower()
        assert a.description.endswith(".") and a.unit
        assert a.reading is None or (a.reading.sign in (-1, 1) and a.reading.label and a.reading.note)


def test_equal_seeds_give_equal_rollouts(domain):
    params = domain.sample_params(np.random.default_rng(7))
    a, b = domain.rollout(params, seed=3), domain.rollout(params, seed=3)
    np.testing.assert_array_equal(a.states, b.states)
    np.testing.assert_array_equal(a.replay, b.replay)
    assert a.proxies == b.proxies and a.success == b.success


def test_rollouts_are_finite_and_shaped(domain):
    rng = np.random.default_rng(0)
    for seed in range(3):
        r = domain.rollout(domain.sample_params(rng), seed)
        assert r.states.dtype == np.float32 and r.states.ndim == 2 and r.states.shape[1] == domain.state_dim
        assert len(r.states) >= 5 and np.isfinite(r.states).all()
        assert r.replay.ndim == 2 and len(r.replay) >= 2 and np.isfinite(r.replay).all()
        assert set(r.proxies) == set(domain.attribute_names)
        assert all(np.isfinite(v) for v in r.proxies.values())
        assert set(r.params) == set(domain.param_names)


def test_render_is_deterministic_uint8(domain):
    r = domain.rollout(domain.sample_params(np.random.default_rng(1)), seed=0)
    r.replay = r.replay[:3]
    first = list(domain.render(r, 64, 48))
    again = list(domain.render(r, 64, 48))
    assert len(first) == 3
    for f, g in zip(first, again, strict=True):
        assert f.shape == (48, 64, 3) and f.dtype == np.uint8 and f.std() > 0
        np.testing.assert_array_equal(f, g)


def test_a_clip_rendered_in_parts_has_the_frames_of_the_whole_clip(domain):
    """The compute layer renders a clip's parts on separate workers (``RenderJob.parts``): every frame must be
    the one the whole clip has, wherever its part starts (a camera aimed from the first row, a sky drawn once)."""
    r = domain.rollout(domain.sample_params(np.random.default_rng(2)), seed=0)
    r.replay = r.replay[: min(len(r.replay), 40): 4]  # ten rows a few steps apart: the body moves between parts
    parts = {rows.start: list(domain.render(r, 64, 48, rows))  # the last part first: no part leans on another
             for rows in (slice(7, None), slice(3, 7), slice(0, 3))}
    parts = [f for start in sorted(parts) for f in parts[start]]
    whole = list(domain.render(r, 64, 48))
    assert len(whole) == len(parts) == len(r.replay)
    for i, (f, g) in enumerate(zip(whole, parts, strict=True)):
        np.testing.assert_array_equal(f, g, err_msg=f"frame {i}")


def test_sample_params_stay_inside_the_declared_parameter_space(domain):
    """What ``rba.generate.cma`` may search covers every parameter the domain's own sampler draws."""
    space = domain.param_space()
    assert space.names == domain.param_names and space.fixed <= set(space.names)
    assert all(space.low[k] < space.high[k] for k in space.names) and space.free
    rng = np.random.default_rng(11)
    for _ in range(200):
        params = domain.sample_params(rng)
        assert space.contains(params), {k: (space.low[k], v, space.high[k]) for k, v in params.items()}
        back = space.from_unit(space.to_unit(params), params)
        np.testing.assert_allclose([back[k] for k in space.names], [params[k] for k in space.names], rtol=1e-12)
