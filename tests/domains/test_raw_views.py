"""The raw views (``<domain>_raw``, ``--states raw``): the base domain's behaviour, seen through the simulator's
own positions and velocities instead of hand-made features."""

from __future__ import annotations

import numpy as np
import pytest

from rba.cli import main
from rba.core.store import Store
from rba.data.library import SPLITS, SkillLibrary
from rba.domains import domain_names, get_domain

BASES = ("walker", "manipulator", "lane_change", "snake")
# columns of a raw state's first sample that are the positions the replay's first row holds (replay[0] order)
REPLAY_COLUMNS = {
    "walker": list(range(9)),  # qpos
    "manipulator": list(range(11)),  # qpos
    "snake": list(range(20)),  # qpos
    "lane_change": [0, 1, 4, 5, 6, 9],  # ego x, y, heading; follower x, y, heading
}
PER_SPLIT = 4  # shipped rollouts compared per split


def test_every_base_domain_has_a_registered_raw_view():
    assert {f"{b}_raw" for b in BASES} <= set(domain_names())
    for base in BASES:
        raw, kin = get_domain(f"{base}_raw"), get_domain(base)
        assert raw.raw_states and not kin.raw_states and raw.state_dim != kin.state_dim
        assert (raw.attributes, raw.param_names, raw.frame_rate, raw.serve_size) == (
            kin.attributes, kin.param_names, kin.frame_rate, kin.serve_size)
        assert raw.sample_params(np.random.default_rng(4)) == kin.sample_params(np.random.default_rng(4))


@pytest.mark.parametrize("base", BASES)
def test_a_raw_rollout_is_the_same_behaviour_with_raw_states(base):
    kin, raw = get_domain(base), get_domain(f"{base}_raw")
    params = kin.sample_params(np.random.default_rng(11))
    a, b = kin.rollout(params, seed=2), raw.rollout(params, seed=2)
    np.testing.assert_array_equal(a.replay, b.replay)
    assert (a.proxies, a.success, a.params, a.seed) == (b.proxies, b.success, b.params, b.seed)
    assert b.domain == f"{base}_raw" and b.states.dtype == np.float32
    assert b.states.shape[1] == raw.state_dim and a.states.shape[1] == kin.state_dim
    # the first sample of the first raw state is the pose the replay starts from: positions as simulated
    np.testing.assert_array_equal(b.states[0, REPLAY_COLUMNS[base]], np.asarray(a.replay[0], dtype=np.float32))


def _shipped_pairs() -> list[tuple[str, str]]:
    store = Store.from_settings()
    return [(b, s) for b in BASES for s in SPLITS
            if store.libraries.complete(f"{b}_raw", s) and store.libraries.complete(b, s)]


@pytest.mark.parametrize(("base", "split"), _shipped_pairs())
def test_shipped_raw_libraries_hold_the_base_librarys_rollouts(base, split):
    """Same ids, params, seeds, proxies and success as the base's split; a sample's replay equal, states not."""
    kin, raw = SkillLibrary.load(base, split), SkillLibrary.load(f"{base}_raw", split)
    assert raw.ids == kin.ids
    for name in ("seeds", "success"):
        np.testing.assert_array_equal(getattr(raw, name), getattr(kin, name), err_msg=f"{split} {name}")
    # params and proxies: equal but for the last bits where the raw view was built on another machine
    for name in ("params", "proxies"):
        np.testing.assert_allclose(getattr(raw, name), getattr(kin, name), rtol=1e-9, atol=1e-12, err_msg=name)
    assert raw.states.shape[1] == get_domain(f"{base}_raw").state_dim
    for i in sorted({int(i) for i in np.linspace(0, len(kin) - 1, PER_SPLIT).round()}):
        a, b = kin.rollout(i), raw.rollout(i)
        np.testing.assert_array_equal(a.replay, b.replay, err_msg=a.id)
        assert a.proxies == pytest.approx(b.proxies, rel=1e-9), a.id


def test_states_raw_picks_the_view_and_a_missing_one_names_the_valid_views(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("RBA_DATA_DIR", str(tmp_path))
    assert main(["render", "snake", "serve-00001", str(tmp_path / "x.mp4"), "--states", "raw"]) == 2
    assert "run `rba build snake_raw`" in capsys.readouterr().err
    assert main(["eval", "--domain", "manipulator", "--states", "image"]) == 2
    assert capsys.readouterr().err == "rba: error: domain 'manipulator' has no 'image' states; valid: kinematic, raw\n"
