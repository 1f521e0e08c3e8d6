"""The one resolver of rollout ids (``server.runtime.clip_sources``): a serve clip and a made clip resolve to a key,
measured values and a rollout alike; an unknown id of either kind is one ``UnknownRollout``; guesses never simulate."""

from __future__ import annotations

import pytest
from sqlmodel import Session

from rba.compute.base import CLIP_PARTS
from rba.generate import cma
from rba.media.clip_cache import render_job
from server.db.engine import make_engine
from server.db.tables import GeneratedClip
from server.runtime.catalog import Catalog
from server.runtime.clip_sources import MADE, ClipRef, ClipSources, UnknownRollout

PARAMS = {"amplitude": 0.5, "pace": 0.5}


@pytest.fixture
def sources(make_settings, tmp_path):
    """A resolver over the toy domain and a database holding one made clip's row: (sources, db, made rollout)."""
    settings = make_settings(database_url=f"sqlite:///{tmp_path / 'rba.db'}")
    made = cma.replay("toy", PARAMS, 3)
    engine = make_engine(settings.db_url)
    with Session(engine) as db:
        db.add(GeneratedClip(id=made.id, domain="toy", params=made.params, seed=made.seed,
                             proxies={k: float(v) for k, v in made.proxies.items()}))
        db.commit()
        yield ClipSources(Catalog(settings), settings.clip_width, settings.clip_height), db, made
    engine.dispose()


def test_a_serve_clip_resolves_to_its_library(sources):
    resolver, db, _ = sources
    library = resolver.catalog.library("toy")
    rid = library.ids[2]
    clip = resolver.resolve(db, "toy", rid)
    assert clip.key.version == library.version and clip.key.parts == 1 and clip.rollout_id == rid
    assert clip.measured == library.proxies_of(2) and clip.generated is False
    assert clip.source() is library and clip.source(simulate=False) is library
    assert clip.rollout().id == rid and clip.rollout().params == library.rollout(2).params
    assert resolver.guess(ClipRef("toy", rid)) == (clip.key, library)


def test_a_made_clip_resolves_to_its_row_and_is_remade_only_when_asked(sources):
    resolver, db, made = sources
    clip = resolver.resolve(db, "toy", made.id)
    assert clip.key.version == MADE and clip.key.parts == CLIP_PARTS and clip.generated is True
    assert clip.measured == pytest.approx(made.proxies)
    assert clip.source(simulate=False) is None  # not in memory: a stored clip needs no simulation
    with pytest.raises(LookupError, match="no longer in memory"):
        resolver.guess(ClipRef("toy", made.id))  # a guess never simulates
    remade = clip.rollout()  # simulated again from the row's params and seed
    assert remade.id == made.id and (remade.states == made.states).all()
    assert clip.source(simulate=False) is remade and resolver.guess(ClipRef("toy", made.id)) == (clip.key, remade)
    assert render_job(clip.key, remade).split == CLIP_PARTS


def test_unknown_ids_of_either_kind_are_one_error_naming_valid_ids(sources):
    resolver, db, made = sources
    with pytest.raises(UnknownRollout, match=r"unknown rollout id 'nope' in toy/serve; ids look like ") as serve:
        resolver.resolve(db, "toy", "nope")
    assert serve.value.generated is False
    with pytest.raises(UnknownRollout, match="unknown generated rollout id 'gen-0000000000000000' in toy") as gen:
        resolver.resolve(db, "toy", "gen-0000000000000000")
    assert gen.value.generated is True
    with pytest.raises(UnknownRollout):  # a made clip of another domain is not this domain's
        resolver.resolve(db, "walker", made.id)
