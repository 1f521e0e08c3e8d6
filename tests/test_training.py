"""The training side's shared pieces: presets, the one Bradley-Terry loss, the step loop, state encoders."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.nn import functional as F

from rba.data.labels import AttributeLabels, LocalPairs
from rba.learn.common import StepLoop, bradley_terry_loss
from rba.learn.training import ENCODER_TRAINERS, PRESETS, GlobalTrainConfig, LocalTrainConfig, prepare_states


def test_an_unknown_preset_names_the_valid_ones():
    assert PRESETS == ("default", "pairwise", "quick", "tiny")
    with pytest.raises(ValueError, match="unknown preset 'huge'; valid: default, pairwise, quick, tiny"):
        GlobalTrainConfig.preset("huge")
    for name in ("huge", "pairwise"):  # 'pairwise' only changes ζσ's labels: RBA-Local has none
        with pytest.raises(ValueError, match=f"unknown preset '{name}'; valid: default, quick, tiny"):
            LocalTrainConfig.preset(name)


def test_presets_set_the_seed_and_share_one_short_local_reward():
    quick, tiny = LocalTrainConfig.preset("quick", seed=4), LocalTrainConfig.preset("tiny", seed=4)
    assert (quick.reward.steps, quick.reward.hidden, quick.reward.lstm_hidden) == (150, 64, 32)
    assert quick.reward == tiny.reward and quick.reward.seed == 4 and quick.labels.seed == 4
    assert LocalTrainConfig.preset("default", 1).reward.steps == 1500
    g = GlobalTrainConfig.preset("quick", seed=2)
    assert (g.ranker.steps, g.reward.steps, g.reward.hidden, g.ranker.seed, g.reward.seed) == (800, 300, 128, 2, 2)
    assert GlobalTrainConfig.preset("tiny", 5).reward.seed == 5
    assert GlobalTrainConfig.preset("tiny").ranker is not GlobalTrainConfig.preset("tiny").ranker  # no shared state


def test_one_bradley_terry_loss_for_soft_labels_masks_and_weights():
    ra, rb = torch.tensor([2.0, -1.0, 0.5]), torch.tensor([0.0, 1.0, 0.5])
    pref = torch.tensor([1.0, 0.0, 0.5])
    want = -(torch.log(torch.sigmoid(ra - rb)) * pref + torch.log(torch.sigmoid(rb - ra)) * (1 - pref)).mean()
    assert torch.allclose(bradley_terry_loss(ra, rb, pref), want)
    w = torch.tensor([3.0, 0.0, 0.0])
    assert torch.allclose(bradley_terry_loss(ra, rb, pref, weight=w), F.softplus(-(ra - rb))[0] * 3 / 3)
    scores = torch.tensor([1.0, 0.0, -2.0])
    more = torch.tensor([[False, True, False], [False, False, True], [False, False, False]])
    pairwise = bradley_terry_loss(scores[:, None], scores[None, :], torch.ones(2), mask=more)
    assert torch.allclose(pairwise, F.softplus(-torch.tensor([1.0, 2.0])).mean())
    # without labels every pair prefers a: the same value (RBA-Local's softplus form)
    assert torch.allclose(bradley_terry_loss(scores[:, None], scores[None, :], mask=more), pairwise)
    with pytest.raises(ValueError, match="weight needs pref_a"):
        bradley_terry_loss(ra, rb, weight=w)


def test_the_step_loop_steps_and_reports_the_first_every_nth_and_last_step():
    p = torch.nn.Parameter(torch.tensor(1.0))
    reports = []
    loop = StepLoop(torch.optim.SGD([p], lr=0.1), steps=5, progress=lambda *a: reports.append(a), report_every=2)
    assert np.isnan(loop.loss)
    for step in range(5):
        loop.step(step, p ** 2)
    assert [r[0] for r in reports] == [1, 3, 5] and all(r[1] == 5 for r in reports)
    assert p.item() == pytest.approx(0.8 ** 5) and loop.loss == pytest.approx((0.8 ** 4) ** 2)


def test_label_pairs_round_trip():
    labels = AttributeLabels.from_values(np.array([4, 7, 9]), np.array([0.2, 0.9, 0.5]))
    assert sorted(map(tuple, labels.pairs().tolist())) == [(7, 4), (7, 9), (9, 4)]
    assert len(LocalPairs.from_rows([])) == 0
    assert LocalPairs.from_rows([(1, 2, 0, -1)]).direction.tolist() == [-1]


def test_prepare_states_trains_a_missing_encoder_once(monkeypatch, tmp_path):
    trained = []

    def train(domain, seed, root):
        trained.append((domain, seed))
        return {}

    monkeypatch.setitem(ENCODER_TRAINERS, "vae", train)
    prepare_states("lane_change_image", seed=3, models_root=tmp_path)  # none saved under tmp_path
    assert trained == [("lane_change_image", 3)]
    prepare_states("lane_change_image", seed=3)  # the shipped one is found
    prepare_states("manipulator", seed=3, models_root=tmp_path)  # needs no encoder
    assert trained == [("lane_change_image", 3)]


def test_lane_change_image_only_loads_its_vae_and_says_how_to_make_it(monkeypatch):
    from rba.core import artifacts
    from rba.domains.lane_change_image import LaneChangeImage

    def missing(*a, **k):
        raise artifacts.ModelNotFoundError("gone")

    monkeypatch.setattr(artifacts, "load_model", missing)
    with pytest.raises(artifacts.ModelNotFoundError, match=r"rba build lane_change --states image"):
        LaneChangeImage().rollout({"lateral_gain": 1.0, "gap": 10.0}, seed=0)
    assert not hasattr(LaneChangeImage, "prepare")
