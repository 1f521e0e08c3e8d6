"""Every label an agent designer gives, and the stand-ins proxies give for them.

* ``AttributeLabels``: for one attribute, which trajectory shows more of it than which
  (RBA-Global's ζσ learns from these). ``proxy_labels`` orders ``max_labelled`` train clips by
  proxy, the stand-in for an agent designer's labels.
* ``GlobalLabelConfig`` / ``annotator_labels``: the same labels as a person can give them: a seeded
  simulated annotator's answers to at most ``max_pairs`` pairs of those clips, with Bradley–Terry
  flips (a set share of the answers) and "can't tell" for pairs too close to tell apart.
* ``LocalPairs``: local-change pairs (τ_c, τ_t, α, h) for RBA-Local (paper §4.3): "τ_t is τ_c with
  a little more (h = +1) or less (h = −1) of α, everything else kept". "A little" is expressed in
  units of each attribute's ε, the user's resolution: the user only asks for a change when the
  shown behaviour is more than ε from the target, so a change well below ε is not a *viable* one
  (the user would not see it), and a change of at most 2ε can never overshoot a target that is
  more than ε away; hence the default band [0.5 ε, 1.5 ε] for the asked attribute, while every
  other attribute may move by at most 0.5 ε (so an attribute the user is already happy with
  stays within ε).
* ``LabelSet``: labels by reference to clips (orderings, comparisons, local changes), as admins
  give them. A clip reference is a library rollout id of the domain (``train-00012``,
  ``serve-00086``) or the name of a trajectory in the ``.npz`` uploaded with the labels. The JSON
  form is what ``POST /api/admin/datasets`` accepts and what the admin page saves::

    {"new_attributes": [{"name": "speed", "description": "How fast the walker moves forward."}],
     "orderings":   [{"attribute": "speed", "clips": ["serve-00003", "walk_a", "serve-00120"]}],
     "comparisons": [{"attribute": "step_size", "more": "walk_b", "less": "serve-00007"}],
     "local_changes": [{"attribute": "softness", "anchor": "serve-00001", "changed": "serve-00044",
                        "direction": "more"}]}

  An ordering lists clips from least to most of the attribute. A local change says ``changed``
  is ``anchor`` with a little more (or less) of the attribute and otherwise the same.
"""

from __future__ import annotations

import logging
import re
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, field_validator
from scipy.optimize import brentq
from scipy.special import expit

if TYPE_CHECKING:
    from rba.data.library import SkillLibrary

log = logging.getLogger(__name__)

ATTRIBUTE_NAME = re.compile(r"^[a-z][a-z0-9_]{0,31}$")
MAX_LABELS = 100_000  # label records per set
MAX_PROBLEMS = 50  # problems listed one by one; the rest are counted


def capped(problems: list[str], limit: int = MAX_PROBLEMS) -> list[str]:
    """At most ``limit`` problems, then how many more there are: a broken file of 100,000 labels stays readable."""
    extra = len(problems) - limit
    return problems if extra <= 0 else [*problems[:limit], f"and {extra} more problem(s)"]


# --- pairwise labels (RBA-Global's ζσ) ---


def labelled_subset(lib: SkillLibrary, max_labelled: int, seed: int) -> np.ndarray:
    """Indices of the train clips an agent designer would label (a seeded random subset)."""
    rng = np.random.default_rng(seed)
    n = min(max_labelled, len(lib))
    return np.sort(rng.choice(len(lib), size=n, replace=False))


@dataclass
class AttributeLabels:
    """One attribute's labels: which labelled trajectory shows more of it than which."""

    clips: np.ndarray  # int64[m]: the labelled trajectories (indices into the training data)
    more: np.ndarray  # bool[m, m]: more[i, j] = clips[i] shows more of the attribute than clips[j]

    def __post_init__(self) -> None:
        m = len(self.clips)
        if self.more.shape != (m, m):
            raise ValueError(f"more must be [{m}, {m}], got {list(self.more.shape)}")
        if (self.more & self.more.T).any():
            raise ValueError("contradictory labels: some pair is labelled both ways")

    @classmethod
    def from_values(cls, clips: np.ndarray, values: np.ndarray) -> AttributeLabels:
        """A total order by ``values`` (ties stay unlabelled): how proxies label clips."""
        values = np.asarray(values, dtype=np.float64)
        return cls(np.asarray(clips, dtype=np.int64), values[:, None] > values[None, :])

    @classmethod
    def from_pairs(cls, pairs: list[tuple[int, int]]) -> AttributeLabels:
        """From (more, less) trajectory pairs; orderings become the pairs they imply."""
        clips = np.unique(np.asarray(pairs, dtype=np.int64).reshape(-1))
        pos = {int(c): i for i, c in enumerate(clips)}
        more = np.zeros((len(clips), len(clips)), dtype=bool)
        for hi, lo in pairs:
            more[pos[int(hi)], pos[int(lo)]] = True
        return cls(clips, more)

    @property
    def num_pairs(self) -> int:
        return int(self.more.sum())

    def pairs(self) -> np.ndarray:
        """int64[P, 2]: every labelled (more, less) pair of trajectories."""
        hi, lo = np.nonzero(self.more)
        return np.stack([self.clips[hi], self.clips[lo]], 1)


def proxy_labels(lib: SkillLibrary, max_labelled: int, seed: int) -> list[AttributeLabels]:
    """Every attribute's ordering, by proxy, of the same ``max_labelled`` clips of ``lib``."""
    idx = labelled_subset(lib, max_labelled, seed)
    return [AttributeLabels.from_values(idx, lib.proxies[idx, a]) for a in range(lib.proxies.shape[1])]


# --- a simulated annotator's pairwise answers (ζσ's labels as a person can give them) ---


@dataclass(frozen=True)
class GlobalLabelConfig:
    """Where ζσ's labels come from: ``ordering`` (every pair of the labelled clips, ordered by proxy: the
    paper's stand-in, which no person can give) or ``pairwise`` (a simulated annotator's answers).

    The annotator is shown at most ``max_pairs`` distinct pairs of the labelled clips and answers each for
    every attribute: "can't tell" for the ``cant_tell`` share of pairs closest by proxy (a just-noticeable
    difference; those answers are dropped, see ``annotate_pairs``), otherwise "the first shows more" with
    probability sigmoid((p_i − p_j) / T), T calibrated so that an expected ``noise`` share is flipped.
    """

    mode: Literal["ordering", "pairwise"] = "ordering"
    max_pairs: int = 1000  # pairs shown (each answered for every attribute)
    noise: float = 0.1  # expected share of the more/less answers that contradict the proxy
    cant_tell: float = 0.1  # share of the shown pairs, per attribute, answered "can't tell"

    def __post_init__(self) -> None:
        if self.mode not in ("ordering", "pairwise"):
            raise ValueError(f"label mode must be 'ordering' or 'pairwise', got {self.mode!r}")
        if not 0 <= self.noise < 0.5:
            raise ValueError(f"label noise is a share of flipped answers in [0, 0.5), got {self.noise}")
        if not 0 <= self.cant_tell < 1:
            raise ValueError(f"the can't-tell share must be in [0, 1), got {self.cant_tell}")
        if self.max_pairs < 1:
            raise ValueError(f"max_pairs must be at least 1, got {self.max_pairs}")


def sample_pairs(m: int, max_pairs: int, rng: np.random.Generator) -> np.ndarray:
    """int64[P, 2]: min(max_pairs, m(m−1)/2) distinct unordered pairs (i < j) of range(m), uniformly."""
    i, j = np.triu_indices(m, 1)
    pick = np.sort(rng.choice(len(i), size=min(max_pairs, len(i)), replace=False))
    return np.stack([i[pick], j[pick]], 1).astype(np.int64)


def flip_temperature(abs_diffs: np.ndarray, noise: float) -> float:
    """T with mean(sigmoid(−|Δp| / T)) = ``noise`` over ``abs_diffs``: the expected flip share asked (0: none)."""
    d = np.asarray(abs_diffs, dtype=np.float64)
    if noise == 0 or not len(d) or not d.any():
        return 0.0
    scale = float(np.median(d[d > 0]))
    return float(np.exp(brentq(lambda lt: float(np.mean(expit(-d / np.exp(lt)))) - noise,
                               np.log(scale * 1e-6), np.log(scale * 1e6), xtol=1e-10)))


def annotate_pairs(values: np.ndarray, pairs: np.ndarray, cfg: GlobalLabelConfig, rng: np.random.Generator
                   ) -> tuple[list[tuple[int, int]], dict]:
    """One attribute's answers to ``pairs`` (indices into ``values``): (more, less) pairs and their stats.

    "Can't tell" (the ``cant_tell`` share closest by proxy, and every exact tie) is dropped rather than
    kept as a tie: ζσ only has to order clips, a tie's loss would pull apart-by-a-little clips onto one
    score, and the pairs a person cannot tell apart are the ones a flip would make wrong anyway.
    """
    d = values[pairs[:, 0]] - values[pairs[:, 1]]
    unsure = np.zeros(len(d), dtype=bool)
    unsure[np.argsort(np.abs(d), kind="stable")[: round(cfg.cant_tell * len(d))]] = True
    unsure |= d == 0
    d, answered = d[~unsure], pairs[~unsure]
    temp = flip_temperature(np.abs(d), cfg.noise)
    p_first = expit(d / temp) if temp > 0 else (d > 0).astype(np.float64)
    first = rng.random(len(d)) < p_first
    out = [(int(a), int(b)) if f else (int(b), int(a)) for (a, b), f in zip(answered, first, strict=True)]
    stats = {"answered": len(out), "cant_tell": int(unsure.sum()), "flipped": int(np.sum(first != (d > 0))),
             "temperature": temp}
    return out, stats


def annotator_labels(lib: SkillLibrary, max_labelled: int, cfg: GlobalLabelConfig, seed: int
                     ) -> tuple[list[AttributeLabels], dict]:
    """Every attribute's answers of a seeded simulated annotator over the same labelled clips and pairs.

    The clips are ``labelled_subset`` (at most ``max_labelled``), the pairs ``sample_pairs`` of them;
    returns the labels (row indices of ``lib``) and what the annotator did (a list: one entry per attribute).
    """
    idx = labelled_subset(lib, max_labelled, seed)
    rng = np.random.default_rng([seed, 1])
    pairs = sample_pairs(len(idx), cfg.max_pairs, rng)
    labels, stats = [], []
    for a in range(lib.proxies.shape[1]):
        answered, st = annotate_pairs(lib.proxies[idx, a], pairs, cfg, rng)
        stats.append(st)
        labels.append(AttributeLabels.from_pairs([(int(idx[hi]), int(idx[lo])) for hi, lo in answered]))
    return labels, {"pairs_shown": len(pairs), "clips": len(idx), "per_attribute": stats}


def merge_pairs(pair_lists: Iterable[Iterable[tuple[int, int]]]) -> AttributeLabels:
    """One attribute's labels from several sources; a later source overrides an earlier one on the same pair."""
    decided: dict[tuple[int, int], bool] = {}
    for pairs in pair_lists:
        for hi, lo in pairs:
            key = (min(hi, lo), max(hi, lo))
            decided[key] = hi < lo  # True: the smaller index has more
    return AttributeLabels.from_pairs([(a, b) if first else (b, a) for (a, b), first in decided.items()])


# --- local-change pairs (RBA-Local) ---


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

    @classmethod
    def from_rows(cls, rows: Iterable[tuple[int, int, int, int]]) -> LocalPairs:
        """From (anchor, target, attr, direction) rows (none: no pairs)."""
        arr = np.array(list(rows), dtype=np.int64).reshape(-1, 4)
        return cls(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3])

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
    rows = _draw_pairs(_viable_changes(proxies, eps, attribute_names, cfg), n, limit, rng)
    if not rows:
        log.warning("no local-change pairs found among %d rollouts; is the band too narrow?", n)
    return LocalPairs.from_rows(rows)


def _viable_changes(proxies: np.ndarray, eps: np.ndarray, attribute_names: tuple[str, ...],
                    cfg: LocalLabelConfig) -> dict[tuple[int, int], np.ndarray]:
    """(attr, direction) -> bool[anchor, target]: target is a change of anchor within the band."""
    k = proxies.shape[1]
    d = (proxies[None, :, :] - proxies[:, None, :]) / eps  # d[c, t, a]: change of a from c to t, in ε
    valid = {}
    for a, h in [(a, h) for a in range(k) for h in (1, -1)]:
        lo, hi = cfg.band(attribute_names[a])
        others = np.delete(np.abs(d), a, axis=2)
        ok = (h * d[:, :, a] >= lo) & (h * d[:, :, a] <= hi) & np.all(others <= cfg.keep, axis=2)
        np.fill_diagonal(ok, False)
        valid[(a, h)] = ok
    return valid


def _draw_pairs(valid: dict[tuple[int, int], np.ndarray], n: int, limit: int,
                rng: np.random.Generator) -> list[tuple[int, int, int, int]]:
    """Passes over the anchors in random order, rotating the asked (attr, direction), until ``limit``."""
    combos = list(valid)
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
    return rows


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
    return LocalPairs.from_rows(rows)


# --- label sets by clip reference (what admins give) ---


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class NewAttribute(_Strict):
    """An attribute the domain does not have yet; labels in the same file (or later) may use it."""

    name: str = Field(description="lower case letters, digits and _, starting with a letter, at most 32 characters "
                                  "(e.g. foot_lift); not one of the domain's own attributes",
                      examples=["foot_lift"])
    description: str = Field(description="one sentence (3-300 characters) saying what more of it looks like: the "
                                         "language representation embeds it",
                             examples=["How high the walker lifts its feet while stepping."])

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        if not ATTRIBUTE_NAME.match(v):
            raise ValueError(f"attribute name {v!r} must match {ATTRIBUTE_NAME.pattern} (lower case, digits, _)")
        return v

    @field_validator("description")
    @classmethod
    def _description(cls, v: str) -> str:
        v = v.strip()
        if not 3 <= len(v) <= 300:
            raise ValueError("a description is one sentence of 3-300 characters")
        return v


ATTRIBUTE_FIELD = ("a domain's own attribute (GET /api/admin/attributes), one an admin added, or one this file "
                   "declares in new_attributes")
CLIP_FIELD = ("a clip: a train or serve rollout id of the domain (e.g. train-00012, serve-00086) or the name of a "
              "trajectory in the .npz uploaded with the labels")


class Ordering(_Strict):
    """Clips ordered by how much of one attribute they show."""

    attribute: str = Field(max_length=32, description=ATTRIBUTE_FIELD)
    clips: list[str] = Field(min_length=2, max_length=1000, description=(
        f"2-1000 distinct clips from least to most of the attribute; each is {CLIP_FIELD}"))

    @field_validator("clips")
    @classmethod
    def _distinct(cls, v: list[str]) -> list[str]:
        if len(set(v)) != len(v):
            raise ValueError("an ordering lists each clip once")
        if any(not 0 < len(c) <= 128 for c in v):
            raise ValueError("clip references are 1-128 characters")
        return v


class Comparison(_Strict):
    """One clip shows more of an attribute than another."""

    attribute: str = Field(max_length=32, description=ATTRIBUTE_FIELD)
    more: str = Field(min_length=1, max_length=128, description=f"the clip with more of it: {CLIP_FIELD}")
    less: str = Field(min_length=1, max_length=128, description=f"the clip with less of it: {CLIP_FIELD}")


class LocalChange(_Strict):
    """``changed`` is ``anchor`` with a little more (or less) of an attribute and otherwise the same (RBA-Local)."""

    attribute: str = Field(max_length=32, description=ATTRIBUTE_FIELD)
    anchor: str = Field(min_length=1, max_length=128, description=f"the clip changed from: {CLIP_FIELD}")
    changed: str = Field(min_length=1, max_length=128, description=f"the changed clip: {CLIP_FIELD}")
    direction: Literal["more", "less"] = Field(description="whether changed shows a little more or a little less")


class LabelSet(_Strict):
    """A label file (POST /api/admin/datasets): a JSON object with any of these four lists, no other keys.

    ``problems`` checks it against what the domain and the upload hold.
    """

    new_attributes: list[NewAttribute] = Field(default_factory=list, max_length=16, description=(
        "attributes to add to the domain (at most 16), each named and described"))
    orderings: list[Ordering] = Field(default_factory=list, max_length=MAX_LABELS, description=(
        "clips from least to most of an attribute (every pair in an ordering counts as a comparison)"))
    comparisons: list[Comparison] = Field(default_factory=list, max_length=MAX_LABELS, description=(
        "pairs of clips: which shows more of an attribute"))
    local_changes: list[LocalChange] = Field(default_factory=list, max_length=MAX_LABELS, description=(
        "a clip and a minimal change of it in one attribute (RBA-Local learns from these)"))
    _positions: dict[str, list[int]] = PrivateAttr(default_factory=dict)  # a salvaged item's place in the file

    @classmethod
    def parse(cls, obj: object) -> tuple[LabelSet | None, list[str]]:
        """The label set and no problems; or, when it does not parse, what of it does (``salvage``, or None) and one
        line per problem, each naming where it is and what is valid."""
        try:
            return cls.model_validate(obj), []
        except ValidationError as e:
            return cls.salvage(obj), [_problem(err) for err in e.errors()]

    @classmethod
    def salvage(cls, obj: object) -> LabelSet | None:
        """The items of the known lists that parse on their own (None if none does): checked against the domain too,
        so that a misspelt key in one label does not hide an unknown attribute or clip in another."""
        if not isinstance(obj, dict):
            return None
        kept: dict[str, list] = {}
        positions: dict[str, list[int]] = {}
        for group, model in GROUP_MODELS.items():
            items = obj.get(group)
            if isinstance(items, list):
                parsed = [(i, x) for i, x in enumerate(_parsed(model, item) for item in items[:MAX_LABELS])
                          if x is not None]
                positions[group] = [i for i, _ in parsed]
                kept[group] = [x for _, x in parsed]
        kept["new_attributes"] = kept.get("new_attributes", [])[:16]
        labels = cls(**kept)
        labels._positions = positions
        return labels if labels.size() or labels.new_attributes else None

    def located(self) -> Iterable[tuple[str, str, list[str]]]:
        """(where, attribute, clips) of every label, where as in ``comparisons[3]`` (its place in the file)."""
        def where(group: str, i: int) -> str:
            return f"{group}[{self._positions[group][i] if group in self._positions else i}]"

        for i, o in enumerate(self.orderings):
            yield where("orderings", i), o.attribute, o.clips
        for i, p in enumerate(self.comparisons):
            yield where("comparisons", i), p.attribute, [p.more, p.less]
        for i, c in enumerate(self.local_changes):
            yield where("local_changes", i), c.attribute, [c.anchor, c.changed]

    def references(self) -> set[str]:
        return {c for _, _, clips in self.located() for c in clips}

    def attributes_used(self) -> set[str]:
        return {x.attribute for group in (self.orderings, self.comparisons, self.local_changes) for x in group}

    def size(self) -> int:
        return len(self.orderings) + len(self.comparisons) + len(self.local_changes)

    def problems(self, known_attributes: Iterable[str], known_clips: set[str] | frozenset[str],
                 builtin_attributes: Iterable[str]) -> list[str]:
        """What is wrong given the attributes that exist and the clips that can be referred to."""
        out = []
        builtin = set(builtin_attributes)
        declared = Counter(a.name for a in self.new_attributes)
        out += [f"new attribute {name!r} is already an attribute of the domain" for name in declared if name in builtin]
        out += [f"new attribute {name!r} is declared {k} times; declare each once"
                for name, k in sorted(declared.items()) if k > 1]
        valid = set(known_attributes) | builtin | {a.name for a in self.new_attributes}
        seen: set[str] = set()  # each unknown attribute and clip once, where it first appears
        for where, attribute, clips in self.located():
            if attribute not in valid and f"attribute {attribute}" not in seen:
                seen.add(f"attribute {attribute}")
                out.append(f"labels.{where}.attribute: unknown attribute {attribute!r}; valid: "
                           f"{', '.join(sorted(valid))} (declare a new one: new_attributes in an upload, or POST "
                           "/api/admin/attributes)")
            for ref in clips:
                if ref not in known_clips and ref not in seen:
                    seen.add(ref)
                    out.append(f"labels.{where}: clip {ref!r} is no train or serve rollout id of the domain (ids "
                               "look like train-00012 or serve-00086) and no trajectory name of the uploaded .npz")
        out += [f"comparison {i}: 'more' and 'less' are the same clip" for i, p in enumerate(self.comparisons)
                if p.more == p.less]
        out += [f"local change {i}: anchor and changed are the same clip" for i, p in enumerate(self.local_changes)
                if p.anchor == p.changed]
        if self.size() == 0 and not self.new_attributes:
            out.append("no labels: give orderings, comparisons or local_changes")
        return out

    def pairs(self, attribute: str) -> list[tuple[str, str]]:
        """Every (more, less) pair of clip references these labels state for ``attribute``."""
        out = [(p.more, p.less) for p in self.comparisons if p.attribute == attribute]
        for o in self.orderings:
            if o.attribute == attribute:
                out += [(o.clips[j], o.clips[i]) for i in range(len(o.clips)) for j in range(i + 1, len(o.clips))]
        return out


GROUP_MODELS: dict[str, type[_Strict]] = {"new_attributes": NewAttribute, "orderings": Ordering,
                                          "comparisons": Comparison, "local_changes": LocalChange}
"""The lists of a label file and the model of each item."""


def _parsed(model: type[_Strict], item: object) -> _Strict | None:
    try:
        return model.model_validate(item)
    except ValidationError:
        return None


def _where(loc: tuple) -> str:
    """``labels.comparisons[3].more`` for pydantic's ("comparisons", 3, "more")."""
    return "labels" + "".join(f"[{part}]" if isinstance(part, int) else f".{part}" for part in loc)


def _problem(err: dict) -> str:
    """One line for a pydantic error: where it is and, for a wrong or missing key, the keys that are valid there."""
    loc = tuple(err["loc"])
    model = GROUP_MODELS.get(loc[0], LabelSet) if len(loc) > 2 else LabelSet
    keys = ", ".join(model.model_fields)
    if err["type"] == "extra_forbidden":
        return f"{_where(loc[:-1])}: unknown key {loc[-1]!r}; valid keys: {keys}"
    if err["type"] == "missing":
        return f"{_where(loc[:-1])}: key {loc[-1]!r} is missing; an item of {loc[0]} has the keys {keys}"
    return f"{_where(loc)}: {str(err['msg']).removeprefix('Value error, ')}"
