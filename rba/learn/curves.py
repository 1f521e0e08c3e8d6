"""Training curves: each model's loss and held-out measures against the step, in TensorBoard's format.

Why event files: `tensorboard --logdir <models>/<domain>/curves` shows them as they are written, they travel with
the models they describe (a job's version folder, or the models folder of `rba train`), and the admin page reads
the same files (``read_curves``), so there is one record of a run. Weights & Biases gets the same numbers when
``RBA_WANDB_PROJECT`` is set (its own ``WANDB_MODE`` / ``WANDB_API_KEY`` / ``WANDB_DIR`` apply); it is imported
only then.

Costs are bounded: the loss is already a float every step (``StepLoop``) and is written every ``LOSS_EVERY`` steps;
the held-out measure, forward passes over a fixed part of ``val``, runs at most ``HELD_OUT_POINTS`` times a run and
at the last step, spaced further apart when it would otherwise take more than ``HELD_OUT_BUDGET`` of the time the
steps take (a short run's steps are few and quick, while measuring rθ scores the whole serve library).
"""

from __future__ import annotations

import math
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import nn

from rba.core.settings import LibrarySettings
from rba.learn.common import CurveOf

LOSS_EVERY = 5  # steps between two loss points
HELD_OUT_POINTS = 10  # held-out measurements per run at most (the last step's is one of them)
HELD_OUT_BUDGET = 0.05  # measuring takes at most this share of the steps' time (besides the last step's)
LOSS_TAG = "loss"
HELD_OUT_TAG = "held_out/"  # prefix of every held-out measure's tag
Measure = Callable[[nn.Module], dict[str, float]]  # the model now -> held-out numbers (tag suffix -> value)


def held_out_every(total: int) -> int:
    """Steps between two held-out measurements of a run of ``total`` steps."""
    return max(1, math.ceil(total / HELD_OUT_POINTS))


class CurveWriter:
    """One model's training curve: the loss every ``LOSS_EVERY`` steps and ``measure`` at ``HELD_OUT_POINTS``
    steps, written to ``folder`` (replaced: the curve describes the model saved beside it) and, when configured, to
    a Weights & Biases run named ``run``."""

    def __init__(self, folder: Path, run: str, model: nn.Module, measure: Measure | None = None,
                 config: dict | None = None, budget: float | None = HELD_OUT_BUDGET) -> None:
        from torch.utils.tensorboard import SummaryWriter

        shutil.rmtree(folder, ignore_errors=True)
        self.model, self.measure, self.budget = model, measure, budget
        self.started, self.measuring, self.next_measure = time.perf_counter(), 0.0, 0
        self.measurements = 0
        self.writer = SummaryWriter(log_dir=str(folder), flush_secs=5)
        self.wandb = _wandb_run(run, config or {})

    def record(self, step: int, total: int, loss: float) -> None:
        """Step ``step`` (1-based) of ``total`` ended with ``loss``; write what is due, close after the last."""
        last = step == total
        points: dict[str, float] = {}
        if step % LOSS_EVERY == 0 or last or step == 1:
            points[LOSS_TAG] = loss
        if self.measure is not None and (step >= max(self.next_measure, held_out_every(total)) or last):
            points |= {HELD_OUT_TAG + k: v for k, v in self._measured().items()}
            self.next_measure = step + self._spacing(step, total)
        for tag, value in points.items():
            self.writer.add_scalar(tag, value, step)
        if points:
            self.writer.flush()  # the admin page reads the file while the job runs
            if self.wandb is not None:
                self.wandb.log(points, step=step)
        if last:
            self.close()

    def _spacing(self, step: int, total: int) -> int:
        """Steps to the next measurement: ``total / HELD_OUT_POINTS``, or more while the measurements so far took
        more than ``budget`` of the steps' time."""
        every = held_out_every(total)
        stepping = time.perf_counter() - self.started - self.measuring  # seconds in the steps so far
        if self.budget is None or stepping <= 0:
            return every
        per_step, per_measure = stepping / step, self.measuring / self.measurements
        return max(every, math.ceil(per_measure / (self.budget * per_step)))

    def _measured(self) -> dict[str, float]:
        """``measure`` in eval mode without gradients, the model's mode restored after (training goes on)."""
        was, t0 = self.model.training, time.perf_counter()
        try:
            with torch.no_grad():
                return self.measure(self.model)
        finally:
            self.model.train(was)
            self.measuring += time.perf_counter() - t0
            self.measurements += 1

    def close(self) -> None:
        self.writer.close()
        if self.wandb is not None:
            self.wandb.finish()
            self.wandb = None


def curve_of(folder: Path, run: str, measure: Measure | None = None, config: dict | None = None,
             budget: float | None = HELD_OUT_BUDGET) -> CurveOf:
    """What a trainer takes as ``curve``: the model it builds -> its ``CurveWriter`` (``budget`` None: measure at
    exactly every ``held_out_every`` steps, whatever it costs)."""
    return lambda model: CurveWriter(folder, run, model, measure, config, budget)


def _wandb_run(name: str, config: dict):
    """A Weights & Biases run when ``RBA_WANDB_PROJECT`` is set, else None; wandb is imported only then."""
    project = LibrarySettings().wandb_project
    if not project:
        return None
    import wandb

    return wandb.init(project=project, name=name, config=config, reinit="create_new")


# -- reading -----------------------------------------------------------------------------------------

@dataclass
class Series:
    """One tag of one model's curve: its steps and values in step order (a value may be nan)."""

    tag: str
    steps: list[int] = field(default_factory=list)
    values: list[float] = field(default_factory=list)


@dataclass
class ModelCurve:
    model: str  # "<kind>-<rep>", the model file the curve belongs to
    series: list[Series]


def read_curves(folder: Path) -> list[ModelCurve]:
    """Every model's curve under ``folder`` (``ModelFiles.curves``), in name order; nothing when it does not
    exist. Reads what is written so far, so a running training's curves come out partial."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = []
    for run in _runs(folder):
        acc = EventAccumulator(str(run), size_guidance={"scalars": 0})  # 0: keep every point
        acc.Reload()
        series = [Series(tag, [e.step for e in acc.Scalars(tag)], [e.value for e in acc.Scalars(tag)])
                  for tag in sorted(acc.Tags()["scalars"], key=lambda t: (t != LOSS_TAG, t))]
        out.append(ModelCurve(run.name, series))
    return out


def _runs(folder: Path) -> list[Path]:
    """The run folders; none when ``folder`` is missing or goes while listed (a job's staging folder is renamed
    when it is published, removed when the job fails)."""
    try:
        return sorted(p for p in folder.iterdir() if p.is_dir())
    except FileNotFoundError:
        return []
