"""Model artifacts: a state_dict (``.pt``) + a card (``.json``), where ``rba.core.store.ModelFiles`` says.

The card says how to rebuild the module (architecture), what it was trained on (data
hashes), and how well it did on held-out data. Weights load with ``weights_only=True``.
"""

from __future__ import annotations

import datetime as dt
import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn

from rba.core.fileio import load_json, load_torch, save_json, save_torch
from rba.core.store import model_files
from rba.learn.global_reward import GlobalReward
from rba.learn.local_reward import LocalReward
from rba.learn.ranker import AttributeRanker
from rba.learn.vae import FrameVAE


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


def save_model(model: nn.Module, card: dict, root: Path | None = None) -> Path:
    """Write weights then card (the card's presence marks a complete artifact)."""
    card = dict(card, created=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"))
    files, key = model_files(root), (card["domain"], card["kind"], card["representation"])
    save_torch(files.weights(*key), model.state_dict())
    save_json(files.card(*key), card)
    return files.weights(*key)


def load_model(domain: str, kind: str, rep: str, root: Path | None = None) -> Artifact:
    files = model_files(root)
    path = files.weights(domain, kind, rep)
    if not files.complete(domain, kind, rep):
        raise ModelNotFoundError(f"no {kind} model ({rep}) for {domain!r} at {path}; run `rba train {domain}`")
    card = load_json(files.card(domain, kind, rep))
    model = BUILDERS[card["kind"]](card)
    model.load_state_dict(load_torch(path))
    return Artifact(model.eval(), card)


def weights_sha(model: nn.Module) -> str:
    """The first 12 hex digits of the sha256 of a model's tensors: the version a card and a session name."""
    h = hashlib.sha256()
    for name, t in sorted(model.state_dict().items()):
        h.update(name.encode() + t.detach().contiguous().numpy().tobytes())
    return h.hexdigest()[:12]
