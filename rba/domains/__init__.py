"""The domain registry: the one place that names every domain.

Domains are imported lazily so that, say, listing domains does not start MuJoCo.
Adding a domain = one module + one line in ``_BUILTIN``.
"""

from __future__ import annotations

import importlib
from functools import cache

from rba.domains.base import AttributeSpec, Domain, Rollout

__all__ = ["AttributeSpec", "Domain", "Rollout", "domain_names", "domain_target", "get_domain", "load_domain",
           "register"]

# name -> "module:Class"
_BUILTIN: dict[str, str] = {
    "walker": "rba.domains.walker:Walker",
    "lane_change": "rba.domains.lane_change:LaneChange",
    "lane_change_image": "rba.domains.lane_change_image:LaneChangeImage",
    "manipulator": "rba.domains.manipulator:Manipulator",
    "snake": "rba.domains.snake:Snake",
}
_EXTRA: dict[str, str] = {}


class UnknownDomainError(KeyError):
    def __str__(self) -> str:  # KeyError quotes its message; we want it plain
        return str(self.args[0])


def register(name: str, target: str) -> None:
    """Register a domain at run time (plugins, tests) by its import path ``"module:Class"``.

    A path, not an object, so that simulation worker processes can import it too.
    """
    _EXTRA[name] = target
    get_domain.cache_clear()


def domain_target(name: str) -> str:
    """The ``"module:Class"`` import path of domain ``name``."""
    if name in _EXTRA:
        return _EXTRA[name]
    if name not in _BUILTIN:
        raise UnknownDomainError(f"unknown domain {name!r}; valid: {', '.join(domain_names())}")
    return _BUILTIN[name]


@cache
def load_domain(target: str) -> Domain:
    """Instantiate (once per process) the domain class at ``"module:Class"``."""
    module_name, cls_name = target.split(":")
    return getattr(importlib.import_module(module_name), cls_name)()


def domain_names() -> tuple[str, ...]:
    return tuple(_BUILTIN) + tuple(n for n in _EXTRA if n not in _BUILTIN)


@cache
def get_domain(name: str) -> Domain:
    """The (cached) domain instance called ``name``."""
    return load_domain(domain_target(name))
