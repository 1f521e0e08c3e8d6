"""ζσ pooled by mean (``RankerConfig.pool``, ``Domain.ranker_pool``): what it computes, and that it survives a save."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from rba.artifacts import load_model, save_model
from rba.domains import domain_names, get_domain
from rba.learn.common import Ragged
from rba.learn.ranker import AttributeRanker, RankerConfig
from rba.training import GlobalTrainConfig


def _ranker(pool: str) -> AttributeRanker:
    torch.manual_seed(0)
    model = AttributeRanker(4, torch.eye(2), hidden=16, layers=2, pool=pool)
    with torch.no_grad():
        model.f[-1].weight.mul_(100.0)  # away from the tiny initial last layer: scores that differ
    return model


def _clips() -> tuple[np.ndarray, Ragged, Ragged]:
    """Two clips of 3 and 5 states, and the same two clips each played twice over (twice the length)."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(3, 4)).astype(np.float32), rng.normal(size=(5, 4)).astype(np.float32)
    once = Ragged.from_numpy(np.concatenate([a, b]), np.array([0, 3, 8]))
    twice = Ragged.from_numpy(np.concatenate([a, a, b, b]), np.array([0, 6, 16]))
    return np.concatenate([a, b]), once, twice


def test_a_mean_pooled_zeta_is_the_clipped_mean_of_f_and_ignores_how_long_a_behaviour_is_played():
    states, once, twice = _clips()
    mean, summed = _ranker("mean"), _ranker("sum")
    f = torch.stack([mean.per_state(torch.as_tensor(states), a) for a in range(2)], 1).detach().numpy()
    expected = 20.0 * np.tanh(np.stack([f[:3].mean(0), f[3:].mean(0)]) / 20.0)
    np.testing.assert_allclose(mean.score(once), expected, atol=1e-5)
    np.testing.assert_allclose(mean.score(twice), mean.score(once), atol=1e-5)
    assert not np.allclose(summed.score(twice), summed.score(once), atol=1e-3)  # the paper's sum counts the states
    seg = once.segment_ids()
    training = mean.trajectory_scores(once.states, seg, 2, 1).detach().numpy()  # what the loss sees
    np.testing.assert_allclose(training, expected[:, 1], atol=1e-5)


@pytest.mark.parametrize("pool", ["sum", "mean"])
def test_pooled_features_under_the_trained_head_give_the_rankers_scores(pool):
    _, once, _ = _clips()
    ranker = _ranker(pool)
    phi, lengths = ranker.pooled_features(once)
    np.testing.assert_allclose(ranker.zeta_of(phi, lengths, *ranker.trained_head()), ranker.score(once), atol=1e-4)
    assert lengths.tolist() == ([3.0, 5.0] if pool == "sum" else [1.0, 1.0])


def test_the_pooling_is_saved_on_the_card_and_an_unknown_one_is_refused(tmp_path):
    ranker = _ranker("mean")
    card = {"domain": "toy", "kind": "ranker", "representation": "onehot",
            "architecture": {"state_dim": 4, "num_attributes": 2, "embed_dim": 2, "hidden": 16, "layers": 2,
                             "clip": 20.0, "pool": "mean"}}
    save_model(ranker, card, tmp_path)
    loaded = load_model("toy", "ranker", "onehot", tmp_path).model
    _, once, _ = _clips()
    assert loaded.pool == "mean"
    np.testing.assert_allclose(loaded.score(once), ranker.score(once), atol=1e-6)
    with pytest.raises(ValueError, match=r"unknown ζσ pooling 'max'; valid: sum, mean"):
        RankerConfig(pool="max")
    with pytest.raises(ValueError, match=r"unknown ζσ pooling 'Mean'"):
        AttributeRanker(4, torch.eye(2), pool="Mean")


def test_the_domain_chooses_the_pooling_of_its_trained_zeta(monkeypatch):
    for name in domain_names():
        assert GlobalTrainConfig.preset("pairwise", 0, name).ranker.pool == get_domain(name).ranker_pool
    monkeypatch.setattr(type(get_domain("walker")), "ranker_pool", "mean")
    assert GlobalTrainConfig.preset("default", 0, "walker").ranker.pool == "mean"
    assert GlobalTrainConfig.preset("tiny", 0, "walker").ranker.pool == "sum"  # CI's smoke preset keeps its own
