"""Shared fixtures: the toy domain registered, and a tiny trained toy pipeline on disk."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from rba.domains import register

os.environ.setdefault("MUJOCO_GL", "egl")
register("toy", "tests.toy:Toy")


@pytest.fixture(scope="session")
def local_compute():
    """One local compute backend for the whole run (its worker processes start once, on first use)."""
    from rba.compute.local import LocalCompute

    with LocalCompute(workers=2, nice=0, background_nice=5) as compute:
        yield compute


@pytest.fixture(scope="session")
def toy_roots(tmp_path_factory):
    """(data_root, models_root) with toy libraries and one-hot global models trained on them."""
    from rba.data.library import build_all
    from rba.learn.global_reward import GlobalRewardConfig
    from rba.learn.ranker import RankerConfig
    from rba.learn.training import GlobalTrainConfig, train_global

    root = tmp_path_factory.mktemp("toy")
    data, models = root / "data", root / "models"
    build_all("toy", seed=0, sizes={"train": 120, "serve": 300, "val": 40, "test": 40}, workers=1, root=data,
              progress=False)
    cfg = GlobalTrainConfig(RankerConfig(steps=200, hidden=64), GlobalRewardConfig(steps=400, hidden=64))
    metrics = train_global("toy", "onehot", cfg, data_root=data, models_root=models)
    return data, models, metrics


@pytest.fixture
def toy_env(toy_roots, monkeypatch):
    """The toy data and models as the settings' defaults (``RBA_DATA_DIR``, ``RBA_MODELS_DIR``): for code that loads
    by domain name alone, as the benchmarks and the CLI do; ``toy_roots``."""
    monkeypatch.setenv("RBA_DATA_DIR", str(toy_roots[0]))
    monkeypatch.setenv("RBA_MODELS_DIR", str(toy_roots[1]))
    return toy_roots


def own_copy(toy_roots, root: Path) -> tuple[Path, Path]:
    """Copies of the toy ``data`` and ``models`` folders under ``root`` (jobs, uploads and sweeps write there);
    their paths."""
    data, models = root / "data", root / "models"
    shutil.copytree(toy_roots[0], data)
    shutil.copytree(toy_roots[1], models)
    return data, models


def _in_gap(proxies):
    """The toy clips whose amplitude and pace both lie in the middle of their ranges."""
    return (proxies[:, 0] > 0.3) & (proxies[:, 0] < 1.1) & (proxies[:, 1] > 1.9) & (proxies[:, 1] < 2.9)


@pytest.fixture(scope="session")
def gap_roots(toy_roots, tmp_path_factory):
    """The toy data with a serve library that lacks every clip of a gap (targets there need generation); the
    toy models."""
    return serve_subset_roots(toy_roots, tmp_path_factory.mktemp("gap"), lambda proxies: ~_in_gap(proxies))


def serve_subset_roots(toy_roots, root: Path, keep) -> tuple[Path, Path]:
    """Copies of the toy data and models under ``root`` whose serve library holds only the clips whose proxies
    ``keep(proxies) -> bool[N]`` selects."""
    import numpy as np

    from rba.data.library import SkillLibrary

    data, models = own_copy(toy_roots, root)
    serve = SkillLibrary.load("toy", "serve", data)
    lib = serve.subset(np.flatnonzero(keep(serve.proxies)))
    lib.split = "serve"
    lib.save(data)
    return data, models
