"""Labels made from proxies: local-change pairs for RBA-Local (paper §4.3), and their validation.

A local-change pair (τ_c, τ_t, α, h) says "τ_t is τ_c with a little more (h = +1) or less
(h = −1) of α, everything else kept". Proxies stand in for the agent designer who would pick
such pairs by hand. "A little" is expressed in units of each attribute's ε, the user's
resolution: the user only asks for a change when the shown behaviour is more than ε from
the target, so

* a change well below ε is not a *viable* one (the user would not see it), and
* a change of at most 2ε can never overshoot a target that is more than ε away,

hence the default band [0.5 ε, 1.5 ε] for the asked attribute, while every other attribute
may move by at most 0.5 ε (so an attribute the user is already happy with stays within ε).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger(__name__)


@dataclass
class LocalLabelConfig:
    """How local-change pairs are drawn (all changes in units of the attribute's ε)."""

    max_pairs: int = 200  # labelled pairs per domain (the paper's label budget)
    min_change: float = 0.5  # smallest change of the asked attribute, × ε
    max_change: float = 1.5  # largest change of the asked attribute, × ε
    keep: float = 0.5  # largest change of every other attribute, × ε
    per_attribute: dict[str, tuple[float, float]] = field(default_factory=dict)  # name -> (min, max) override, × ε
    seed: int = 0

    def band(self, name: str) -> tuple[float, float]:
        lo, hi = self.per_attribute.get(name, (self.min_change, self.max_change))
        if not 0 <= lo < hi:
            raise ValueError(f"change band for {name!r} must satisfy 0 <= min < max, got ({lo}, {hi})")
        return float(lo), float(hi)


@dataclass
class LocalPairs:
    """Row i: rollout ``target[i]`` is a minimal change of ``anchor[i]`` in ``attr[i]``, way ``direction[i]``."""

    anchor: np.ndarray  # int64[M], row indices into a library
    target: np.ndarray  # int64[M]
    attr: np.ndarray  # int64[M], attribute column
    direction: np.ndarray  # int64[M], +1 (more) or -1 (less)

    def __len__(self) -> int:
        return len(self.anchor)

    def reversed(self) -> LocalPairs:
        """The same pairs read backwards: τ_c is a minimal change of τ_t the other way (no new labels)."""
        return LocalPairs(self.target.copy(), self.anchor.copy(), self.attr.copy(), -self.direction)

    def concat(self, other: LocalPairs) -> LocalPairs:
        return LocalPairs(*(np.concatenate([getattr(self, f), getattr(other, f)])
                            for f in ("anchor", "target", "attr", "direction")))

    def to_records(self, ids: list[str], attribute_names: tuple[str, ...]) -> list[dict]:
        """JSON records ``{anchor, target, attribute, direction}`` with rollout ids (the upload format)."""
        return [{"anchor": ids[c], "target": ids[t], "attribute": attribute_names[a], "direction": int(h)}
                for c, t, a, h in zip(self.anchor, self.target, self.attr, self.direction, strict=True)]


def _empty() -> LocalPairs:
    z = np.zeros(0, dtype=np.int64)
    return LocalPairs(z, z.copy(), z.copy(), z.copy())


def local_pairs(proxies: np.ndarray, epsilons: np.ndarray, attribute_names: tuple[str, ...],
                cfg: LocalLabelConfig, max_pairs: int | None = None) -> LocalPairs:
    """Draw up to ``max_pairs`` (default ``cfg.max_pairs``) local-change pairs among the rows of ``proxies``.

    Anchors are visited in a seeded random order, each used at most once per pass, and the
    (attribute, direction) asked of each anchor rotates so that all are about equally common.
    The target is drawn uniformly among the rows inside the band.
    """
    proxies = np.asarray(proxies, dtype=np.float64)
    eps = np.asarray(epsilons, dtype=np.float64)
    n, k = proxies.shape
    if len(eps) != k or len(attribute_names) != k:
        raise ValueError(f"proxies have {k} columns but {len(eps)} epsilons and {len(attribute_names)} names")
    limit = cfg.max_pairs if max_pairs is None else max_pairs
    rng = np.random.default_rng(cfg.seed)
    # d[c, t, a]: change of attribute a from anchor c to target t, in ε
    d = (proxies[None, :, :] - proxies[:, None, :]) / eps
    combos = [(a, h) for a in range(k) for h in (1, -1)]
    valid = {}
    for a, h in combos:
        lo, hi = cfg.band(attribute_names[a])
        others = np.delete(np.abs(d), a, axis=2)
        ok = (h * d[:, :, a] >= lo) & (h * d[:, :, a] <= hi) & np.all(others <= cfg.keep, axis=2)
        np.fill_diagonal(ok, False)
        valid[(a, h)] = ok
    used: set[tuple[int, int, int]] = set()
    rows: list[tuple[int, int, int, int]] = []
    turn = 0
    while len(rows) < limit:
        added = 0
        for c in rng.permutation(n):
            if len(rows) >= limit:
                break
            for j in range(len(combos)):
                a, h = combos[(turn + j) % len(combos)]
                if (c, a, h) in used:
                    continue
                cand = np.flatnonzero(valid[(a, h)][c])
                if len(cand):
                    rows.append((int(c), int(rng.choice(cand)), a, h))
                    used.add((c, a, h))
                    turn = (turn + j + 1) % len(combos)
                    added += 1
                    break
        if not added:
            break
    if not rows:
        log.warning("no local-change pairs found among %d rollouts; is the band too narrow?", n)
        return _empty()
    arr = np.array(rows, dtype=np.int64)
    return LocalPairs(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3])


def pair_counts(pairs: LocalPairs, attribute_names: tuple[str, ...]) -> dict[str, int]:
    """How many pairs ask for more / less of each attribute (for model cards)."""
    out = {}
    for a, name in enumerate(attribute_names):
        for h, word in ((1, "more"), (-1, "less")):
            out[f"{word}_{name}"] = int(np.sum((pairs.attr == a) & (pairs.direction == h)))
    return out


def validate_local_records(records: list[dict], ids: list[str] | dict[str, int],
                           attribute_names: tuple[str, ...]) -> LocalPairs:
    """Check uploaded pairs ``{anchor, target, attribute, direction}`` and turn them into row indices.

    Raises ValueError naming the first bad record and what is wrong with it.
    """
    index = ids if isinstance(ids, dict) else {rid: i for i, rid in enumerate(ids)}
    if not isinstance(records, list) or not records:
        raise ValueError("local-change labels must be a non-empty list of {anchor, target, attribute, direction}")
    rows = []
    for n, rec in enumerate(records):
        if not isinstance(rec, dict):
            raise ValueError(f"label {n}: expected an object, got {type(rec).__name__}")
        missing = {"anchor", "target", "attribute", "direction"} - rec.keys()
        if missing:
            raise ValueError(f"label {n}: missing {', '.join(sorted(missing))}")
        for key in ("anchor", "target"):
            if rec[key] not in index:
                raise ValueError(f"label {n}: unknown rollout id {rec[key]!r} for {key}")
        if rec["anchor"] == rec["target"]:
            raise ValueError(f"label {n}: anchor and target are the same rollout {rec['anchor']!r}")
        if rec["attribute"] not in attribute_names:
            raise ValueError(f"label {n}: unknown attribute {rec['attribute']!r}; valid: {', '.join(attribute_names)}")
        if rec["direction"] not in (1, -1) or isinstance(rec["direction"], bool):
            raise ValueError(f"label {n}: direction must be +1 (more) or -1 (less), got {rec['direction']!r}")
        rows.append((index[rec["anchor"]], index[rec["target"]], attribute_names.index(rec["attribute"]),
                     rec["direction"]))
    arr = np.array(rows, dtype=np.int64)
    return LocalPairs(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3])
