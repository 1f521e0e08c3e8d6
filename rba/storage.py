"""Safe, atomic file I/O: npz without pickle, JSON, torch state_dicts with weights_only."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np


def _atomic_target(path: Path) -> tuple[int, str]:
    path.parent.mkdir(parents=True, exist_ok=True)
    return tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")


def write_atomic(path: Path, write) -> None:
    """Call ``write(tmp_path)`` then rename over ``path``: readers never see half a file."""
    fd, tmp = _atomic_target(path)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; artifacts are meant to be read by others (e.g. a container)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def save_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) atomically: reports and notes are never half-written."""
    write_atomic(Path(path), lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


def save_report(out: Path, report: dict, markdown: str) -> None:
    """A benchmark's report: ``<out>.json`` (the numbers) and ``<out>.md`` (for people), each atomically."""
    out.parent.mkdir(parents=True, exist_ok=True)
    save_text(out.with_suffix(".json"), json.dumps(report, indent=2) + "\n")
    save_text(out.with_suffix(".md"), markdown)


def save_json(path: Path, obj: Any) -> None:
    def write(tmp: str) -> None:
        with open(tmp, "w") as f:
            json.dump(obj, f, indent=2, sort_keys=True)
            f.write("\n")

    write_atomic(path, write)


def load_json(path: Path) -> Any:
    with open(path) as f:
        return json.load(f)


def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)

    write_atomic(path, write)


def load_npz(path: Path) -> dict[str, np.ndarray]:
    """Load every array of an ``.npz``; object arrays are refused (never unpickle)."""
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def save_torch(path: Path, state_dict: dict) -> None:
    import torch

    write_atomic(path, lambda tmp: torch.save(state_dict, tmp))


def load_torch(path: Path) -> dict:
    import torch

    return torch.load(path, map_location="cpu", weights_only=True)
