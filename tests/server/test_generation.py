"""Generating sessions over HTTP: an answer no serve clip fits starts a search (202), the page polls its progress,
and the clip it made is served, listed in the history, exported and kept across a restart.

The toy serve library has a gap (``gap_roots``): the agent's targets there are far from every clip, so answers
from the first clip search. ``InProcessCompute`` simulates in the test's process and renders at once.
"""

from __future__ import annotations

import copy
import time

import pytest
from fastapi.testclient import TestClient
from pydantic import ValidationError
from sqlmodel import Session

from rba.compute.base import CLIP_PARTS
from rba.core.methods import get_method
from rba.data.export_zip import read_export, replay
from rba.generate import cma
from rba.generate.cma import generated_id, is_generated
from rba.interact import AttributeFeedback, generating_agent
from rba.interact.generating_agent import GeneratingGlobalAgent
from rba.media.clip_cache import ClipKey, render_job
from server.common.app_settings import Settings
from server.db.admin_tables import BUILTIN_VERSION
from server.db.tables import TuningSession
from server.main import create_app
from server.ops.prerender import next_clips, resume_prerender
from server.ops.session_export import export_to_file
from server.ops.session_searches import WouldSearch, begin, step_context
from server.ops.session_steps import load_session
from server.runtime.clip_sources import MADE, ClipRef
from tests.fakes import FakeCompute, InProcessCompute, InstantCompute
from tests.server.conftest import more
from tests.toy import Toy

SEARCH_SECONDS = 30
GENERATING = get_method("global").form(True)  # RBA-Global's generating form: what steps these sessions


@pytest.fixture
def gen_settings(make_settings, gap_roots, database_url):
    data, models = gap_roots
    return make_settings(data_dir=data, models_dir=models, database_url=database_url, generate=True,
                         generate_spread=0.0,  # every answer off the target searches, however wide the belief
                         generate_seconds=60.0)  # searches run their whole budget: slow enough to watch


def search_done(client: TestClient, sid: str) -> dict:
    """Poll the session's search until it ends; its last progress."""
    deadline = time.monotonic() + SEARCH_SECONDS
    while time.monotonic() < deadline:
        r = client.get(f"/api/sessions/{sid}/generation")
        assert r.status_code == 200, r.text
        if r.json()["state"] != "searching":
            return r.json()
        time.sleep(0.02)
    raise AssertionError(f"the search of session {sid} did not end in {SEARCH_SECONDS} s")


def answer_generating(client: TestClient, s: dict, attribute: str = "amplitude", direction: str = "less") -> dict:
    """Answer ``s``'s clip; the answer must search (202 naming the progress route); the session after it."""
    r = client.post(f"/api/sessions/{s['id']}/feedback", json=more(attribute, s["step"], direction,
                                                                   clip=s["clip"]["rollout_id"]))
    assert r.status_code == 202, r.text
    assert r.headers["location"] == f"/api/sessions/{s['id']}/generation"
    assert r.json()["step"] == s["step"]  # still at its step, and clip, until the search ends
    assert r.json()["clip"]["rollout_id"] == s["clip"]["rollout_id"]
    progress = search_done(client, s["id"])
    assert progress["state"] == "done" and progress["step"] == s["step"] and progress["detail"] is None
    assert 1 <= progress["generation"] <= progress["generations"] == 6  # SearchConfig(): 48 simulations, 8 a gen.
    now = client.get(f"/api/sessions/{s['id']}").json()
    assert now["step"] == s["step"] + 1 and now["generation"] is None
    return now


def test_a_generated_clip_is_served_listed_and_exported(gen_settings, tmp_path, local_compute):
    compute = InProcessCompute()
    with TestClient(create_app(gen_settings, compute)) as client:
        s = client.post("/api/sessions", json={"domain": "toy"}).json()
        assert s["generate"] is True and s["clip"]["generated"] is False  # every session starts at a serve clip
        now = answer_generating(client, s)
        clip = now["clip"]
        assert is_generated(clip["rollout_id"]) and clip["generated"] is True and clip["ready"] is True
        assert clip["url"] == f"/api/clips/toy/{clip['rollout_id']}.mp4" and set(clip["measured"]) == {"amplitude",
                                                                                                      "pace"}
        assert compute.jobs[-1].rollout.id == clip["rollout_id"]  # the step asked for its render at once

        r = client.get(clip["url"])
        assert r.status_code == 200 and r.headers["content-type"] == "video/mp4", r.text
        assert r.content == InProcessCompute.CLIP
        assert client.get(clip["url"], headers={"If-None-Match": r.headers["etag"]}).status_code == 304
        st = client.get(clip["url"].replace(".mp4", "/status"))
        assert st.status_code == 200 and st.json()["state"] == "ready"

        later = answer_generating(client, now, "pace", "more")
        assert later["history"][1]["rollout_before"] == {**clip, "ready": True}  # marked generated in the history
        assert later["history"][0]["rollout_after"] == clip["rollout_id"]
        r = client.post(f"/api/sessions/{s['id']}/feedback", json={"step": later["step"], "satisfied": True})
        assert r.status_code == 200 and r.json()["status"] == "satisfied", r.text  # choosing searches nothing

        r = client.get(f"/api/sessions/{s['id']}/export")
        assert r.status_code == 200 and r.headers["content-type"] == "application/zip", r.text
    (tmp_path / "export.zip").write_bytes(r.content)
    export = read_export(tmp_path / "export.zip")
    profile = export.profile
    chosen = later["clip"]
    assert profile.rollout_id == chosen["rollout_id"] == generated_id("toy", profile.params, profile.seed)
    assert profile.proxies == chosen["measured"] and export.clip == InProcessCompute.CLIP
    assert profile.reward is not None and profile.zeta is not None
    assert replay(tmp_path / "export.zip").matches  # its params and seed remake it
    cli = export_to_file(s["id"], tmp_path / "cli.zip", gen_settings.model_copy(
        update={"cache_dir": tmp_path / "cli-clips"}))  # `rba export`: remade and rendered in this process
    assert cli.rollout_id == profile.rollout_id and cli.params == profile.params and cli.seed == profile.seed
    clip = read_export(tmp_path / "cli.zip").clip
    assert clip[4:8] == b"ftyp"  # a real MP4 this time: the bytes the app's compute layer renders for that key
    key = ClipKey("toy", MADE, profile.rollout_id, gen_settings.clip_width, gen_settings.clip_height, CLIP_PARTS)
    made = cma.replay("toy", profile.params, profile.seed)  # the clip's rollout, remade
    assert clip == local_compute.render(render_job(key, made)).future.result(SEARCH_SECONDS)


def test_a_search_on_the_surface_makes_its_clip_in_one_generation(gen_settings, monkeypatch):
    """A domain with a ζσ surface (``Domain.zeta_surface``): the app's search solves it and simulates once."""
    monkeypatch.setattr(Toy, "zeta_surface", 16)
    with TestClient(create_app(gen_settings, InProcessCompute())) as client:
        s = client.post("/api/sessions", json={"domain": "toy"}).json()
        r = client.post(f"/api/sessions/{s['id']}/feedback", json=more("amplitude", s["step"], "less",
                                                                       clip=s["clip"]["rollout_id"]))
        assert r.status_code == 202, r.text
        progress = search_done(client, s["id"])
        assert progress["state"] == "done" and progress["generation"] == progress["generations"] == 1
        svc = client.app.state.services
        with Session(svc.engine) as db:  # a new search starts at generation 0 of 1, not of CMA-ES's 6
            started = begin(svc, load_session(db, s["id"]))
        assert (started.generation, started.generations) == (0, 1)
        clip = client.get(f"/api/sessions/{s['id']}").json()["clip"]
        assert is_generated(clip["rollout_id"]) and clip["generated"] is True and clip["ready"] is True


def test_by_default_a_first_answer_shows_a_serve_clip_at_once(gen_settings):
    """The default ``generate_spread``: while the belief is wide, a serve clip near its median asks as well."""
    assert Settings().generate_spread is None  # the domain's own default (Domain.generate_spread)
    default = gen_settings.model_copy(update={"generate_spread": None})
    with TestClient(create_app(default, InProcessCompute())) as client:
        s = client.post("/api/sessions", json={"domain": "toy"}).json()
        r = client.post(f"/api/sessions/{s['id']}/feedback", json=more("amplitude", s["step"], "less",
                                                                       clip=s["clip"]["rollout_id"]))
        assert r.status_code == 200 and r.json()["clip"]["generated"] is False, r.text
        assert r.json()["step"] == s["step"] + 1 and r.json()["generation"] is None


def first_search(settings: Settings) -> dict:
    """The progress of the search a toy session's first answer starts, on a compute layer taking 0.3 s a job."""
    with TestClient(create_app(settings, InProcessCompute(delay=0.3))) as client:
        s = client.post("/api/sessions", json={"domain": "toy"}).json()
        r = client.post(f"/api/sessions/{s['id']}/feedback", json=more("amplitude", s["step"], "less",
                                                                       clip=s["clip"]["rollout_id"]))
        assert r.status_code == 202, r.text
        return search_done(client, s["id"])


def test_a_search_stops_at_its_seconds(gen_settings):
    """``generate_seconds``: no generation starts that would end after it (the first is cut short once a
    candidate arrived late: rba.generate.cma's own tests)."""
    for bad in ("0", "inf", "nan"):
        with pytest.raises(ValidationError, match="generate_seconds"):
            Settings(generate_seconds=bad)
    for bad in ("-1", "inf", "nan"):  # an infinite spread would turn generation off without a word
        with pytest.raises(ValidationError, match="generate_spread"):
            Settings(generate_spread=bad)
    bounded = gen_settings.model_copy(update={"generate_seconds": 0.2})
    assert bounded.search_seconds("walker") == bounded.search_seconds("snake") == 0.2  # one value bounds every domain
    progress = first_search(bounded)
    assert progress["state"] == "done" and (progress["generation"], progress["generations"]) == (1, 6)
    assert progress["seconds_at_most"] == 0.2  # the page's progress runs against it


def test_each_domain_has_its_own_default_bound(gen_settings, monkeypatch):
    """Unset, a search's bound is its domain's ``Domain.generate_seconds``, chosen on val (docs/decisions/0005;
    tests/server/test_app_settings.py): the walker and the manipulator 1 s, the snake 1.25 s, others 2 s."""
    assert Settings.model_fields["generate_seconds"].default is None
    default = Settings(generate_seconds=None)
    assert [default.search_seconds(d) for d in ("walker", "manipulator", "snake")] == [1.0, 1.0, 1.25]
    assert default.search_seconds("toy") == Toy.generate_seconds == 2.0
    monkeypatch.setattr(Toy, "generate_seconds", 0.2)  # the catalog asks the settings per domain
    unset = gen_settings.model_copy(update={"generate_seconds": None})
    progress = first_search(unset)
    assert progress["seconds_at_most"] == 0.2 and progress["generation"] == 1


def test_refusals_name_what_is_valid(gen_settings):
    with TestClient(create_app(gen_settings, InProcessCompute(delay=0.5))) as client:
        r = client.post("/api/sessions", json={"domain": "toy", "method": "local", "generate": True})
        assert r.status_code == 422
        assert r.json()["detail"] == ("method 'local' cannot generate behaviours; valid with generate: global "
                                      "(or leave generate out)")
        r = client.post("/api/sessions", json={"domain": "toy", "generate": "yes"})
        assert r.status_code == 422 and r.json()["errors"][0]["loc"] == ["body", "generate"]
        plain = client.post("/api/sessions", json={"domain": "toy", "generate": False}).json()
        assert plain["generate"] is False
        r = client.post(f"/api/sessions/{plain['id']}/feedback", json=more("amplitude", 0, "less"))
        assert r.status_code == 200 and not r.json()["clip"]["generated"], r.text  # a library clip, at once
        r = client.get(f"/api/sessions/{plain['id']}/generation")
        assert r.status_code == 404
        assert r.json()["detail"].startswith(f"session {plain['id']} has no search in this server")
        r = client.get("/api/clips/toy/gen-0000000000000000.mp4")
        assert r.status_code == 404
        assert r.json()["detail"].startswith("unknown generated rollout id 'gen-0000000000000000' in toy")
        assert client.get("/api/clips/toy/gen-0000000000000000/status").status_code == 404

        s = client.post("/api/sessions", json={"domain": "toy"}).json()
        r = client.post(f"/api/sessions/{s['id']}/feedback", json=more("amplitude", 0, "less"))
        assert r.status_code == 202, r.text
        again = client.post(f"/api/sessions/{s['id']}/feedback", json=more("pace", 0, "more"))
        assert again.status_code == 409
        assert again.json()["detail"].startswith(f"session {s['id']} is still making a new behaviour for step 0")
        assert client.get(f"/api/sessions/{s['id']}").json()["generation"]["state"] == "searching"
        assert client.post(f"/api/sessions/{s['id']}/abandon").status_code == 200
        progress = search_done(client, s["id"])
        assert progress["state"] == "failed"
        assert progress["detail"] == f"session {s['id']} is abandoned; it takes no more feedback (start a new session)"


@pytest.mark.parametrize("refit", [False, True], ids=["zeta", "zeta-refit"])
def test_a_session_showing_a_generated_clip_continues_after_a_restart(gen_settings, tmp_path, monkeypatch, refit):
    """Also with ζσ re-fitted on the session's answers (``Domain.session_refit``, here from the first answer on): the
    restored session fits the same heads from its stored answers."""
    monkeypatch.setattr(Toy, "session_refit", refit)
    monkeypatch.setattr(generating_agent, "REFIT_AFTER", 1)
    fits, fit = [], generating_agent.refit_heads
    monkeypatch.setattr(generating_agent, "refit_heads", lambda *args: fits.append(len(args[1])) or fit(*args))
    with TestClient(create_app(gen_settings, InProcessCompute())) as first:
        s = first.post("/api/sessions", json={"domain": "toy"}).json()
        shown = answer_generating(first, s)
    compute = InProcessCompute()
    cold = gen_settings.model_copy(update={"cache_dir": tmp_path / "cold-clips"})  # nor a clip on disk
    with TestClient(create_app(cold, compute)) as second:  # nothing in memory: the database only
        again = second.get(f"/api/sessions/{s['id']}").json()
        assert again == {**shown, "clip": {**shown["clip"], "ready": False}} and again["clip"]["generated"]
        r = second.get(again["clip"]["url"])
        assert r.status_code == 200 and r.content == InProcessCompute.CLIP
        assert compute.batches == 1 and compute.jobs[-1].rollout.id == again["clip"]["rollout_id"]  # simulated again
        after = answer_generating(second, again, "pace", "more")
        other = second.post("/api/sessions", json={"domain": "toy"}).json()  # the same answers, never restarted
        other = answer_generating(second, other)  # this process never made that step: it searches
        r = second.post(f"/api/sessions/{other['id']}/feedback", json=more("pace", other["step"], "more",
                                                                             clip=other["clip"]["rollout_id"]))
        assert r.status_code == 200, r.text  # the restored session made this step here: equal states, the memo's
        other = r.json()
        assert other["clip"]["rollout_id"] == after["clip"]["rollout_id"]
        assert [h["rollout_before"]["rollout_id"] for h in after["history"]] == \
               [h["rollout_before"]["rollout_id"] for h in other["history"]]
        with Session(second.app.state.services.engine) as db:
            answered = db.get(TuningSession, s["id"]).agent_state["generation"]["answered"]
        assert [rid for rid, _ in answered] == ([h["rollout_before"]["rollout_id"] for h in after["history"]]
                                                if refit else [])
    assert bool(fits) == refit  # the heads were fitted on the answers, and only with the re-fit


def test_a_restored_refit_session_remakes_its_clip_without_it_counting_as_a_search(gen_settings, tmp_path,
                                                                                   monkeypatch):
    """After a restart a re-fitting session's next step simulates its made clips again for ζσ's features: a guess
    (no search allowed) may do that, and only a real search makes it ``WouldSearch``."""
    monkeypatch.setattr(Toy, "session_refit", True)
    monkeypatch.setattr(generating_agent, "REFIT_AFTER", 1)
    with TestClient(create_app(gen_settings, InProcessCompute())) as first:
        s = first.post("/api/sessions", json={"domain": "toy"}).json()
        answer_generating(first, s)
    compute = InProcessCompute()
    with TestClient(create_app(gen_settings.model_copy(update={"prerender": False}), compute)) as second:
        svc = second.app.state.services
        with Session(svc.engine) as db:
            state = db.get(TuningSession, s["id"]).agent_state
        guess = step_context(svc, ("toy", "global", "onehot", BUILTIN_VERSION), None)
        try:
            svc.transitions.advance(guess, GENERATING, state, [AttributeFeedback("pace", 1)])
        except WouldSearch as would:
            assert would.fallback is not None  # a search the step would start, not the clip made again
        made = state["generation"]
        assert compute.batches == len(made["generated"]) + len(made["pool"]) > 1  # each made clip, for its features


def fallback_of(client: TestClient, sid: str) -> str:
    """The serve clip the session's last step showed or, when it showed a made clip, would have fallen back to."""
    svc = client.app.state.services
    with Session(svc.engine) as db:
        state = db.get(TuningSession, sid).agent_state
    return svc.catalog.context("toy", "global", "onehot", BUILTIN_VERSION).serve.ids[state["shown"]]


def test_guesses_never_search_but_render_the_clip_a_search_falls_back_to(gen_settings):
    """Prerendering works out a generating session's next clips too: an answer that would search never searches
    as a guess (``WouldSearch``, nothing memoised), but the serve clip its search would fall back to is among the
    first guesses, and rendered (the library and the shared trees are not prerendered here: only the session's
    next clips are)."""
    compute = InProcessCompute()
    only_next = {"prerender": True, "prerender_library": False, "prerender_tree_min_share": 1.0}
    with TestClient(create_app(gen_settings.model_copy(update=only_next), compute)) as client:
        s = client.post("/api/sessions", json={"domain": "toy"}).json()
        svc = client.app.state.services
        assert svc.wait_idle(SEARCH_SECONDS)
        assert compute.batches == 0 and svc.thinker.failed == 0 and svc.thinker.done >= 1
        assert compute.jobs and not any(is_generated(j.rollout.id) for j in compute.jobs)  # the serve clips only
        with Session(svc.engine) as db:
            state = db.get(TuningSession, s["id"]).agent_state
        key = ("toy", "global", "onehot", BUILTIN_VERSION)
        guessed = next_clips(svc, key, True, state, None, lambda: False)  # what the thinker queued first
        misses = svc.transitions.misses
        with pytest.raises(WouldSearch) as would:
            svc.transitions.advance(step_context(svc, key, None), GENERATING, state, [AttributeFeedback("amplitude",
                                                                                                      -1)])
        assert svc.transitions.misses == misses  # nothing memoised: the real answer runs the step (and searches)
        rendered = [j.rollout.id for j in compute.jobs]
        answer_generating(client, s)  # the real answer still searches
        assert compute.batches >= 1
        assert would.value.fallback == fallback_of(client, s["id"])
        assert would.value.fallback in guessed and would.value.fallback in rendered


def test_a_search_renders_its_fallback_beside_it(gen_settings):
    """Without prerendering, the serve clip a search would fall back to is asked for, urgently, before its first
    simulation: a search that falls short does not leave the person waiting for a render."""
    compute = InProcessCompute()
    at_first_simulation = []
    simulate = compute.simulate
    compute.simulate = lambda jobs: at_first_simulation.append(len(compute.jobs)) or simulate(jobs)
    with TestClient(create_app(gen_settings, compute)) as client:
        s = client.post("/api/sessions", json={"domain": "toy"}).json()
        before = len(compute.jobs)
        now = answer_generating(client, s)
        assert is_generated(now["clip"]["rollout_id"])
        made = now["clip"]["rollout_id"]
        assert [j.rollout.id for j in compute.jobs[before:]] == [fallback_of(client, s["id"]), made]
        assert [urgent for urgent, _ in compute.submitted[before:]] == [True, True]
        assert at_first_simulation[0] == before + 1  # asked for before the search simulated anything


class HoldsGeneratedRenders(InstantCompute):
    """Serve clips render at once; a generated clip's render waits until the test finishes it."""

    def render(self, job, urgent=True):
        return FakeCompute.render(self, job, urgent) if is_generated(job.rollout.id) else super().render(job, urgent)


def test_a_generating_answer_guesses_the_next_clips_only_once_its_clip_is_rendered(gen_settings):
    """Working out the next answers' clips beside the render of the clip someone waits for slowed it: the step
    drops its old guesses, and the new ones are scheduled when the clip is stored. Meanwhile no guess starts."""
    renders = HoldsGeneratedRenders()
    with TestClient(create_app(gen_settings.model_copy(update={"prerender": True}),
                               InProcessCompute(renders=renders))) as client:
        svc = client.app.state.services
        s = client.post("/api/sessions", json={"domain": "toy"}).json()
        assert svc.wait_idle(SEARCH_SECONDS) and svc.prerendering[s["id"]] == s["step"]
        now = answer_generating(client, s)
        made = now["clip"]["rollout_id"]
        rendering = [j.rollout.id for j in renders.jobs]  # the search's fallback is asked for beside it, either order
        assert is_generated(made) and made in rendering  # its render, held
        thought = svc.thinker.done
        time.sleep(0.3)  # the thinker would have started at once
        assert svc.someone_waits() and svc.thinker.done == thought  # the clip renders alone
        assert svc.prerendering[s["id"]] == now["step"]  # scheduled, so reading the session does not start it
        renders.submitted[rendering.index(made)][1].set_result(InstantCompute.CLIP)
        assert svc.thinker.wait_idle(SEARCH_SECONDS) and svc.thinker.done == thought + 1 and not svc.someone_waits()
        assert client.get(now["clip"]["url"]).content == InstantCompute.CLIP


def test_a_runner_up_the_next_answer_would_show_is_rendered_ahead(gen_settings, tmp_path):
    """A made clip an answer would show without a search (a pooled runner-up) is among that session's guesses and
    rendered ahead, so the answer that shows it asks for no render; chosen, it is exported and replays. The session's
    pool is set so that one of its clips sits at the target "more pace" leads to: the toy's searches reach their
    targets, so a runner-up is near a later target only by chance."""
    compute = InProcessCompute()
    only_next = {"prerender": True, "prerender_library": False, "prerender_tree_min_share": 1.0}
    answer = [AttributeFeedback("pace", 1)]
    with TestClient(create_app(gen_settings.model_copy(update=only_next), compute)) as client:
        svc = client.app.state.services
        s = answer_generating(client, client.post("/api/sessions", json={"domain": "toy"}).json())
        assert svc.wait_idle(SEARCH_SECONDS)
        key = ("toy", "global", "onehot", BUILTIN_VERSION)
        with Session(svc.engine) as db:
            row = db.get(TuningSession, s["id"])
            pooled = next(iter(row.agent_state["generation"]["pool"]))
            row.agent_state = at_next_target(svc, key, row.agent_state, pooled, answer)
            db.add(row)
            db.commit()
            state = row.agent_state
        assert pooled in next_clips(svc, key, True, state, None, lambda: False)  # a guess that searches nothing

        svc.prerendering.pop(s["id"])  # the session's guesses again, from the state set above
        with Session(svc.engine) as db:
            resume_prerender(svc, load_session(db, s["id"]))
        assert svc.wait_idle(SEARCH_SECONDS)
        assert [urgent for j, (urgent, _) in zip(compute.jobs, compute.submitted, strict=True)
                if j.rollout.id == pooled] == [False]  # rendered once, as a guess
        renders = len(compute.jobs)
        r = client.post(f"/api/sessions/{s['id']}/feedback", json=more("pace", s["step"], clip=s["clip"]["rollout_id"]))
        assert r.status_code == 200, r.text  # no search: the clip was made by the first one
        clip = r.json()["clip"]
        assert clip["rollout_id"] == pooled and clip["generated"] is True and clip["ready"] is True
        assert pooled not in [j.rollout.id for j in compute.jobs[renders:]]  # its render was there already
        with pytest.raises(LookupError, match="no longer in memory"):  # a guess never simulates a forgotten clip
            svc.prefetch.resolve(ClipRef("toy", generated_id("toy", {"amplitude": 0.5}, 0)))

        r = client.post(f"/api/sessions/{s['id']}/feedback", json={"step": s["step"] + 1, "satisfied": True})
        assert r.status_code == 200 and r.json()["status"] == "satisfied", r.text
        r = client.get(f"/api/sessions/{s['id']}/export")  # a pooled clip leaves the app as any made clip does
        assert r.status_code == 200, r.text
    (tmp_path / "pooled.zip").write_bytes(r.content)
    assert read_export(tmp_path / "pooled.zip").profile.rollout_id == pooled
    assert replay(tmp_path / "pooled.zip").matches


def at_next_target(svc, key, state: dict, pooled: str, answer) -> dict:
    """``state`` with the pooled clip ``pooled`` read at the target ``answer`` leads to (so that answer shows it)."""
    gctx = step_context(svc, key, None)
    probe = GeneratingGlobalAgent.from_state(copy.deepcopy(state), gctx)
    with pytest.raises(WouldSearch):  # as the state stands, that answer searches
        probe.update(answer)
    state = copy.deepcopy(state)
    state["generation"]["pool"][pooled]["zeta"] = [float(v) for v in probe.inner.target]
    return state



def test_a_saved_step_is_done_even_if_rendering_ahead_fails(gen_settings, monkeypatch):
    """Once the step is saved the search has ended well: a render request that fails afterwards is logged, not
    reported as a failed search the page would answer again for (and get a 409: the session moved on)."""
    with TestClient(create_app(gen_settings, InProcessCompute())) as client:
        svc = client.app.state.services
        s = client.post("/api/sessions", json={"domain": "toy"}).json()
        asked = svc.clips.request

        def fail_once(key, *args, **kwargs):
            if not is_generated(key.rollout_id):  # the search's fallback, asked for before it simulates
                return asked(key, *args, **kwargs)
            monkeypatch.setattr(svc.clips, "request", asked)
            raise RuntimeError("the render queue is gone")

        monkeypatch.setattr(svc.clips, "request", fail_once)
        now = answer_generating(client, s)  # the search reports done, the session is at its next step
        assert svc.clips.request is asked  # the failing request ran (after the step was saved)
        r = client.get(now["clip"]["url"])  # the page's own request renders it
        assert r.status_code == 200 and r.content == InProcessCompute.CLIP, r.text
