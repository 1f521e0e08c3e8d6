"""The method registry: the one place that names every method (RBA-Global, RBA-Local, PbRL, ...).

A method is one frozen ``Method`` record, defined in the method's own module beside its agent:
the agent class, how to load its shared context, the model files it needs, how to train them.
The CLI, the evaluation, the server's catalog, jobs and API validation all iterate this registry.
Reference rows (``reference="floor"`` / ``"ceiling"``: the random and oracle rows of the tables) are registered
too, so ``rba eval`` and the tables run them, but ``methods()`` leaves them out unless asked: the web app
never offers them.
Records are imported lazily (listing names starts no torch). Adding a method = one module + one
line in ``REGISTRY``.
A method may have a *generating form* (``Method.generating``): another ``Method`` record, of an agent that
also makes clips beyond the serve library, reached through its base record rather than by a name of its own:
it shares the base's name, models and state (a session asks for it with ``generate``), so the CLI, the
evaluation's rows and the API's method names stay the registry's; ``Method.form`` picks the record that steps.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol

from rba.core.registry import Registry, import_object

if TYPE_CHECKING:
    from rba.interact.base import Agent, FeedbackKind
    from rba.learn.training import LabelSource, StageProgress

__all__ = ["REPS", "Method", "Rep", "Trainer", "UnknownMethodError", "generating_methods", "get_method", "method_names",
           "method_target", "method_targets", "methods", "register", "train_presets", "trainable"]


@dataclass(frozen=True)
class Rep:
    """How an attribute representation shows to people: the paper's row suffix, and whether it is for research."""

    suffix: str  # RBA-Global-L is the language rep
    description: str  # one line on what the models read, for people picking a method
    research: bool  # a variant the paper compares: the page offers it behind its "Advanced" choice


REPS = {
    "onehot": Rep("", "", research=False),
    "language": Rep("-L", "Research variant: the models read each attribute through a sentence embedding of its "
                    "description rather than as its own input.", research=True),
}


class Trainer(Protocol):
    """Fits and saves a method's model files at a named preset; returns the held-out metrics."""

    def __call__(self, domain: str, rep: str, preset: str, seed: int = 0, data_root: Path | None = None,
                 models_root: Path | None = None, sources: list[LabelSource] | None = None,
                 on_progress: StageProgress | None = None) -> dict: ...


@dataclass(frozen=True)
class Method:
    """Everything the rest of the code base needs to know about one method.

    ``name`` and ``feedback_kind`` are the agent class's own (its ``state_dict`` carries the name,
    its ``update`` checks the kind), so they are read from it rather than said twice.
    """

    agent: type[Agent]
    label: str  # display name, e.g. "RBA-Global"
    load_context: Callable[..., Any]  # (domain, rep, data_root=None, models_root=None) -> shared context
    model_kinds: tuple[str, ...]  # the ``<kind>-<rep>.pt`` files it needs; () when it learns online
    trainer: Trainer | None  # None when there is nothing to train beforehand
    presets: tuple[str, ...]  # valid ``preset`` names of ``trainer``
    reps: tuple[str, ...]  # attribute representations it learns with; () when it has none
    description: str = ""  # one line on how it chooses the next clip, for people picking a method (the API lists it)
    reference: Literal["floor", "ceiling"] | None = None  # a reference row of the tables, not a method people use
    # "module:RECORD" of this method's generating form (imported when asked for: it imports this one); None: none
    generating: str | None = None
    # a generating form's context built over its base method's loaded one (sharing its serve library and models):
    # (base context, models_root, **options) -> context; None for a method of the registry
    extends: Callable[..., Any] | None = None

    @property
    def name(self) -> str:
        return self.agent.method

    @property
    def feedback_kind(self) -> FeedbackKind:
        return self.agent.feedback_kind

    @property
    def run_reps(self) -> tuple[str, ...]:
        """The representations to run it with: its own, or once as "onehot" (ignored) when it has none."""
        return self.reps or ("onehot",)

    def form(self, generate: bool) -> Method:
        """The record whose agent steps this method's sessions: itself, or with ``generate`` its generating form;
        ValueError naming the methods that can generate."""
        if not generate:
            return self
        if self.generating is None:
            raise ValueError(f"method {self.name!r} cannot generate behaviours; valid with generation: "
                             f"{', '.join(generating_methods())}")
        return _form(self.generating)

    def describe(self, rep: str) -> str:
        """``description``, and with a research representation what its models read: the line the page shows."""
        note = REPS[rep].description if self.reps else ""
        return f"{self.description} {note}" if note else self.description

    def label_for(self, rep: str) -> str:
        """The paper's row label of this method with ``rep``: "RBA-Global", "RBA-Global-L", "PbRL"."""
        return self.label + (REPS[rep].suffix if self.reps else "")


class UnknownMethodError(ValueError):
    """A method name the registry does not know (a bad value: the message names the valid ones)."""


# name -> "module:Object" (a ``Method`` record)
REGISTRY = Registry("method", {
    "global": "rba.interact.global_agent:METHOD",
    "local": "rba.interact.local_agent:METHOD",
    "pbrl": "rba.interact.pbrl_agent:METHOD",
    "random": "rba.interact.reference:RANDOM",
    "oracle": "rba.interact.reference:ORACLE",
}, UnknownMethodError, on_change=lambda: get_method.cache_clear())
method_names = REGISTRY.names
method_target = REGISTRY.target
method_targets = REGISTRY.targets
register = REGISTRY.register  # a method at run time (plugins, tests), by the import path of its record


@cache
def get_method(name: str) -> Method:
    """The record of method ``name``; ``UnknownMethodError`` naming the valid ones otherwise."""
    record = import_object(method_target(name))
    if not isinstance(record, Method) or record.name != name:
        raise TypeError(f"{method_target(name)} is not the Method record of {name!r}")
    return record


@cache
def _form(target: str) -> Method:
    record = import_object(target)
    if not isinstance(record, Method) or record.extends is None:
        raise TypeError(f"{target} is not a generating form's Method record (one with ``extends``)")
    return record


def generating_methods() -> tuple[str, ...]:
    """The registered methods that have a generating form."""
    return tuple(m.name for m in methods() if m.generating is not None)


def methods(include_reference: bool = False) -> tuple[Method, ...]:
    """Every registered method's record, built-in ones first; the reference rows only if asked."""
    return tuple(m for m in map(get_method, method_names()) if include_reference or m.reference is None)


def trainable() -> tuple[Method, ...]:
    """The methods that have models to train beforehand (a ``trainer``)."""
    return tuple(m for m in methods() if m.trainer is not None)


def train_presets() -> tuple[str, ...]:
    """Every preset name some trainable method knows, in first-seen order."""
    return tuple(dict.fromkeys(p for m in trainable() for p in m.presets))
