"""Model artifacts: ``<models_dir>/<domain>/<kind>-<rep>.pt`` (state_dict) + ``.json`` (card).

The card says how to rebuild the module (architecture), what it was trained on (data
hashes), and how well it did on held-out data. Weights load with ``weights_only=True``.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn

from rba.learn.global_reward import GlobalReward
from rba.learn.local_reward import LocalReward
from rba.learn.ranker import AttributeRanker
from rba.learn.vae import FrameVAE
from rba.paths import models_dir
from rba.storage import load_json, load_torch, save_json, save_torch


class ModelNotFoundError(FileNotFoundError):
    pass


def _build_ranker(card: dict) -> nn.Module:
    arch = card["architecture"]
    return AttributeRanker(arch["state_dim"], torch.zeros(arch["num_attributes"], arch["embed_dim"]),
                           arch["hidden"], arch["layers"], arch["clip"])


def _build_global_reward(card: dict) -> nn.Module:
    arch = card["architecture"]
    return GlobalReward(arch["state_dim"], arch["num_attributes"], arch["hidden"], arch["layers"])


def _build_local_reward(card: dict) -> nn.Module:
    arch = card["architecture"]
    return LocalReward(arch["state_dim"], torch.zeros(arch["num_attributes"], arch["embed_dim"]), arch["hidden"],
                       arch["layers"], arch["lstm_hidden"], arch["lstm_layers"], arch["anchor_stride"])


def _build_vae(card: dict) -> nn.Module:
    return FrameVAE(card["architecture"]["latent"])


BUILDERS: dict[str, Callable[[dict], nn.Module]] = {
    "vae": _build_vae,
    "ranker": _build_ranker,
    "global_reward": _build_global_reward,
    "local_reward": _build_local_reward,
}


@dataclass
class Artifact:
    model: nn.Module
    card: dict


def model_path(domain: str, kind: str, rep: str, root: Path | None = None) -> Path:
    return (root or models_dir()) / domain / f"{kind}-{rep}.pt"


def save_model(model: nn.Module, card: dict, root: Path | None = None) -> Path:
    """Write weights then card (the card's presence marks a complete artifact)."""
    card = dict(card, created=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"))
    path = model_path(card["domain"], card["kind"], card["representation"], root)
    save_torch(path, model.state_dict())
    save_json(path.with_suffix(".json"), card)
    return path


def load_model(domain: str, kind: str, rep: str, root: Path | None = None) -> Artifact:
    path = model_path(domain, kind, rep, root)
    card_path = path.with_suffix(".json")
    if not path.exists() or not card_path.exists():
        raise ModelNotFoundError(f"no {kind} model ({rep}) for {domain!r} at {path}; run `rba train {domain}`")
    card = load_json(card_path)
    model = BUILDERS[card["kind"]](card)
    model.load_state_dict(load_torch(path))
    return Artifact(model.eval(), card)
