"""ζσ's labels as a person can give them: the simulated annotator, and a ranker trained on its answers."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.special import expit

from rba.core.fileio import load_json
from rba.core.methods import get_method
from rba.data.labels import (
    GlobalLabelConfig,
    annotate_pairs,
    annotator_labels,
    flip_temperature,
    labelled_subset,
    sample_pairs,
)
from rba.learn.training import GlobalTrainConfig, train_global


class _Lib:
    """What the annotator reads of a library: its length and proxies."""

    def __init__(self, proxies: np.ndarray) -> None:
        self.proxies = proxies

    def __len__(self) -> int:
        return len(self.proxies)


def _lib(n: int, k: int = 2, seed: int = 0) -> _Lib:
    return _Lib(np.random.default_rng(seed).normal(size=(n, k)))


@pytest.mark.parametrize("noise", [0.1, 0.2])
def test_the_flip_share_matches_the_asked_noise_on_many_pairs(noise):
    rng = np.random.default_rng(3)
    values = rng.gamma(2.0, size=2000)  # skewed, as proxies are
    pairs = sample_pairs(len(values), 40_000, rng)
    answered, stats = annotate_pairs(values, pairs, GlobalLabelConfig("pairwise", 40_000, noise, 0.1), rng)
    assert stats["answered"] == len(answered) == 36_000 and stats["cant_tell"] == 4_000
    wrong = sum(values[hi] < values[lo] for hi, lo in answered)
    assert wrong == stats["flipped"]
    assert abs(wrong / len(answered) - noise) < 0.01, wrong / len(answered)


def test_the_temperature_gives_the_expected_flip_share_exactly_and_none_without_noise():
    d = np.abs(np.random.default_rng(0).normal(size=500))
    for noise in (0.05, 0.1, 0.2, 0.4):
        t = flip_temperature(d, noise)
        assert np.mean(expit(-d / t)) == pytest.approx(noise, abs=1e-6)
    assert flip_temperature(d, 0.0) == 0.0
    assert flip_temperature(d, 0.2) < flip_temperature(2 * d, 0.2)  # in the proxy's units


def test_without_noise_every_answer_is_the_truth_and_exact_ties_are_never_answered():
    values = np.array([0.0, 0.0, 1.0, 3.0])
    pairs = sample_pairs(4, 100, np.random.default_rng(0))
    assert len(pairs) == 6 and (pairs[:, 0] < pairs[:, 1]).all()
    answered, stats = annotate_pairs(values, pairs, GlobalLabelConfig("pairwise", 6, 0.0, 0.0),
                                     np.random.default_rng(0))
    assert sorted(answered) == [(2, 0), (2, 1), (3, 0), (3, 1), (3, 2)]  # (0, 1) tie: "can't tell"
    assert stats == {"answered": 5, "cant_tell": 1, "flipped": 0, "temperature": 0.0}


def test_cant_tell_drops_the_closest_pairs():
    values = np.array([0.0, 0.1, 0.5, 2.0, 5.0])
    pairs = sample_pairs(5, 10, np.random.default_rng(0))
    answered, stats = annotate_pairs(values, pairs, GlobalLabelConfig("pairwise", 10, 0.0, 0.3),
                                     np.random.default_rng(0))
    assert stats["cant_tell"] == 3 and len(answered) == 7
    dropped = {frozenset(map(int, p)) for p in pairs} - {frozenset(p) for p in answered}
    assert dropped == {frozenset((0, 1)), frozenset((1, 2)), frozenset((0, 2))}  # gaps 0.1, 0.4, 0.5
    assert all(values[hi] > values[lo] for hi, lo in answered)


def test_the_annotator_never_exceeds_its_pairs_or_clips_and_stays_among_the_labelled_ones():
    lib = _lib(500, k=3)
    labels, stats = annotator_labels(lib, 200, GlobalLabelConfig("pairwise", 1000, 0.1, 0.1), seed=4)
    subset = set(labelled_subset(lib, 200, 4).tolist())
    assert stats["pairs_shown"] == 1000 and stats["clips"] == 200 and len(stats["per_attribute"]) == 3
    shown = None
    for lab, st in zip(labels, stats["per_attribute"], strict=True):
        assert lab.num_pairs == st["answered"] == 900 and len(lab.clips) <= 200
        assert set(lab.clips.tolist()) <= subset
        pairs = {frozenset(p) for p in lab.pairs().tolist()}
        shown = pairs if shown is None else shown | pairs
    assert len(shown) <= 1000  # every attribute answers the same shown pairs
    few, small = annotator_labels(_lib(10), 200, GlobalLabelConfig("pairwise", 1000), seed=0)
    assert small["pairs_shown"] == 45 and small["clips"] == 10 and few[0].num_pairs <= 45


def test_the_annotator_is_seeded_and_deterministic():
    lib, cfg = _lib(300), GlobalLabelConfig("pairwise", 500, 0.2, 0.1)
    a, sa = annotator_labels(lib, 200, cfg, seed=7)
    b, sb = annotator_labels(lib, 200, cfg, seed=7)
    c, _ = annotator_labels(lib, 200, cfg, seed=8)
    assert sa == sb
    assert all(np.array_equal(x.pairs(), y.pairs()) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a[0].pairs(), c[0].pairs())


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"mode": "ranking"}, "'ordering' or 'pairwise'"),
    ({"noise": 0.5}, "[0, 0.5)"),
    ({"cant_tell": 1.0}, "can't-tell share"),
    ({"max_pairs": 0}, "max_pairs"),
])
def test_a_label_config_out_of_range_says_what_is_valid(kwargs, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace("[", r"\[").replace(")", r"\)")):
        GlobalLabelConfig(**kwargs)


def test_the_pairwise_preset_is_rba_globals_only():
    assert "pairwise" in get_method("global").presets and "pairwise" not in get_method("local").presets
    labels = GlobalTrainConfig.preset("pairwise", seed=3, domain="walker").ranker.labels
    assert labels == GlobalLabelConfig("pairwise", max_pairs=1000, noise=0.1, cant_tell=0.1)
    assert GlobalTrainConfig.preset("default").ranker.labels.mode == "ordering"


def test_a_tiny_ranker_learns_from_pairwise_labels_and_its_card_says_how_they_were_made(toy_roots, tmp_path):
    data, models, _ = toy_roots
    base = GlobalTrainConfig.preset("tiny", seed=0)
    labels = GlobalLabelConfig("pairwise", max_pairs=400, noise=0.1, cant_tell=0.1)
    metrics = train_global("toy", "onehot", replace(base, ranker=replace(base.ranker, labels=labels)),
                           data_root=data, models_root=tmp_path)
    assert all(m["pairwise_accuracy"] > 0.85 for m in metrics["ranker"].values()), metrics["ranker"]
    card = load_json(tmp_path / "toy" / "ranker-onehot.json")["training"]
    assert card["labels"]["mode"] == "pairwise" and card["labels"]["pairs_shown"] == 400
    assert card["labels"]["clips"] == 120 and set(card["labels"]["per_attribute"]) == {"amplitude", "pace"}
    assert card["labelled_pairs"] == [360, 360]
    assert 10 < card["labels"]["per_attribute"]["pace"]["flipped"] < 70  # ~36 expected
    perfect = load_json(models / "toy" / "ranker-onehot.json")["training"]
    assert perfect["labels"]["mode"] == "ordering" and perfect["labelled_pairs"] == [7140, 7140]
