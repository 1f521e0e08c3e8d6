"""Checking uploaded datasets before anything is stored (every problem found, in words), and the
locks that let start-up tell what a dead upload left from what a live one is writing.

An upload is an ``.npz`` of trajectories (one float array T x state_dim per trajectory) and a
JSON label set (``rba.data.labels``). The ``.npz`` is opened as a zip and every array's header is
read before any array is: object arrays, wrong shapes and zip bombs are refused without
allocating what they claim. Arrays are then read member by member with ``allow_pickle=False``.
Trajectory names are data: any printable text, never a path or a keyword argument.

An upload is checked in a workspace folder (``/tmp/rba-upload-*``) and stored under its
dataset's lock file; each holds an ``flock`` while its request runs. The kernel drops the lock
when the process dies, so a free lock marks a dead upload's leftovers, whichever process or
replica left them; leftovers no lock vouches for are only removed once they are old.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import math
import os
import shutil
import tempfile
import time
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic_core import from_json

from rba.core.fileio import load_npz
from rba.data.labels import LabelSet

log = logging.getLogger(__name__)
NAME_RULE = "1-128 printable characters (any language), no / or \\, no leading or trailing space"
WORKSPACE_PREFIX = "rba-upload-"
OWNER_LOCK = "owner.lock"
LEFTOVER_GRACE_SECONDS = 3600.0  # a leftover no lock vouches for may be another replica's upload under way
JSON_TYPES = {dict: "an object", list: "an array", str: "a string", int: "a number", float: "a number",
              bool: "true or false", type(None): "null"}


@dataclass(frozen=True)
class UploadLimits:
    max_bytes: int  # the whole request
    max_uncompressed: int  # what the .npz may expand to
    min_steps: int = 2  # states per trajectory
    max_steps: int = 10_000
    max_trajectories: int = 20_000


def name_problem(name: str) -> str | None:
    """Why ``name`` cannot name a trajectory, or None: names are shown and matched, never used as paths."""
    if not 0 < len(name) <= 128 or not name.isprintable() or "/" in name or "\\" in name or name != name.strip():
        return f"trajectory names are {NAME_RULE}"
    return None


def _header(f, version: tuple[int, int]):
    if version == (1, 0):
        return np.lib.format.read_array_header_1_0(f)
    if version == (2, 0):
        return np.lib.format.read_array_header_2_0(f)
    raise ValueError(f"unsupported .npy format version {version}")


def _member_problem(zf: zipfile.ZipFile, info: zipfile.ZipInfo, state_dim: int, limits: UploadLimits) -> str | None:
    """Why one member of the .npz is not a usable trajectory, judged from its .npy header only; None if it is."""
    name = info.filename.removesuffix(".npy")
    if not info.filename.endswith(".npy") or name_problem(name):
        return f"trajectories: member {info.filename[:80]!r} is not a .npy array named with {NAME_RULE}"
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


def _zip_problems(infos: list[zipfile.ZipInfo], limits: UploadLimits) -> list[str]:
    """What is wrong with the zip as a whole: empty, too many members, too large expanded, a name twice."""
    if not infos:
        return ["trajectories: the .npz holds no arrays"]
    if len(infos) > limits.max_trajectories:
        return [f"trajectories: {len(infos)} arrays, more than the limit of {limits.max_trajectories}"]
    expanded = sum(i.file_size for i in infos)
    if expanded > limits.max_uncompressed:
        return [f"trajectories: the .npz expands to {expanded} bytes, over the limit of "
                f"{limits.max_uncompressed} (zip bomb?)"]
    seen: set[str] = set()
    twice = sorted({i.filename for i in infos if i.filename in seen or seen.add(i.filename)})
    return [f"trajectories: member {n[:80]!r} appears more than once; each trajectory has one name" for n in twice]


def _check_members(path: Path, state_dim: int, limits: UploadLimits) -> list[str]:
    """The problems of the zip's members, found before any array is read."""
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
            problems = _zip_problems(infos, limits)
            if problems:
                return problems
            return [p for p in (_member_problem(zf, info, state_dim, limits) for info in infos) if p]
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        return [f"trajectories: corrupt .npz ({e})"]


def check_npz(path: Path, state_dim: int, limits: UploadLimits) -> tuple[dict[str, np.ndarray], list[str]]:
    """The trajectories of the .npz at ``path`` by name, or the problems that stop them being used."""
    if not zipfile.is_zipfile(path):
        return {}, ["trajectories: not an .npz file (a zip of .npy arrays, as numpy.savez writes); "
                    "pickles and other formats are refused"]
    problems = _check_members(path, state_dim, limits)
    if problems:
        return {}, problems
    try:
        arrays = load_npz(path)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as e:
        return {}, [f"trajectories: could not be read ({e})"]
    out = {name: np.asarray(a, dtype=np.float32) for name, a in arrays.items()}
    problems = [f"trajectory {name!r}: holds NaN or infinite values" for name, a in out.items()
                if not np.isfinite(a).all()]
    return ({} if problems else out), problems


def _parse_json(raw: bytes) -> tuple[object, list[str]]:
    """The JSON value of ``raw`` (UTF-8, a byte-order mark allowed), or why it is none.

    pydantic's parser stops at a fixed nesting depth with an error, where ``json.loads`` would
    recurse until Python's stack gives out (a RecursionError, a 500).
    """
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        return None, [f"labels: not UTF-8 JSON (byte {raw[e.start]:#04x} at offset {e.start} is not UTF-8)"]
    try:
        return from_json(text), []
    except ValueError as e:
        if "recursion limit" in str(e):
            return None, ["labels: nested too deeply (too many levels of [ ] or { }); a label set is an object "
                          "of lists of objects, at most 4 levels deep (see GET /docs)"]
        return None, [f"labels: not UTF-8 JSON ({e})"]


def check_labels(raw: bytes, limit: int) -> tuple[LabelSet | None, bytes, list[str]]:
    """The label set and its canonical JSON bytes (what is stored and hashed) and no problems; or the problems, with
    what of the set parsed (``LabelSet.salvage``, to be checked against the domain too) and no bytes."""
    if not raw.strip():
        return None, b"", ["labels: the file is empty; expected a JSON object (see GET /docs)"]
    if len(raw) > limit:
        return None, b"", [f"labels: {len(raw)} bytes, over the limit of {limit}"]
    obj, problems = _parse_json(raw)
    if problems:
        return None, b"", problems
    if not isinstance(obj, dict):
        return None, b"", [f"labels: the file holds {JSON_TYPES.get(type(obj), 'a value')}; expected an object "
                           "with new_attributes, orderings, comparisons and/or local_changes (see GET /docs)"]
    labels, problems = LabelSet.parse(obj)
    if problems:
        return labels, b"", problems
    canonical = json.dumps(labels.model_dump(mode="json"), sort_keys=True, separators=(",", ":")).encode()
    return labels, canonical, []


# -- locks held while an upload runs ---------------------------------------------------------------

def _locked(path: Path, create: bool) -> int | None:
    """A descriptor holding an exclusive ``flock`` on ``path``; None if a live process holds it.

    With ``create`` it waits for the lock and makes the file if missing; without, it never waits
    and raises FileNotFoundError when there is no such file (any more).
    """
    while True:
        fd = os.open(path, os.O_RDWR | (os.O_CREAT if create else 0), 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if create else fcntl.LOCK_NB))
        except BlockingIOError:
            os.close(fd)
            return None
        try:
            if os.stat(path).st_ino == os.fstat(fd).st_ino:
                return fd
        except FileNotFoundError:
            if not create:
                os.close(fd)
                raise
        os.close(fd)  # its holder removed the file as it let go: lock the file there now


@contextlib.contextmanager
def claimed(lock: Path) -> Iterator[None]:
    """Hold ``lock`` while a dataset is stored (waiting while another request stores the same one).

    The file is removed only when the block ends normally: after a crash or an error it stays,
    free, and the start-up sweep decides from the database what of the dataset to keep.
    """
    lock.parent.mkdir(parents=True, exist_ok=True)
    fd = _locked(lock, create=True)
    try:
        yield
        lock.unlink()
    finally:
        os.close(fd)


@contextlib.contextmanager
def abandoned(lock: Path) -> Iterator[bool | None]:
    """True (and the lock held) if ``lock`` was left by a dead process, False if a live one holds it,
    None if there is no such lock."""
    try:
        fd = _locked(lock, create=False)
    except FileNotFoundError:
        yield None
        return
    if fd is None:
        yield False
        return
    try:
        yield True
        lock.unlink(missing_ok=True)
    finally:
        os.close(fd)


def older_than(path: Path, seconds: float) -> bool:
    try:
        return path.stat().st_mtime < time.time() - seconds
    except FileNotFoundError:
        return False


@contextlib.contextmanager
def workspace() -> Iterator[Path]:
    """A private folder to check one upload in, locked by this process and removed when done."""
    folder = Path(tempfile.mkdtemp(prefix=WORKSPACE_PREFIX))
    fd = _locked(folder / OWNER_LOCK, create=True)
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)
        os.close(fd)


def sweep_workspaces(grace: float = LEFTOVER_GRACE_SECONDS) -> int:
    """Remove the workspaces of dead uploads (their lock is free) and unlocked ones older than ``grace``
    seconds; returns how many went. Live uploads of other processes keep theirs."""
    removed = 0
    for folder in Path(tempfile.gettempdir()).glob(f"{WORKSPACE_PREFIX}*"):
        try:
            with abandoned(folder / OWNER_LOCK) as dead:
                if dead or (dead is None and older_than(folder, grace)):
                    shutil.rmtree(folder)
                    removed += 1
        except OSError as e:  # another user's folder, or not ours at all: not for us to judge
            log.warning("upload workspace %s left alone: %s", folder, e)
    return removed
