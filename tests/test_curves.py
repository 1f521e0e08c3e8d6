"""Training curves: the event files' tags and values, that writing them changes no weight, and Weights & Biases
offline."""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import pytest
import torch
from torch import nn

from rba.core.artifacts import weights_sha
from rba.core.store import model_files
from rba.data.labels import proxy_labels
from rba.data.library import SkillLibrary
from rba.learn.common import Ragged, StepLoop
from rba.learn.curves import HELD_OUT_POINTS, LOSS_EVERY, CurveWriter, curve_of, read_curves
from rba.learn.ranker import RankerConfig, train_ranker


def _fit(steps: int, curve=None) -> list[float]:
    """A line fitted for ``steps`` steps; every step's loss."""
    torch.manual_seed(0)
    model = nn.Linear(1, 1)
    x = torch.linspace(-1, 1, 32)[:, None]
    losses = []
    loop = StepLoop(torch.optim.SGD(model.parameters(), lr=0.1), steps, curve=curve(model) if curve else None)
    for step in range(steps):
        loop.step(step, ((model(x) - 3 * x) ** 2).mean())
        losses.append(loop.loss)
    return losses


def test_the_event_files_hold_the_loss_and_the_held_out_measure_at_their_steps(tmp_path):
    measured = []

    def measure(model: nn.Module) -> dict[str, float]:
        assert not torch.is_grad_enabled()
        measured.append(model.weight.item())
        return {"slope_error": abs(model.weight.item() - 3)}

    losses = _fit(23, curve_of(tmp_path / "curves" / "line", "line", measure, budget=None))
    [curve] = read_curves(tmp_path / "curves")
    assert curve.model == "line"
    loss, held = curve.series
    assert (loss.tag, held.tag) == ("loss", "held_out/slope_error")
    assert loss.steps == [1, *range(LOSS_EVERY, 23, LOSS_EVERY), 23]
    assert loss.values == pytest.approx([losses[s - 1] for s in loss.steps], rel=1e-6)
    assert held.steps == [3, 6, 9, 12, 15, 18, 21, 23] and len(measured) == len(held.steps) <= HELD_OUT_POINTS
    assert held.values[-1] < held.values[0]  # the line learns its slope
    assert read_curves(tmp_path / "nothing") == []


def test_a_new_curve_replaces_the_old_one_of_its_model(tmp_path):
    _fit(30, curve_of(tmp_path / "line", "line"))
    _fit(10, curve_of(tmp_path / "line", "line"))
    [curve] = read_curves(tmp_path)
    assert curve.series[0].steps[-1] == 10


def test_curves_can_be_read_while_written(tmp_path):
    writer = CurveWriter(tmp_path / "run", "run", nn.Linear(1, 1), lambda m: {"x": 0.5}, budget=None)
    for step in range(1, 21):
        writer.record(step, 100, 1.0 / step)
    [curve] = read_curves(tmp_path)
    assert curve.series[0].steps == [1, 5, 10, 15, 20] and curve.series[1].steps == [10, 20]
    writer.close()


def test_a_costly_measure_is_spaced_out_within_its_budget(tmp_path):
    """Steps of ~1 ms and a measure of ~50 ms: at 5 % of the steps' time, one measure per ~1,000 steps, and the last;
    at every planned point (100 steps) measuring would take about a third of the time."""
    def slow(model: nn.Module) -> dict[str, float]:
        time.sleep(0.05)
        return {"x": 1.0}

    writer = CurveWriter(tmp_path / "run", "run", nn.Linear(1, 1), slow)
    for step in range(1, 1001):
        time.sleep(0.001)
        writer.record(step, 1000, 1.0)
    held = read_curves(tmp_path)[0].series[1]
    assert held.steps[0] == 100 and held.steps[-1] == 1000  # the first as planned, the last always
    assert len(held.steps) <= 6, held.steps  # steps 5 times slower than asked for would still space them 200 apart


def test_writing_the_curve_changes_no_weight(toy_roots, tmp_path):
    data, _, _ = toy_roots
    train = SkillLibrary.load("toy", "train", data)
    ragged = Ragged.from_numpy(train.states, train.state_offsets)
    labels = proxy_labels(train, 60, 0)
    embed = np.eye(len(labels), dtype=np.float32)
    cfg = RankerConfig(steps=30, hidden=32)
    plain, _ = train_ranker(ragged, labels, embed, cfg)
    logged, _ = train_ranker(ragged, labels, embed, cfg, curve=curve_of(
        tmp_path / "ranker", "ranker", lambda m: {"mean_zeta": float(m.score(ragged).mean())}))
    assert weights_sha(plain) == weights_sha(logged)
    assert [s.tag for s in read_curves(tmp_path)[0].series] == ["loss", "held_out/mean_zeta"]


def test_rba_train_writes_each_models_curve_beside_it(toy_roots):
    """The session's toy models were trained by ``train_global``: their curves are in the models folder."""
    _, models, _ = toy_roots
    curves = {c.model: c for c in read_curves(model_files(models).curves("toy"))}
    assert sorted(curves) == ["global_reward-onehot", "ranker-onehot"]
    ranker = {s.tag: s for s in curves["ranker-onehot"].series}
    assert sorted(ranker) == ["held_out/pairwise_accuracy/amplitude", "held_out/pairwise_accuracy/pace", "loss"]
    held = ranker["held_out/pairwise_accuracy/pace"].steps
    assert ranker["loss"].steps[-1] == 200 and 2 <= len(held) <= HELD_OUT_POINTS and held[-1] == 200
    card = json.loads(model_files(models).card("toy", "ranker", "onehot").read_text())
    for name in ("amplitude", "pace"):  # the last point is the card's number: one code measures both
        assert ranker[f"held_out/pairwise_accuracy/{name}"].values[-1] == pytest.approx(
            card["held_out"][name]["pairwise_accuracy"], abs=1e-6)
    reward = {s.tag: s for s in curves["global_reward-onehot"].series}
    assert sorted(reward) == ["held_out/argmax_within_epsilon", "loss"]
    assert all(0 <= v <= 1 for v in reward["held_out/argmax_within_epsilon"].values)
    assert reward["loss"].values[-1] < reward["loss"].values[0]


def _wandb_history(run_file) -> dict[str, dict[int, float]]:
    """What an offline run's ``.wandb`` file holds: tag -> {step: value} (read with wandb's own record reader; a key
    with a slash may come as its parts)."""
    from wandb.proto import wandb_internal_pb2
    from wandb.sdk.internal import datastore

    store, out = datastore.DataStore(), {}
    store.open_for_scan(str(run_file))
    while (data := store.scan_data()) is not None:
        record = wandb_internal_pb2.Record()
        record.ParseFromString(data)
        if record.WhichOneof("record_type") == "history":
            items = {i.key or "/".join(i.nested_key): json.loads(i.value_json) for i in record.history.item}
            for key, value in items.items():
                if not key.startswith("_"):  # wandb's own keys: _step, _runtime, _timestamp
                    out.setdefault(key, {})[items["_step"]] = value
    return out


def test_weights_and_biases_gets_the_same_numbers_offline(tmp_path, monkeypatch):
    pytest.importorskip("wandb")
    monkeypatch.setenv("RBA_WANDB_PROJECT", "rba-test")
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_DIR", str(tmp_path))
    monkeypatch.setenv("WANDB_SILENT", "true")
    _fit(12, curve_of(tmp_path / "tb" / "line", "toy/line", lambda m: {"w": m.weight.item()}))
    [run_file] = (tmp_path / "wandb").glob("offline-run-*/run-*.wandb")
    logged = _wandb_history(run_file)
    [curve] = read_curves(tmp_path / "tb")
    assert sorted(logged) == sorted(s.tag for s in curve.series) == ["held_out/w", "loss"]
    for s in curve.series:
        assert list(logged[s.tag]) == s.steps
        assert list(logged[s.tag].values()) == pytest.approx(s.values, rel=1e-6)


def test_without_a_project_wandb_is_not_imported(tmp_path, monkeypatch):
    monkeypatch.delenv("RBA_WANDB_PROJECT", raising=False)
    monkeypatch.setitem(sys.modules, "wandb", None)  # importing it would raise
    _fit(5, curve_of(tmp_path / "line", "line"))
    assert read_curves(tmp_path)[0].series[0].steps == [1, 5]
