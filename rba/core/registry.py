"""What the domain and the method registries share: names -> ``"module:Object"`` import paths.

Built-in names come first, then those registered at run time (plugins, tests). Paths rather than
objects, so that worker and training processes can import the same things: a parent passes
``targets()`` and the child ``register``s them again.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable


def import_object(target: str) -> object:
    """The object at ``"module:Object"``."""
    module_name, name = target.split(":")
    return getattr(importlib.import_module(module_name), name)


class Registry:
    """One kind of registered thing ("domain", "method"): its names and their import paths."""

    def __init__(self, kind: str, builtin: dict[str, str], error: Callable[[str], Exception],
                 on_change: Callable[[], None] = lambda: None) -> None:
        self.kind, self.builtin, self.extra = kind, dict(builtin), {}
        self._error, self._on_change = error, on_change

    def register(self, name: str, target: str) -> None:
        self.extra[name] = target
        self._on_change()

    def names(self) -> tuple[str, ...]:
        return tuple(self.builtin) + tuple(n for n in self.extra if n not in self.builtin)

    def target(self, name: str) -> str:
        """The import path of ``name``; the registry's error naming the valid names otherwise."""
        if name in self.extra:
            return self.extra[name]
        if name not in self.builtin:
            raise self._error(f"unknown {self.kind} {name!r}; valid: {', '.join(self.names())}")
        return self.builtin[name]

    def targets(self) -> dict[str, str]:
        """Every name's import path (what another process needs to register the same things)."""
        return {name: self.target(name) for name in self.names()}
