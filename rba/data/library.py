"""SkillLibrary: many rollouts of a domain's skill, stored as ragged arrays (npz + JSON).

On disk (where ``rba.core.store.LibraryFiles`` says): ``<split>.npz`` holds only numeric arrays
(states and replay concatenated over rollouts with offsets), ``<split>.json`` the metadata.
Loading never unpickles.
"""

from __future__ import annotations

import hashlib
import logging
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rba.compute import Compute, SimJob
from rba.core.fileio import load_json, load_npz, save_json, save_npz
from rba.core.store import library_files
from rba.domains import Rollout, domain_target, get_domain, load_domain

log = logging.getLogger(__name__)

SPLITS = ("train", "serve", "val", "test")
# Each split's code seeds its parameter stream and its rollout seeds. Code 2 was the first release's test split;
# settings were tuned on it, so it is now ``val`` (the same rollouts); ``test`` draws from code 3, a stream
# nothing had been measured on when it was built.
SPLIT_CODES = {"train": 0, "serve": 1, "val": 2, "test": 3}
HELD_OUT = ("val", "test")  # never in train: val for tuning and model selection, test only for `rba eval` and tables
DEFAULT_SIZES = {"train": 300, "val": 120, "test": 120}  # serve: the domain's ``serve_size``
FORMAT_VERSION = 1


class LibraryNotFoundError(FileNotFoundError):
    pass


@dataclass
class SkillLibrary:
    """Rollouts of one split; row i of every array belongs to ``ids[i]``."""

    domain: str
    split: str
    ids: list[str]
    param_names: tuple[str, ...]
    attribute_names: tuple[str, ...]
    params: np.ndarray  # float64[N, P]
    seeds: np.ndarray  # int64[N]
    proxies: np.ndarray  # float64[N, k], columns in attribute_names order
    success: np.ndarray  # bool[N]
    state_offsets: np.ndarray  # int64[N + 1]
    states: np.ndarray  # float32[sum T, state_dim]
    replay_offsets: np.ndarray  # int64[N + 1]
    replay: np.ndarray  # float32[sum F, R] (float32 on disk: plenty for rendering, half the size)
    meta: dict = field(default_factory=dict)
    _index: dict[str, int] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self._index = {rid: i for i, rid in enumerate(self.ids)}

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def version(self) -> str:
        """Content hash: changes whenever any array changes (clip cache key, model cards)."""
        return self.meta.get("version") or _content_hash(self)

    @property
    def lengths(self) -> np.ndarray:
        return np.diff(self.state_offsets)

    def index_of(self, rollout_id: str) -> int:
        try:
            return self._index[rollout_id]
        except KeyError:
            raise KeyError(f"unknown rollout id {rollout_id!r} in {self.domain}/{self.split}") from None

    def __contains__(self, rollout_id: str) -> bool:
        return rollout_id in self._index

    def trajectory(self, i: int) -> np.ndarray:
        return self.states[self.state_offsets[i] : self.state_offsets[i + 1]]

    def proxies_of(self, i: int) -> dict[str, float]:
        return {a: float(v) for a, v in zip(self.attribute_names, self.proxies[i], strict=True)}

    def rollout(self, i: int) -> Rollout:
        return Rollout(
            id=self.ids[i],
            domain=self.domain,
            params=dict(zip(self.param_names, map(float, self.params[i]), strict=True)),
            seed=int(self.seeds[i]),
            states=self.trajectory(i),
            replay=self.replay[self.replay_offsets[i] : self.replay_offsets[i + 1]],
            proxies=self.proxies_of(i),
            success=bool(self.success[i]),
        )

    def subset(self, indices) -> SkillLibrary:
        idx = np.asarray(indices, dtype=np.int64)
        return SkillLibrary.from_rollouts([self.rollout(int(i)) for i in idx], self.split, self.param_names,
                                          self.attribute_names, dict(self.meta, version=None))

    @classmethod
    def from_rollouts(cls, rollouts: list[Rollout], split: str, param_names, attribute_names,
                      meta: dict | None = None) -> SkillLibrary:
        if not rollouts:
            raise ValueError("a library needs at least one rollout")

        def offsets(arrays):
            return np.concatenate([[0], np.cumsum([len(a) for a in arrays])]).astype(np.int64)

        lib = cls(
            domain=rollouts[0].domain,
            split=split,
            ids=[r.id for r in rollouts],
            param_names=tuple(param_names),
            attribute_names=tuple(attribute_names),
            params=np.array([[r.params[p] for p in param_names] for r in rollouts], dtype=np.float64),
            seeds=np.array([r.seed for r in rollouts], dtype=np.int64),
            proxies=np.array([[r.proxies[a] for a in attribute_names] for r in rollouts], dtype=np.float64),
            success=np.array([r.success for r in rollouts], dtype=bool),
            state_offsets=offsets([r.states for r in rollouts]),
            states=np.concatenate([r.states for r in rollouts]).astype(np.float32),
            replay_offsets=offsets([r.replay for r in rollouts]),
            replay=np.concatenate([r.replay for r in rollouts]).astype(np.float32),
            meta=dict(meta or {}),
        )
        lib.meta["version"] = _content_hash(lib)
        return lib

    # -- persistence -------------------------------------------------------------------
    _ARRAYS = ("params", "seeds", "proxies", "success", "state_offsets", "states", "replay_offsets", "replay")

    def save(self, root: Path | None = None) -> Path:
        files = library_files(root)
        save_npz(files.arrays(self.domain, self.split), {k: getattr(self, k) for k in self._ARRAYS})
        meta = dict(self.meta, format=FORMAT_VERSION, domain=self.domain, split=self.split, ids=self.ids,
                    param_names=list(self.param_names), attribute_names=list(self.attribute_names),
                    version=self.version)
        # JSON last: a library is complete only when its metadata names the arrays' hash.
        save_json(files.meta(self.domain, self.split), meta)
        return files.folder(self.domain)

    @classmethod
    def load(cls, domain: str, split: str, root: Path | None = None) -> SkillLibrary:
        if split not in SPLITS:
            raise ValueError(f"unknown split {split!r}; valid: {', '.join(SPLITS)}")
        files = library_files(root)
        npz, js = files.arrays(domain, split), files.meta(domain, split)
        if not files.complete(domain, split):
            raise LibraryNotFoundError(f"no {split} library for {domain!r} under {files.folder(domain)}; "
                                       f"run `rba build {domain}`")
        meta = load_json(js)
        arrays = load_npz(npz)
        lib = cls(domain=meta["domain"], split=meta["split"], ids=list(meta["ids"]),
                  param_names=tuple(meta["param_names"]), attribute_names=tuple(meta["attribute_names"]),
                  meta={k: v for k, v in meta.items() if k not in ("ids",)}, **arrays)
        if _content_hash(lib) != meta["version"]:
            raise ValueError(f"{npz} does not match its metadata (version {meta['version']}); rebuild it")
        return lib


def _content_hash(lib: SkillLibrary) -> str:
    h = hashlib.sha256()
    for name in SkillLibrary._ARRAYS:
        a = np.ascontiguousarray(getattr(lib, name))
        h.update(name.encode() + str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    h.update("\n".join(lib.ids).encode())
    return h.hexdigest()[:12]


# -- generation ------------------------------------------------------------------------

def generate(domain_name: str, split: str, n: int, seed: int = 0, workers: int = 2, progress: bool = True,
             compute: Compute | None = None) -> SkillLibrary:
    """Simulate ``n`` successful rollouts for ``split`` (failures are counted, not kept) on ``compute``
    (default: ``workers`` local processes, or this process when ``workers`` is 1).

    Each split draws parameters from its own seeded stream, so test parameters never repeat
    train parameters; rollout ``k`` of a split always has the same parameters and seed, whatever
    the backend or the number of workers.
    """
    from tqdm import tqdm

    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; valid: {', '.join(SPLITS)}")
    domain, target = get_domain(domain_name), domain_target(domain_name)
    split_code = SPLIT_CODES[split]
    rng = np.random.default_rng([seed, split_code])
    start = time.perf_counter()
    kept: list[Rollout] = []
    attempted = 0
    bar = tqdm(total=n, desc=f"{domain_name}/{split}", unit="rollout", disable=not progress)
    with _backend(compute, workers) as run:
        while len(kept) < n and attempted < 3 * n + 10:
            jobs = []
            for _ in range(max(n - len(kept), 1)):
                jobs.append(SimJob(target, domain.sample_params(rng),
                                   seed * 10_000_000 + split_code * 1_000_000 + attempted))
                attempted += 1
            for r in run(jobs):
                if r.success and len(kept) < n:
                    r.id = f"{split}-{len(kept):05d}"
                    kept.append(r)
                    bar.update(1)
    bar.close()
    if len(kept) < n:
        raise RuntimeError(f"only {len(kept)} of {attempted} {domain_name} rollouts succeeded; wanted {n}")
    seconds = time.perf_counter() - start
    meta = {"seed": seed, "attempted": attempted, "succeeded": len(kept), "success_rate": len(kept) / attempted,
            "build_seconds": round(seconds, 2), "workers": compute.capacity if compute else workers}
    log.info("%s/%s: %d rollouts (%d attempted) in %.1f s", domain_name, split, n, attempted, seconds)
    return SkillLibrary.from_rollouts(kept, split, domain.param_names, domain.attribute_names, meta)


@contextmanager
def _backend(compute: Compute | None, workers: int) -> Iterator[Callable[[list[SimJob]], Iterable[Rollout]]]:
    """``compute.simulate``; without a backend, a temporary local pool of ``workers`` (or this process)."""
    if compute is not None:
        yield compute.simulate
    elif workers > 1:
        from rba.compute.local import LocalCompute

        with LocalCompute(workers, nice=0) as local:
            yield local.simulate
    else:
        yield lambda jobs: (load_domain(j.target).rollout(j.params, j.seed) for j in jobs)


def build_all(domain_name: str, seed: int = 0, sizes: dict[str, int] | None = None, workers: int = 2,
              root: Path | None = None, progress: bool = True, compute: Compute | None = None,
              splits: tuple[str, ...] = SPLITS) -> dict[str, SkillLibrary]:
    """Generate and save ``splits`` (default: all); check that no held-out parameters occur in train.

    Building only some splits (``rba build --splits val test``) leaves the others as they are: train,
    for the check, is then loaded from ``root``.
    """
    unknown = [s for s in splits if s not in SPLITS]
    if unknown:
        raise ValueError(f"unknown split(s) {', '.join(map(repr, unknown))}; valid: {', '.join(SPLITS)}")
    domain = get_domain(domain_name)
    sizes = {**DEFAULT_SIZES, "serve": domain.serve_size, **{k: v for k, v in (sizes or {}).items() if v is not None}}
    libs = {s: generate(domain_name, s, sizes[s], seed, workers, progress, compute) for s in splits}
    train = libs["train"] if "train" in libs else SkillLibrary.load(domain_name, "train", root)
    train_rows = {tuple(row) for row in train.params}
    for split in HELD_OUT:
        leaked = sum(tuple(row) in train_rows for row in libs[split].params) if split in libs else 0
        if leaked:
            raise RuntimeError(f"{leaked} {split} rollouts repeat train parameters")
    for lib in libs.values():
        lib.save(root)
    return libs
