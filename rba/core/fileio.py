"""Safe, atomic file I/O: npz without pickle, JSON, torch state_dicts with weights_only."""

from __future__ import annotations

import json
import os
import platform
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np


def _atomic_target(path: Path) -> tuple[int, str]:
    path.parent.mkdir(parents=True, exist_ok=True)
    return tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")


def write_atomic(path: Path, write) -> None:
    """Call ``write(tmp_path)`` then rename over ``path``: readers never see half a file. The bytes and the
    rename reach the disk before this returns, so a row committed afterwards never names a file a power
    cut took away."""
    fd, tmp = _atomic_target(path)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; artifacts are meant to be read by others (e.g. a container)
        _fsync(tmp)
        os.replace(tmp, path)
        _fsync(path.parent)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _fsync(path: Path | str) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def save_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) atomically: reports and notes are never half-written."""
    write_atomic(Path(path), lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


# in a benchmark's Markdown report: what follows was written by hand (when, at which commit and why a row was measured
# again) and is kept when the script writes the report again
NOTES = "<!-- notes written by hand: kept when the report is written again -->"


def save_markdown(path: Path, text: str) -> None:
    """Write a generated report ``text`` atomically, followed by the hand-written notes of the one at ``path`` (from
    ``NOTES`` on), if it has any: regenerating a report must not lose the history of its rows."""
    path = Path(path)
    old = path.read_text(encoding="utf-8") if path.exists() else ""
    at = old.find(NOTES)
    if at >= 0 and NOTES not in text:
        text = text.rstrip("\n") + "\n\n" + old[at:]
    save_text(path, text)


def report_path(out: Path, suffix: str) -> Path:
    """``<out><suffix>``: a benchmark's ``--out`` names its reports without their suffix, and a dot in that name
    (``--out runs/pull0.001``) is part of it (``with_suffix`` would replace ``.001``: two runs, one file); an ``out``
    that already ends in ``.json`` or ``.md`` has that suffix replaced."""
    return out.with_suffix(suffix) if out.suffix in (".json", ".md") else out.with_name(out.name + suffix)


def machine() -> str:
    """The machine a benchmark ran on, for its report."""
    return f"{os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}"


def report_to_extend(out: Path, setting: dict[str, Any], command: str) -> dict:
    """A benchmark's report that keeps the rows of ``out``'s earlier one if that was measured in the same ``setting``
    (runs of one domain at a time can run side by side and be combined); otherwise it starts empty."""
    path = report_path(out, ".json")
    old = json.loads(path.read_text()) if path.exists() else {}
    kept = old.get("rows", []) if all(old.get(k) == v for k, v in setting.items()) else []
    return {**setting, "command": command, "machine": machine(), "rows": kept}


def save_report(out: Path, report: dict, markdown: str) -> None:
    """A benchmark's report: ``<out>.json`` (the numbers) and ``<out>.md`` (for people), each atomically."""
    out.parent.mkdir(parents=True, exist_ok=True)
    save_text(report_path(out, ".json"), json.dumps(report, indent=2) + "\n")
    save_markdown(report_path(out, ".md"), markdown)


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
    """Write ``arrays`` as a compressed ``.npz``, one ``<name>.npy`` member per array, atomically.

    The zip is written here rather than by ``np.savez_compressed(f, **arrays)``: names are data,
    and passed as keyword arguments a name such as ``file`` or ``allow_pickle`` would be taken for
    that function's own parameter. ``np.load`` reads the result as it reads ``np.savez``'s.
    """
    def write(tmp: str) -> None:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
            for name, value in arrays.items():
                with zf.open(f"{name}.npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)

    write_atomic(path, write)


def load_npz(path: Path) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` by name; object arrays are refused (never unpickle).

    Members are read by their exact names: ``np.load``'s lookup also accepts a name without its
    ``.npy`` suffix, so there trajectories called ``x`` and ``x.npy`` would be one and the same.
    """
    out: dict[str, np.ndarray] = {}
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            name = info.filename.removesuffix(".npy")
            if name == info.filename or name in out:
                raise ValueError(f"{path.name}: member {info.filename!r} is not one uniquely named .npy array")
            with zf.open(info) as member:
                out[name] = np.lib.format.read_array(member, allow_pickle=False)
    return out


def save_torch(path: Path, state_dict: dict) -> None:
    import torch

    write_atomic(path, lambda tmp: torch.save(state_dict, tmp))


def load_torch(path: Path) -> dict:
    import torch

    return torch.load(path, map_location="cpu", weights_only=True)
