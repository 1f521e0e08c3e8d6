"""The domain registry: the one place that names every domain.

Domains are imported lazily so that, say, listing domains does not start MuJoCo.
Adding a domain = one module + one line in ``REGISTRY``, or, from another installed package, an entry
point in the group ``rba.domains`` (``name = "module:Class"``): every process that imports this module
(the CLI, the server, compute workers, training jobs) registers those with :func:`discover`. A plugin is
imported once there, so one that is broken is refused with a warning naming its package instead of
failing later; it can never take a shipped domain's name.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterable
from functools import cache
from importlib.metadata import EntryPoint, entry_points

from rba.core.registry import Registry, import_object
from rba.domains.base import AttributeSpec, Domain, ParamSpace, Rollout

__all__ = ["AttributeSpec", "Domain", "ParamSpace", "Rollout", "discover", "domain_names", "domain_target",
           "domain_targets", "get_domain", "load_domain", "plugin_package", "register"]

ENTRY_POINT_GROUP = "rba.domains"
DOMAIN_NAME = re.compile(r"[a-z][a-z0-9_]{0,63}")  # a name is a folder under data/ and models/: never a path


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


class PluginWarning(UserWarning):
    """An installed plugin domain was refused (the message names its package and why)."""


_PLUGINS: dict[str, str] = {}  # plugin domain name -> the distribution that registered it


def plugin_package(name: str) -> str | None:
    """The installed package that registered domain ``name`` through an entry point (None: not a plugin)."""
    return _PLUGINS.get(name)


def _package(ep: EntryPoint) -> str:
    return ep.dist.name if ep.dist is not None else "an unknown package"


def _refusal(ep: EntryPoint) -> str | None:
    """Why the entry point cannot be the domain it names, or None when it can (its class is imported here)."""
    if not DOMAIN_NAME.fullmatch(ep.name):
        return f"the name {ep.name!r} is not a domain name (lowercase letters, digits and _, starting with a letter)"
    if ep.name in REGISTRY.builtin:
        return f"{ep.name!r} is a domain rba ships; a plugin cannot replace it (choose another name)"
    if ep.attr is None:
        return f"its target {ep.value!r} is not \"module:Class\""
    try:
        cls = import_object(ep.value)
    except Exception as exc:  # a plugin's import may fail in any way; the shipped domains must not
        return f"importing {ep.value!r} failed: {type(exc).__name__}: {exc}"
    if not (isinstance(cls, type) and issubclass(cls, Domain)):
        return f"{ep.value!r} is not a subclass of rba.domains.Domain"
    if getattr(cls, "name", None) != ep.name:
        return f"{ep.value!r} has name {getattr(cls, 'name', None)!r}, not the entry point's {ep.name!r}"
    return None


def discover(found: Iterable[EntryPoint] | None = None) -> list[str]:
    """Register the domains installed packages declare in the group ``rba.domains`` (default: those installed);
    the names registered. A refused one (a bad name, a shipped name, a target that does not import, a name two
    packages claim) gives a :class:`PluginWarning` naming its package and is left out."""
    found = list(entry_points(group=ENTRY_POINT_GROUP) if found is None else found)
    claims: dict[str, set[str]] = {}
    for ep in found:
        claims.setdefault(ep.name, set()).add(_package(ep))
    registered, seen = [], set()
    for ep in found:
        if ep.name in seen:  # a name two packages claim is refused once; a package listed twice counts once
            continue
        seen.add(ep.name)
        if len(claims[ep.name]) > 1:
            why = f"the packages {', '.join(sorted(claims[ep.name]))} all register {ep.name!r}; none is used"
        else:
            why = _refusal(ep)
        if why is not None:
            warnings.warn(f"plugin domain {ep.name!r} from package {_package(ep)!r} was not registered: {why}",
                          PluginWarning, stacklevel=2)
            continue
        register(ep.name, ep.value)
        _PLUGINS[ep.name] = _package(ep)
        registered.append(ep.name)
    return registered


discover()
