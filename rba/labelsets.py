"""Labels an agent designer gives, by reference to clips: orderings, comparisons, local changes.

A clip reference is a library rollout id of the domain (``train-00012``, ``serve-00086``) or
the name of a trajectory in the ``.npz`` uploaded with the labels. The JSON form is what
``POST /api/admin/datasets`` accepts and what the admin page saves::

    {"new_attributes": [{"name": "speed", "description": "How fast the walker moves forward."}],
     "orderings":   [{"attribute": "speed", "clips": ["serve-00003", "walk_a", "serve-00120"]}],
     "comparisons": [{"attribute": "step_size", "more": "walk_b", "less": "serve-00007"}],
     "local_changes": [{"attribute": "softness", "anchor": "serve-00001", "changed": "serve-00044",
                        "direction": "more"}]}

An ordering lists clips from least to most of the attribute. A local change says ``changed``
is ``anchor`` with a little more (or less) of the attribute and otherwise the same (RBA-Local).
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from rba.learn.ranker import AttributeLabels

ATTRIBUTE_NAME = re.compile(r"^[a-z][a-z0-9_]{0,31}$")
MAX_LABELS = 100_000  # label records per set


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


ClipRef = Field(min_length=1, max_length=128)


class NewAttribute(_Strict):
    name: str = Field(description="lower-case identifier, e.g. speed")
    description: str = Field(description="one sentence (3-300 characters): what more of it looks like")

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


class Ordering(_Strict):
    attribute: str = Field(max_length=32)
    clips: list[str] = Field(min_length=2, max_length=1000, description="least to most of the attribute")

    @field_validator("clips")
    @classmethod
    def _distinct(cls, v: list[str]) -> list[str]:
        if len(set(v)) != len(v):
            raise ValueError("an ordering lists each clip once")
        if any(not 0 < len(c) <= 128 for c in v):
            raise ValueError("clip references are 1-128 characters")
        return v


class Comparison(_Strict):
    attribute: str = Field(max_length=32)
    more: str = ClipRef
    less: str = ClipRef


class LocalChange(_Strict):
    attribute: str = Field(max_length=32)
    anchor: str = ClipRef
    changed: str = ClipRef
    direction: Literal["more", "less"]


class LabelSet(_Strict):
    """One batch of labels; ``problems`` checks it against what the domain and the upload hold."""

    new_attributes: list[NewAttribute] = Field(default_factory=list, max_length=16)
    orderings: list[Ordering] = Field(default_factory=list, max_length=MAX_LABELS)
    comparisons: list[Comparison] = Field(default_factory=list, max_length=MAX_LABELS)
    local_changes: list[LocalChange] = Field(default_factory=list, max_length=MAX_LABELS)

    @classmethod
    def parse(cls, obj: object) -> tuple[LabelSet | None, list[str]]:
        """The label set, or None and one readable line per problem."""
        try:
            return cls.model_validate(obj), []
        except ValidationError as e:
            return None, [f"labels.{'.'.join(map(str, err['loc'])) or 'root'}: "
                          f"{str(err['msg']).removeprefix('Value error, ')}" for err in e.errors()]

    def references(self) -> set[str]:
        refs = {c for o in self.orderings for c in o.clips}
        refs |= {c for p in self.comparisons for c in (p.more, p.less)}
        refs |= {c for p in self.local_changes for c in (p.anchor, p.changed)}
        return refs

    def attributes_used(self) -> set[str]:
        return {x.attribute for group in (self.orderings, self.comparisons, self.local_changes) for x in group}

    def size(self) -> int:
        return len(self.orderings) + len(self.comparisons) + len(self.local_changes)

    def problems(self, known_attributes: Iterable[str], known_clips: set[str] | frozenset[str],
                 builtin_attributes: Iterable[str]) -> list[str]:
        """What is wrong given the attributes that exist and the clips that can be referred to."""
        out = []
        builtin = set(builtin_attributes)
        for a in self.new_attributes:
            if a.name in builtin:
                out.append(f"new attribute {a.name!r} is already an attribute of the domain")
        valid = set(known_attributes) | builtin | {a.name for a in self.new_attributes}
        for name in sorted(self.attributes_used() - valid):
            out.append(f"unknown attribute {name!r}; valid: {', '.join(sorted(valid))} "
                       "(declare a new one under new_attributes)")
        missing = sorted(self.references() - set(known_clips))
        if missing:
            shown = ", ".join(repr(m) for m in missing[:10]) + (f" and {len(missing) - 10} more" if len(missing) > 10
                                                                 else "")
            out.append(f"{len(missing)} clip reference(s) match no uploaded trajectory and no library rollout: {shown}")
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


def merge_pairs(pair_lists: Iterable[list[tuple[int, int]]]) -> AttributeLabels:
    """One attribute's labels from several sources; a later source overrides an earlier one on the same pair."""
    decided: dict[tuple[int, int], bool] = {}
    for pairs in pair_lists:
        for hi, lo in pairs:
            key = (min(hi, lo), max(hi, lo))
            decided[key] = hi < lo  # True: the smaller index has more
    return AttributeLabels.from_pairs([(a, b) if first else (b, a) for (a, b), first in decided.items()])
