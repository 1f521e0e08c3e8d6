"""The one place that tells where a rollout comes from: a rollout id -> its clip's key, measured values and rollout.

A rollout id names a clip of the domain's serve library (or of its test split: a study's target), or one a
generating session's search made (``gen-<hash of domain, params, seed>``: its row is ``GeneratedClip``, its
rollout is in the domain's ``GeneratedStore`` while recent, else simulated again from its params and seed). The
views, the clip route, exports, prerendering and the session steps ask this module for a ``ResolvedClip`` and
never look at the id themselves, so a new kind of rollout changes this module only
(``tests/test_architecture.py`` counts the places outside it that tell the kinds apart).

A made clip's key has its own version (``MADE``: its id already hashes what makes it, so a library rebuild
never changes it) and renders in ``CLIP_PARTS`` parts on separate workers: someone waits for it.

Import direction: above ``server.runtime.catalog`` and ``server.db``; ``server.runtime.services`` holds one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

from sqlmodel import Session

from rba.compute.base import CLIP_PARTS
from rba.data.library import LibraryNotFoundError, SkillLibrary
from rba.domains import Rollout
from rba.generate.cma import Simulate, in_process, is_generated
from rba.media.clip_cache import ClipKey, Source
from server.db.tables import GeneratedClip
from server.runtime.catalog import Catalog

TARGETS = "test"  # the split studies draw their targets from: its clips are served too
MADE = "generated"  # the key's version of a made clip (kept: it names the files already in clip stores)


class ClipRef(NamedTuple):
    """A clip by name: what the prerender tiers queue (resolved by ``ClipSources.guess`` when its turn comes)."""

    domain: str
    rollout_id: str


class UnknownRollout(LookupError):
    """No such rollout here: its message is a 404's detail, naming where valid ids come from."""

    def __init__(self, detail: str, generated: bool) -> None:
        super().__init__(detail)
        self.generated = generated  # what the id claims to be (the API shows it for a clip it cannot measure)


@dataclass(frozen=True)
class ResolvedClip:
    """A rollout id resolved: its clip's key and measured values, and how to get the rollout behind it."""

    key: ClipKey
    measured: dict[str, float]  # the rollout's proxies
    generated: bool  # made by a search, not a serve clip (the API says so; nothing branches on it)
    _source: Callable[[bool], Source | None]

    @property
    def rollout_id(self) -> str:
        return self.key.rollout_id

    def source(self, simulate: bool = True) -> Source | None:
        """What the clip renders from. A made clip no longer in memory is simulated again (blocking, on the compute
        layer), or is None with ``simulate=False`` (a stored clip needs no rollout)."""
        return self._source(simulate)

    def rollout(self) -> Rollout:
        """The rollout itself (simulated again if it must be)."""
        source = self.source()
        return source if isinstance(source, Rollout) else source.rollout(source.index_of(self.rollout_id))


class ClipSources:
    """Resolves rollout ids of every domain: its serve library's, then its made clips (rows and memory)."""

    def __init__(self, catalog: Catalog, width: int, height: int, simulate: Simulate = in_process) -> None:
        self.catalog, self.width, self.height, self.simulate = catalog, width, height, simulate

    def resolve(self, db: Session, domain: str, rollout_id: str) -> ResolvedClip:
        """The clip ``rollout_id`` of ``domain`` names; ``UnknownRollout`` if none (or no serve library)."""
        if is_generated(rollout_id):
            return self._made(db, domain, rollout_id)
        library = self._library(domain)
        if rollout_id not in library:
            library = self._target(domain, rollout_id, library)
        key = ClipKey(library.domain, library.version, rollout_id, self.width, self.height)
        measured = library.proxies_of(library.index_of(rollout_id))
        return ResolvedClip(key, measured, False, lambda _simulate: library)

    def guess(self, ref: ClipRef) -> tuple[ClipKey, Source]:
        """The key and source of a guessed clip (``server.runtime.prefetch.Resolve``). A guess never simulates and
        reads no database: a made clip is guessed while the domain's store keeps it (a search's runner-up has no
        row until shown), else ``LookupError`` (it is rendered once it is shown)."""
        if not is_generated(ref.rollout_id):
            library = self._library(ref.domain)
            library.index_of(ref.rollout_id)
            return ClipKey(library.domain, library.version, ref.rollout_id, self.width, self.height), library
        rollout = self.catalog.generated_store(ref.domain).get(ref.rollout_id)
        if rollout is None:
            raise LookupError(f"generated rollout {ref.rollout_id} of {ref.domain} is no longer in memory")
        return self._made_key(ref.domain, ref.rollout_id), rollout

    def _target(self, domain: str, rollout_id: str, serve: SkillLibrary) -> SkillLibrary:
        """The test split, when ``rollout_id`` is one of its clips (a study's target, shown beside the agent's)."""
        try:
            test = self.catalog.split(domain, TARGETS)
        except LibraryNotFoundError:
            test = None
        if test is None or rollout_id not in test:
            raise UnknownRollout(f"unknown rollout id {rollout_id!r} in {domain}/serve; ids look like "
                                 f"{serve.ids[0]}", generated=False)
        return test

    def _library(self, domain: str) -> SkillLibrary:
        try:
            return self.catalog.library(domain)
        except LibraryNotFoundError as exc:
            raise UnknownRollout(str(exc), generated=False) from exc

    def _made_key(self, domain: str, rollout_id: str) -> ClipKey:
        return ClipKey(domain, MADE, rollout_id, self.width, self.height, CLIP_PARTS)

    def _made(self, db: Session, domain: str, rollout_id: str) -> ResolvedClip:
        row = db.get(GeneratedClip, rollout_id)
        if row is None or row.domain != domain:
            raise UnknownRollout(f"unknown generated rollout id {rollout_id!r} in {domain}: generated ids come from "
                                 "a session's clip (clip.rollout_id of GET /api/sessions/{id})", generated=True)
        store, params, seed = self.catalog.generated_store(domain), dict(row.params), int(row.seed)

        def source(simulate: bool) -> Rollout | None:
            if not simulate:
                return store.get(rollout_id)
            return store.rollout(domain, rollout_id, params, seed, self.simulate)

        return ResolvedClip(self._made_key(domain, rollout_id), dict(row.proxies), True, source)
