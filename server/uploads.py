"""Checking uploaded datasets before anything is stored: every problem found, in words.

An upload is an ``.npz`` of trajectories (one float array T x state_dim per trajectory) and a
JSON label set (``rba.labels``). The ``.npz`` is opened as a zip and every array's header is
read before any array is: object arrays, wrong shapes and zip bombs are refused without
allocating what they claim. Arrays are then loaded with ``allow_pickle=False``.
"""

from __future__ import annotations

import json
import math
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rba.labels import LabelSet

TRAJECTORY_NAME = re.compile(r"^[A-Za-z0-9_.:-]{1,128}$")


@dataclass(frozen=True)
class UploadLimits:
    max_bytes: int  # the whole request
    max_uncompressed: int  # what the .npz may expand to
    min_steps: int = 2  # states per trajectory
    max_steps: int = 10_000
    max_trajectories: int = 20_000


def _header(f, version: tuple[int, int]):
    if version == (1, 0):
        return np.lib.format.read_array_header_1_0(f)
    if version == (2, 0):
        return np.lib.format.read_array_header_2_0(f)
    raise ValueError(f"unsupported .npy format version {version}")


def _member_problem(zf: zipfile.ZipFile, info: zipfile.ZipInfo, state_dim: int, limits: UploadLimits) -> str | None:
    """Why one member of the .npz is not a usable trajectory, judged from its .npy header only; None if it is."""
    name = info.filename.removesuffix(".npy")
    if not info.filename.endswith(".npy") or not TRAJECTORY_NAME.match(name):
        return (f"trajectories: member {info.filename[:80]!r} is not a .npy array named with "
                "1-128 letters, digits or _ . : -")
    with zf.open(info) as f:
        try:
            shape, _fortran, dtype = _header(f, np.lib.format.read_magic(f))
        except ValueError as e:
            return f"trajectory {name!r}: unreadable .npy header ({e})"
    if dtype.hasobject:
        return f"trajectory {name!r}: object arrays are refused (they need pickle)"
    if dtype.kind != "f":
        return f"trajectory {name!r}: dtype {dtype} is not a float type (float32 or float64)"
    if len(shape) != 2 or shape[1] != state_dim:
        return f"trajectory {name!r}: shape {list(shape)}, expected [T, {state_dim}] (state_dim of the domain)"
    if not limits.min_steps <= shape[0] <= limits.max_steps:
        return f"trajectory {name!r}: {shape[0]} states; T must be in [{limits.min_steps}, {limits.max_steps}]"
    if math.prod(shape) * dtype.itemsize > info.file_size:
        return f"trajectory {name!r}: the array claims more data than the file holds"
    return None


def _check_members(path: Path, state_dim: int, limits: UploadLimits) -> tuple[list[str], list[str]]:
    """The names of the zip's usable trajectories and the problems found, before any array is read."""
    problems: list[str] = []
    names: list[str] = []
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
            if not infos:
                return [], ["trajectories: the .npz holds no arrays"]
            if len(infos) > limits.max_trajectories:
                return [], [f"trajectories: {len(infos)} arrays, more than the limit of {limits.max_trajectories}"]
            expanded = sum(i.file_size for i in infos)
            if expanded > limits.max_uncompressed:
                return [], [f"trajectories: the .npz expands to {expanded} bytes, over the limit of "
                            f"{limits.max_uncompressed} (zip bomb?)"]
            for info in infos:
                problem = _member_problem(zf, info, state_dim, limits)
                if problem is None:
                    names.append(info.filename.removesuffix(".npy"))
                else:
                    problems.append(problem)
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        return [], [f"trajectories: corrupt .npz ({e})"]
    return names, problems


def check_npz(path: Path, state_dim: int, limits: UploadLimits) -> tuple[dict[str, np.ndarray], list[str]]:
    """The trajectories of the .npz at ``path`` by name, or the problems that stop them being used."""
    if not zipfile.is_zipfile(path):
        return {}, ["trajectories: not an .npz file (a zip of .npy arrays, as numpy.savez writes); "
                    "pickles and other formats are refused"]
    names, problems = _check_members(path, state_dim, limits)
    if problems:
        return {}, problems
    out: dict[str, np.ndarray] = {}
    try:
        with np.load(path, allow_pickle=False) as npz:
            for name in names:
                arr = np.asarray(npz[name], dtype=np.float32)
                if not np.isfinite(arr).all():
                    problems.append(f"trajectory {name!r}: holds NaN or infinite values")
                out[name] = arr
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as e:
        return {}, [f"trajectories: could not be read ({e})"]
    return ({} if problems else out), problems


def check_labels(raw: bytes, limit: int) -> tuple[LabelSet | None, bytes, list[str]]:
    """The label set and its canonical JSON bytes (what is stored and hashed), or the problems."""
    if not raw.strip():
        return None, b"", ["labels: the file is empty; expected a JSON object (see GET /docs)"]
    if len(raw) > limit:
        return None, b"", [f"labels: {len(raw)} bytes, over the limit of {limit}"]
    try:
        obj = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        return None, b"", [f"labels: not UTF-8 JSON ({e})"]
    labels, problems = LabelSet.parse(obj)
    if labels is None:
        return None, b"", problems
    canonical = json.dumps(labels.model_dump(mode="json"), sort_keys=True, separators=(",", ":")).encode()
    return labels, canonical, []
