"""What the server can offer: domains, which method/rep pairs have models, and the loaded contexts.

Contexts (models + serve library) are heavy, so each (domain, method, rep, model version) is loaded once,
on first use, behind a per-key lock so that concurrent first requests load it once.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from rba.core.fileio import load_json
from rba.core.locks import KeyedLocks
from rba.core.methods import get_method
from rba.core.store import ModelFiles, Store
from rba.data.library import SkillLibrary
from rba.domains import Domain, domain_names, get_domain
from rba.generate.cma import SearchConfig
from rba.interact import load_context
from rba.interact.generating_agent import GeneratedStore
from server.common.app_settings import Settings
from server.common.errors import invalid, not_found
from server.db.admin_tables import BUILTIN_VERSION
from server.db.tables import attribute_methods

log = logging.getLogger(__name__)

class Catalog:
    """Domains, availability, serve libraries and agent contexts of one server."""

    def __init__(self, settings: Settings) -> None:
        self.store = Store.from_settings(settings)
        # the generating agents' options from the settings: a domain's search time bound, and the spread
        self._search_seconds = settings.search_seconds
        self._spread = settings.generate_spread  # None: each domain's Domain.generate_spread
        self._contexts: dict[tuple[str, str, str, str], Any] = {}
        self._libraries: dict[str, SkillLibrary] = {}
        self._splits: dict[tuple[str, str], SkillLibrary] = {}  # held-out splits: studies' targets
        self._forms: dict[tuple[str, str, str, str], Any] = {}  # generating forms' contexts
        self._stores: dict[str, GeneratedStore] = {}
        self._locks = KeyedLocks()
        self._guard = threading.Lock()

    # -- domains ---------------------------------------------------------------------------
    def names(self) -> tuple[str, ...]:
        return domain_names()

    def domain(self, name: str) -> Domain:
        """The domain called ``name``; 404 naming the valid ones otherwise."""
        if name not in domain_names():
            raise not_found(f"unknown domain {name!r}; valid: {', '.join(domain_names())}")
        return get_domain(name)

    # -- model versions --------------------------------------------------------------------
    def models(self, version: str = BUILTIN_VERSION) -> ModelFiles:
        """A version's models: the shipped ones, or those a job published."""
        return self.store.models(None if version == BUILTIN_VERSION else version)

    def card_attributes(self, domain: str, method: str, rep: str, version: str = BUILTIN_VERSION) -> list[dict]:
        """The attributes (name, description, unit) the models of ``version`` were trained for."""
        models = self.models(version)
        kind = get_method(method).model_kinds[0]
        card = load_json(models.card(domain, kind, rep))
        return list(card["attributes"])

    def card(self, domain: str, kind: str, rep: str, version: str = BUILTIN_VERSION) -> dict | None:
        """The model card of one artifact of ``version``; None when it has none (or it is unreadable)."""
        try:
            card = load_json(self.models(version).card(domain, kind, rep))
        except (OSError, ValueError):
            return None
        return card if isinstance(card, dict) else None

    # -- availability ----------------------------------------------------------------------
    def has_library(self, domain: str) -> bool:
        return self.store.libraries.complete(domain, "serve")

    def available(self, domain: str, version: str = BUILTIN_VERSION) -> list[tuple[str, str]]:
        """(method, rep) pairs whose serve library and model files (weights + card) all exist."""
        if not self.has_library(domain):
            return []
        pairs = []
        models = self.models(version)
        for method in map(get_method, attribute_methods()):
            for rep in method.run_reps:
                if all(models.complete(domain, kind, rep) for kind in method.model_kinds):
                    pairs.append((method.name, rep))
        return pairs

    def missing_reason(self, domain: str) -> str | None:
        if not self.has_library(domain):
            return f"no skill library under {self.store.libraries.folder(domain)}; run `rba build {domain}`"
        if not self.available(domain):
            return f"no trained models under {self.store.models().folder(domain)}; run `rba train {domain}`"
        return None

    def check_available(self, domain: str, method: str, rep: str, version: str = BUILTIN_VERSION) -> None:
        """422 unless (method, rep) can serve ``domain`` (known names: ``SessionCreate`` checked them); the message
        lists what can."""
        pairs = self.available(domain, version)
        if (method, rep) not in pairs:
            have = ", ".join(f"{m}/{r}" for m, r in pairs) or f"none ({self.missing_reason(domain)})"
            raise invalid(f"no trained {method}/{rep} models for {domain}; available: {have}")

    # -- heavy objects ---------------------------------------------------------------------
    def context(self, domain: str, method: str, rep: str, version: str = BUILTIN_VERSION,
                generate: bool = False) -> Any:
        """The shared agent context (models + serve library), loaded once per key; with ``generate``, the context of
        the method's generating form (``Method.form``) over it (ValueError for a method that has none)."""
        if generate:
            return self._form_context(domain, method, rep, version)
        key = (domain, method, rep, version)
        ctx = self._contexts.get(key)
        if ctx is not None:
            return ctx
        with self._locks(key):
            ctx = self._contexts.get(key)
            if ctx is None:
                start = time.perf_counter()
                ctx = load_context(domain, method, rep, self.store.data_dir, self.models(version).root)
                self._contexts[key] = ctx
                log.info("loaded %s/%s/%s (model %s) in %.1f s", domain, method, rep, ctx.model_version,
                         time.perf_counter() - start)
        return ctx

    def _form_context(self, domain: str, method: str, rep: str, version: str) -> Any:
        """The generating form's context, built once per key over the base one with this server's options: the first
        clip is the library's (one for every session), each domain's search time bound, the spread. It simulates in
        this process: each step gives it the compute layer's ``simulate``."""
        form = get_method(method).form(True)
        key = (domain, method, rep, version)
        with self._locks(("generation", *key)):
            if key not in self._forms:
                self._forms[key] = form.extends(
                    self.context(*key), self.models(version).root, store=self.generated_store(domain),
                    first_from_library=True, config=SearchConfig(seconds=self._search_seconds(domain)),
                    spread=self._spread)
        return self._forms[key]

    def generated_store(self, domain: str) -> GeneratedStore:
        """Recent generated rollouts of ``domain`` in memory, shared by its contexts and the clip route."""
        with self._guard:
            return self._stores.setdefault(domain, GeneratedStore())

    def split(self, domain: str, split: str) -> SkillLibrary:
        """A held-out split of ``domain`` (a study's targets come from ``test``), loaded once; ``LibraryNotFoundError``
        when it was not built."""
        key = (domain, split)
        with self._locks(("split", *key)):
            if key not in self._splits:
                self._splits[key] = SkillLibrary.load(domain, split, self.store.data_dir)
        return self._splits[key]

    def library(self, domain: str) -> SkillLibrary:
        """The serve library of ``domain`` (shared with a loaded context when there is one)."""
        lib = self._libraries.get(domain)
        if lib is not None:
            return lib
        with self._locks(("library", domain)):
            lib = self._libraries.get(domain)
            if lib is None:
                with self._guard:
                    loaded = [c for (d, *_), c in self._contexts.items() if d == domain]
                lib = loaded[0].serve if loaded else SkillLibrary.load(domain, "serve", self.store.data_dir)
                self._libraries[domain] = lib
        return lib
