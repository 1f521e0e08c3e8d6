"""How the generating agent searches and reads clips, in one typed record: what ``rba eval --gen-config FILE``
loads and what benchmarks build to tune on val.

These are research settings: each default was chosen on val (docs/decisions/0003-0011), so a user never needs
them and the command line does not list them. A field left ``None`` takes its default where the agent is made:
the ``Domain`` class attribute of the same name (``resolved``), or the search's own. The file (TOML or JSON)
names only the fields it changes; unknown keys and bad values are refused with what is valid.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rba.generate.cma import SearchConfig, Simulate

if TYPE_CHECKING:
    from rba.domains.base import Domain

FILE_KINDS = (".toml", ".json")


def _setting(doc: str, kind: type, valid: str, ok: Callable[[Any], bool], default: Any = None) -> Any:
    """A field with its documentation and its check (``kind``, then ``ok``; ``valid`` says what passes)."""
    return field(default=default, metadata={"doc": doc, "kind": kind, "valid": valid, "ok": ok})


def _finite(low: float, high: float = math.inf, low_open: bool = False) -> Callable[[float], bool]:
    return lambda v: (low < v if low_open else low <= v) and v < high


@dataclass(frozen=True)
class GenerationConfig:
    """The generating agent's research settings (docs/architecture.md §5); ``None``: the default where the agent
    is made (``resolved``). Each field's ``metadata["doc"]`` says what it does; ``describe()`` lists them."""

    budget: int = _setting(
        "simulations per made clip at most (CMA-ES generations of 8 candidates)", int, "a whole number ≥ 1",
        lambda v: v >= 1, SearchConfig.budget)
    seconds: float | None = _setting(
        "bound each search in time as the app does (RBA_GENERATE_SECONDS, Domain.generate_seconds): no CMA-ES "
        "generation starts that would end later; null: the budget alone, so results do not depend on the machine "
        "(decision 0005)", float, "a number of seconds > 0", _finite(0.0, low_open=True))
    threshold: float | None = _setting(
        "ζσ distance (ζσ's train range = 1) beyond which the agent makes a clip; null: the agent's own, 0.02 "
        "(decision 0003)", float, "a finite number ≥ 0", _finite(0.0))
    generate_spread: float | None = _setting(
        "search only where the library clip also misses its target by more than this share of the belief's half "
        "interquartile range (0: by the threshold alone); null: Domain.generate_spread (decisions 0003, 0008)",
        float, "a finite number ≥ 0", _finite(0.0))
    zeta_noise: float | None = _setting(
        "the belief's soft step for answers, a share of ζσ's train range (0: the hard step); null: "
        "Domain.zeta_noise (decision 0006)", float, "a share in [0, 1)", _finite(0.0, 1.0))
    belief_prior: float | None = _setting(
        "the belief starts where the serve clips lie in ζσ, a kernel of this share of ζσ's train range (0: uniform); "
        "null: Domain.belief_prior (decision 0010)", float, "a share in [0, 1)", _finite(0.0, 1.0))
    zeta_surface: int | None = _setting(
        "read and make clips on a fit of ζσ over the skill's parameters through this many nearest serve clips "
        "(0: each clip's own ζσ); null: Domain.zeta_surface (decision 0008)", int,
        "0 (no surface) or a whole number of clips ≥ 2", lambda v: v == 0 or v >= 2)
    session_refit: bool | None = _setting(
        "re-fit ζσ's last layers near the target on the session's answers (not with a surface); null: "
        "Domain.session_refit (decision 0011)", bool, "true or false", lambda v: True)
    noisy_skill: bool | None = _setting(
        "simulate each candidate of a search with a seed of its own, so the skill's noise is chosen among too "
        "(false: one seed); null: Domain.noisy_skill (decision 0007)", bool, "true or false", lambda v: True)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if value is not None:
                object.__setattr__(self, f.name, _checked(f.name, value, f.metadata))

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @classmethod
    def describe(cls) -> str:
        """One line per key with what it does: the reference the guide and the refusals point to."""
        return "\n".join(f"{f.name} ({f.metadata['valid']}): {f.metadata['doc']}" for f in fields(cls))

    @classmethod
    def from_mapping(cls, values: dict[str, Any]) -> GenerationConfig:
        """A config from a file's table; unknown keys are refused naming the valid ones."""
        unknown = sorted(set(values) - set(cls.names()))
        if unknown:
            raise ValueError(f"unknown generation setting {', '.join(map(repr, unknown))}; valid: "
                             f"{', '.join(cls.names())}")
        return cls(**values)

    @classmethod
    def from_file(cls, path: Path) -> GenerationConfig:
        """The config a ``.toml`` or ``.json`` file names (only the keys it changes)."""
        path = Path(path)
        if path.suffix not in FILE_KINDS:
            raise ValueError(f"a generation config is a {' or '.join(FILE_KINDS)} file, got {path.name!r}")
        text = path.read_text(encoding="utf-8")
        try:
            values = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text)
        except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(f"{path.name} is not valid {path.suffix[1:].upper()}: {exc}") from None
        if not isinstance(values, dict):
            raise ValueError(f"{path.name} must hold a table of settings; valid keys: {', '.join(cls.names())}")
        return cls.from_mapping(values)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    def resolved(self, domain: Domain) -> GenerationConfig:
        """Every ``None`` a ``Domain`` attribute of the same name has taken from ``domain``: what the agent runs
        with (``seconds`` and ``threshold`` stay ``None``: the budget alone, the agent's threshold)."""
        own = {k: getattr(domain, k) for k in self.names() if getattr(self, k) is None and hasattr(domain, k)}
        return replace(self, **own)

    def context_options(self, domain: Domain, simulate: Simulate | None = None) -> dict[str, Any]:
        """Keyword arguments of the agent's ``GenerationContext``, defaults resolved on ``domain``."""
        c = self.resolved(domain)
        options: dict[str, Any] = {
            "config": SearchConfig(budget=c.budget, seconds=c.seconds, vary_seed=c.noisy_skill),
            "spread": c.generate_spread, "zeta_noise": c.zeta_noise, "prior_width": c.belief_prior,
            "surface": c.zeta_surface, "refit": c.session_refit}
        if c.threshold is not None:
            options["threshold"] = c.threshold
        if simulate is not None:
            options["simulate"] = simulate
        return options


def _checked(name: str, value: Any, meta: dict[str, Any]) -> Any:
    """``value`` of the field ``name`` as its kind (an int is a float too), or ValueError saying what is valid."""
    kind, given = meta["kind"], value
    fits = isinstance(value, kind) and (kind is bool or not isinstance(value, bool))
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value, fits = float(value), True
    if not fits or not meta["ok"](value):
        raise ValueError(f"generation setting {name} must be {meta['valid']}, got {given!r}")
    return value
