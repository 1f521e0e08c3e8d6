"""The domain registry: the one place that names every domain.

Domains are imported lazily so that, say, listing domains does not start MuJoCo.
Adding a domain = one module + one line in ``REGISTRY``.
"""

from __future__ import annotations

from functools import cache

from rba.core.registry import Registry, import_object
from rba.domains.base import AttributeSpec, Domain, ParamSpace, Rollout

__all__ = ["AttributeSpec", "Domain", "ParamSpace", "Rollout", "domain_names", "domain_target", "domain_targets",
           "get_domain", "load_domain", "register"]


class UnknownDomainError(KeyError):
    def __str__(self) -> str:  # KeyError quotes its message; we want it plain
        return str(self.args[0])


# name -> "module:Class"
REGISTRY = Registry("domain", {
    "walker": "rba.domains.walker:Walker",
    "lane_change": "rba.domains.lane_change:LaneChange",
    "lane_change_image": "rba.domains.lane_change_image:LaneChangeImage",
    "manipulator": "rba.domains.manipulator:Manipulator",
    "snake": "rba.domains.snake:Snake",
    "walker_raw": "rba.domains.walker:WalkerRaw",
    "manipulator_raw": "rba.domains.manipulator:ManipulatorRaw",
    "lane_change_raw": "rba.domains.lane_change:LaneChangeRaw",
    "snake_raw": "rba.domains.snake:SnakeRaw",
}, UnknownDomainError, on_change=lambda: get_domain.cache_clear())
domain_names = REGISTRY.names
domain_target = REGISTRY.target
domain_targets = REGISTRY.targets
register = REGISTRY.register  # a domain at run time (plugins, tests), by its import path "module:Class"


@cache
def load_domain(target: str) -> Domain:
    """Instantiate (once per process) the domain class at ``"module:Class"``."""
    return import_object(target)()


@cache
def get_domain(name: str) -> Domain:
    """The (cached) domain instance called ``name``."""
    return load_domain(domain_target(name))
