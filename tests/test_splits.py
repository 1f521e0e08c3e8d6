"""Tune on val, report on test: the splits' streams, the shipped libraries and every model card keep them apart."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rba.core.fileio import load_json
from rba.core.store import Store
from rba.data.library import HELD_OUT, SPLIT_CODES, SPLITS, SkillLibrary, build_all
from rba.domains import domain_names
from rba.learn.training import TUNED, tuning_record

FIRST_TEST_CODE = 2  # the first release's test split: tuned on, so it became val


def test_every_split_has_its_own_stream_and_test_is_not_the_one_tuned_on():
    assert set(SPLIT_CODES) == set(SPLITS) and len(set(SPLIT_CODES.values())) == len(SPLITS)
    assert SPLIT_CODES["val"] == FIRST_TEST_CODE and SPLIT_CODES["test"] != FIRST_TEST_CODE
    assert HELD_OUT == ("val", "test")


def _cards() -> list[Path]:
    root = Store.from_settings().models_dir
    return sorted(p for p in root.glob("*/*.json") if p.with_suffix(".pt").exists())


def test_no_model_card_names_test_as_tuning_or_held_out_data():
    cards = _cards()
    assert len(cards) >= 20, "the shipped model cards are missing"
    for path in cards:
        card = load_json(path)
        assert card.get("tuning", {}).get("split") == "val", f"{path}: tuning must say split val"
        assert "test" not in card.get("data", {}), f"{path}: trained or measured with test"
        assert card.get("held_out", {"split": "val"})["split"] == "val", f"{path}: held-out numbers from test"


def test_the_tuning_record_lists_what_was_tuned_and_never_test():
    for kind in (*TUNED, "vae"):
        record = tuning_record(kind)
        assert record["split"] == "val" and "test" not in record["settings"]
    assert "GlobalRewardConfig.focus" in tuning_record("global_reward")["settings"]


@pytest.mark.parametrize("domain_name", [d for d in domain_names() if d != "toy"])
def test_shipped_held_out_splits_are_disjoint_from_train_and_each_other(domain_name: str):
    store = Store.from_settings()
    if not all(store.libraries.complete(domain_name, s) for s in SPLITS):
        pytest.skip(f"{domain_name} has no shipped libraries")
    libs = {s: SkillLibrary.load(domain_name, s) for s in SPLITS}
    seeds = {s: set(libs[s].seeds.tolist()) for s in SPLITS}
    for a in SPLITS:
        for b in SPLITS:
            assert a == b or not seeds[a] & seeds[b], f"{domain_name}: {a} and {b} share rollout seeds"
    train = {tuple(r) for r in libs["train"].params}
    for split in HELD_OUT:
        assert not any(tuple(r) in train for r in libs[split].params)
    assert len(libs["test"]) >= 100 and len(libs["val"]) >= 100


def test_building_only_the_held_out_splits_keeps_train_and_serve(tmp_path):
    toy_domain = "toy"
    first = build_all(toy_domain, sizes={"train": 6, "serve": 6, "val": 4, "test": 4}, workers=1, root=tmp_path,
                      progress=False)
    again = build_all(toy_domain, sizes={"val": 4, "test": 4}, workers=1, root=tmp_path, progress=False,
                      splits=("val", "test"))
    assert set(again) == {"val", "test"}
    np.testing.assert_array_equal(SkillLibrary.load(toy_domain, "train", tmp_path).params, first["train"].params)
    np.testing.assert_array_equal(again["test"].params, first["test"].params)
    with pytest.raises(ValueError, match="unknown split\\(s\\) 'holdout'; valid: train, serve, val, test"):
        build_all(toy_domain, workers=1, root=tmp_path, progress=False, splits=("holdout",))
