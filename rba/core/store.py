"""Where every file lives: skill libraries, models, model versions, uploads and the clip cache.

``Store.from_settings()`` is the one place that turns settings into paths; callers ask it for a
library's, a model's or a clip's file by name and never join paths themselves. The clip cache is
addressed by key only (exists / open / write atomically), so it can move to a shared volume or
an object store without its callers changing.

Layout (all absolute)::

    <data>/<domain>/<split>.{npz,json}           skill libraries
    <data>/uploads/<domain>/<dataset>.{npz,json} uploaded datasets (.<dataset>.lock while one is stored)
    <data>/rba.db                                the app's default SQLite database
    <models>/<domain>/<kind>-<rep>.{pt,json}     shipped models (weights + card)
    <models>/<domain>/curves/<kind>-<rep>/       their training curves (TensorBoard event files)
    <models>/versions/<version>/<domain>/...     models a retraining job published
    <models>/versions/.tmp-<job>/                what a running job writes (renamed when it succeeds)
    <data>/jobs/<job>.json                       which process runs a job (a restart kills an orphan)
    <cache>/<domain>/<version>-<digest>-<w>x<h>.mp4  rendered clips (default <data>/cache/clips)
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, TypeVar

from rba.core.fileio import write_atomic
from rba.core.settings import LibrarySettings

if TYPE_CHECKING:
    from rba.media.clip_cache import ClipKey

T = TypeVar("T")
_SAFE = re.compile(r"^[a-z0-9_]{1,64}$")
_HEX = re.compile(r"^[0-9a-f]{1,64}$")
STAGING_PREFIX = ".tmp-"  # a training job's folder under versions/ until it is published
TEMP_GLOB = "*/.*.tmp"  # what ``write_atomic`` leaves behind when a process dies mid-write
CLAIM_GLOB = "*/.*.claim"  # a guessed render in progress (``ClipStore.claim``)
_UPLOAD_FILE = re.compile(r"^\.?([0-9a-f]{16,64})\.(?:npz|json|lock|(?:npz|json)\.[^/]+\.tmp)$")


@dataclass(frozen=True)
class LibraryFiles:
    """Skill libraries under one root: ``<root>/<domain>/<split>.npz`` (arrays) + ``.json`` (metadata)."""

    root: Path

    def folder(self, domain: str) -> Path:
        return self.root / domain

    def arrays(self, domain: str, split: str) -> Path:
        return self.folder(domain) / f"{split}.npz"

    def meta(self, domain: str, split: str) -> Path:
        return self.folder(domain) / f"{split}.json"

    def complete(self, domain: str, split: str) -> bool:
        """Both files exist (the metadata is written last, so this means a whole library)."""
        return self.arrays(domain, split).exists() and self.meta(domain, split).exists()


@dataclass(frozen=True)
class ModelFiles:
    """Models under one root: ``<root>/<domain>/<kind>-<rep>.pt`` (weights) + ``.json`` (card)."""

    root: Path

    def folder(self, domain: str) -> Path:
        return self.root / domain

    def weights(self, domain: str, kind: str, rep: str) -> Path:
        return self.folder(domain) / f"{kind}-{rep}.pt"

    def card(self, domain: str, kind: str, rep: str) -> Path:
        return self.weights(domain, kind, rep).with_suffix(".json")

    def curves(self, domain: str) -> Path:
        """The training curves of the domain's models (TensorBoard's ``--logdir``): one folder per model."""
        return self.folder(domain) / "curves"

    def curve(self, domain: str, kind: str, rep: str) -> Path:
        """The TensorBoard event files of the training that made ``<kind>-<rep>``."""
        return self.curves(domain) / f"{kind}-{rep}"

    def complete(self, domain: str, kind: str, rep: str) -> bool:
        """Weights and card exist (the card is written last, so this means a whole artifact)."""
        return self.weights(domain, kind, rep).exists() and self.card(domain, kind, rep).exists()


@dataclass(frozen=True)
class UploadFiles:
    """One domain's uploaded datasets: ``<dataset>.npz`` (trajectories, optional) + ``<dataset>.json`` (labels).

    While a dataset is being stored its ``.<dataset>.lock`` exists, and ``write_atomic`` writes each
    file first as ``.<dataset>.<ext>.<random>.tmp``.
    """

    folder: Path

    def trajectories(self, dataset_id: str) -> Path:
        return self.folder / f"{dataset_id}.npz"

    def labels(self, dataset_id: str) -> Path:
        return self.folder / f"{dataset_id}.json"

    def lock(self, dataset_id: str) -> Path:
        return self.folder / f".{dataset_id}.lock"

    def stored(self, dataset_id: str) -> list[Path]:
        """The dataset's files that exist."""
        return [p for p in (self.trajectories(dataset_id), self.labels(dataset_id)) if p.exists()]

    def temporaries(self, dataset_id: str) -> list[Path]:
        """Half-written files of the dataset (a write cut short leaves them)."""
        return sorted(self.folder.glob(f".{dataset_id}.*.tmp"))

    def dataset_ids(self) -> set[str]:
        """Every dataset with a file, a temporary or a lock here (other files are not the store's)."""
        found = (_UPLOAD_FILE.match(p.name) for p in self.folder.iterdir()) if self.folder.is_dir() else ()
        return {m.group(1) for m in found if m}


class ClipStore:
    """Rendered clips (and their data) by key; file names come from validated parts and the key's hash, never from
    user text."""

    def __init__(self, root: Path) -> None:
        self.root = root
        root.mkdir(parents=True, exist_ok=True)

    def path(self, key: ClipKey) -> Path:
        """The clip's local file (served as is); it may not exist yet."""
        domain = key.domain if _SAFE.match(key.domain) else hashlib.sha256(key.domain.encode()).hexdigest()[:16]
        version = key.version if _HEX.match(key.version) else hashlib.sha256(key.version.encode()).hexdigest()[:12]
        return self.root / domain / f"{version}-{key.digest}-{key.width}x{key.height}{key.suffix}"

    def exists(self, key: ClipKey) -> bool:
        return self.path(key).exists()

    def open(self, key: ClipKey) -> BinaryIO:
        return self.path(key).open("rb")

    def write(self, key: ClipKey, fill: Callable[[Path], T]) -> T:
        """``fill(tmp)`` writes the clip to a temporary file that then replaces the key's: readers never see half."""
        result: list[T] = []
        write_atomic(self.path(key), lambda tmp: result.append(fill(Path(tmp))))
        return result[0]

    def claim(self, key: ClipKey, ttl: float) -> bool:
        """Mark the clip as being rendered, for every process sharing this store; False if another holds a
        claim younger than ``ttl`` seconds (an older one was left by a crash and is taken over)."""
        marker = self._claim_path(key)
        marker.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            return True
        except FileExistsError:
            try:
                if time.time() - marker.stat().st_mtime < ttl:
                    return False
                os.utime(marker)  # a stale claim: take it over
                return True
            except FileNotFoundError:  # released meanwhile
                return self.claim(key, ttl)

    def release(self, key: ClipKey) -> None:
        with contextlib.suppress(FileNotFoundError):
            self._claim_path(key).unlink()

    def _claim_path(self, key: ClipKey) -> Path:
        path = self.path(key)
        return path.with_name(f".{path.name}.claim")

    def sweep(self, older_than: float) -> int:
        """Remove temporaries and claims a crash left (older than ``older_than`` seconds); returns how many."""
        cutoff, removed = time.time() - older_than, 0
        for tmp in [*self.root.glob(TEMP_GLOB), *self.root.glob(CLAIM_GLOB)]:
            try:
                if tmp.stat().st_mtime < cutoff:
                    tmp.unlink()
                    removed += 1
            except OSError:
                pass
        return removed


@dataclass(frozen=True)
class Store:
    """The file layout of one installation, built from settings (``RBA_DATA_DIR``, ``RBA_MODELS_DIR``, ...)."""

    data_dir: Path
    models_dir: Path
    cache_dir: Path

    @classmethod
    def from_settings(cls, settings: LibrarySettings | None = None) -> Store:
        """The store of ``settings``; without them, of the environment as it is now."""
        s = settings or LibrarySettings()
        return cls(s.data_dir, s.models_dir, s.cache_dir or s.data_dir / "cache" / "clips")

    @property
    def libraries(self) -> LibraryFiles:
        return LibraryFiles(self.data_dir)

    def models(self, version: str | None = None) -> ModelFiles:
        """The shipped models (``version=None``) or those a job published as ``version``."""
        return ModelFiles(self.models_dir if version is None else self.versions_dir / version)

    @property
    def versions_dir(self) -> Path:
        return self.models_dir / "versions"

    def staging(self, job_id: str) -> Path:
        """Where a running job writes its models; only ``publish`` makes them a version."""
        return self.versions_dir / f"{STAGING_PREFIX}{job_id}"

    def staged_jobs(self) -> list[str]:
        """The jobs that have a staging folder (running ones, or what a crash left)."""
        found = self.versions_dir.glob(f"{STAGING_PREFIX}*") if self.versions_dir.is_dir() else []
        return sorted(p.name.removeprefix(STAGING_PREFIX) for p in found if p.is_dir())

    def published(self) -> list[str]:
        """The version folders (published by a job; whether a row names each is the server's to know)."""
        found = self.versions_dir.iterdir() if self.versions_dir.is_dir() else []
        return sorted(p.name for p in found if p.is_dir() and not p.name.startswith(STAGING_PREFIX))

    def publish(self, job_id: str, version: str) -> None:
        os.replace(self.staging(job_id), self.versions_dir / version)

    def carry_over(self, job_id: str, domain: str, version: str | None) -> list[str]:
        """Into a job's staging folder, the files of ``domain``'s models in ``version`` (None: the shipped ones) that
        the job did not train, hard-linked (copied where links cannot be made): a version is then a whole model
        set, and serving it keeps the other methods' models. The names carried over."""
        source, target = self.models(version).root / domain, self.staging(job_id) / domain
        carried = []
        for path in sorted(source.iterdir()) if source.is_dir() else []:
            if path.is_file() and not (target / path.name).exists():
                target.mkdir(parents=True, exist_ok=True)
                try:
                    os.link(path, target / path.name)
                except OSError:
                    shutil.copy2(path, target / path.name)
                carried.append(path.name)
        return carried

    def unpublish(self, version: str) -> None:
        """Remove a version whose job could not record it (nothing refers to it)."""
        shutil.rmtree(self.versions_dir / version, ignore_errors=True)

    def discard(self, job_id: str) -> None:
        shutil.rmtree(self.staging(job_id), ignore_errors=True)

    def job_record(self, job_id: str) -> Path:
        """Which process runs the job (``server.runtime.processes.ProcessRecord``), while it runs."""
        return self.data_dir / "jobs" / f"{job_id}.json"

    def recorded_jobs(self) -> list[str]:
        """The jobs that have a process record."""
        folder = self.data_dir / "jobs"
        return sorted(p.stem for p in folder.glob("*.json")) if folder.is_dir() else []

    def job_touched(self, job_id: str) -> float | None:
        """When anything the job left (its staging folder's files, its process record) last changed (a Unix time);
        None if it left nothing."""
        staging = self.staging(job_id)
        paths = [self.job_record(job_id), staging, *(staging.rglob("*") if staging.is_dir() else [])]
        times = []
        for path in paths:
            with contextlib.suppress(OSError):
                times.append(path.stat().st_mtime)
        return max(times, default=None)

    def sweep_job_records(self, older_than: float) -> int:
        """Remove half-written process records a crash left (older than ``older_than`` seconds); how many."""
        cutoff, removed = time.time() - older_than, 0
        for tmp in (self.data_dir / "jobs").glob(".*.tmp"):
            with contextlib.suppress(OSError):
                if tmp.stat().st_mtime < cutoff:
                    tmp.unlink()
                    removed += 1
        return removed

    def uploads(self, domain: str) -> UploadFiles:
        return UploadFiles(self.uploads_dir / domain)

    @property
    def uploads_dir(self) -> Path:
        return self.data_dir / "uploads"

    def upload_folders(self) -> list[UploadFiles]:
        """Every domain's upload folder that exists."""
        root = self.uploads_dir
        return [UploadFiles(p) for p in sorted(root.iterdir()) if p.is_dir()] if root.is_dir() else []

    @property
    def database_file(self) -> Path:
        return self.data_dir / "rba.db"

    def clips(self) -> ClipStore:
        """The clip cache (creates its folder)."""
        return ClipStore(self.cache_dir)


def library_files(root: Path | None = None) -> LibraryFiles:
    """Libraries under ``root``, else under the configured data folder (the load functions' ``data_root``)."""
    return LibraryFiles(root) if root is not None else Store.from_settings().libraries


def model_files(root: Path | None = None) -> ModelFiles:
    """Models under ``root``, else the configured shipped ones (the load functions' ``models_root``)."""
    return ModelFiles(root) if root is not None else Store.from_settings().models()
