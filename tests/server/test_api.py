"""Every route: success, not found, invalid input and stale steps, with the error text checked."""

from __future__ import annotations

import pytest

from rba.core.methods import get_method, trainable
from rba.domains import domain_names, get_domain
from rba.learn.embed import REPRESENTATIONS
from server.ops.views import method_public
from server.runtime.catalog import attribute_methods
from tests.server.conftest import more

# -- domains ---------------------------------------------------------------------------------

def test_domains_lists_attributes_and_available_models(client):
    r = client.get("/api/domains")
    assert r.status_code == 200
    body = r.json()
    toy = next(d for d in body["domains"] if d["name"] == "toy")
    assert [a["name"] for a in toy["attributes"]] == ["amplitude", "pace"]
    assert toy["attributes"][0] == {"name": "amplitude", "description": "How far the dot swings from side to side.",
                                    "unit": "m", "low": None, "high": None, "decimals": 2, "reading": None}
    assert [(m["method"], m["rep"]) for m in toy["available"]] == [("global", "onehot")]  # only these were trained
    assert toy["missing"] is None
    walker = next(d for d in body["domains"] if d["name"] == "walker")
    assert walker["available"] == [] and "run `rba build walker`" in walker["missing"]
    views = {d["name"]: d["states"] for d in body["domains"]}  # the page lists the research views apart
    assert (views["toy"], views["walker"], views["walker_raw"], views["lane_change_image"]) == (
        "features", "features", "raw", "image")
    assert body["methods"] == list(attribute_methods()) and body["reps"] == list(REPRESENTATIONS)
    assert body["trainable"] == [{"method": m.name, "label": m.label, "presets": list(m.presets)} for m in trainable()]
    assert [m["method"] for m in body["trainable"]] == ["global", "local"]  # PbRL learns online: nothing to train


def test_domains_carry_descriptions_and_mark_research_choices_advanced(client):
    """The page's picker shows each domain and method with its one line, the research views and representations
    behind "Advanced": the lines come from the definitions, and the listing still has every name (the API and the
    CLI take them all)."""
    body = client.get("/api/domains").json()
    by_name = {d["name"]: d for d in body["domains"]}
    assert set(by_name) == set(domain_names())
    for name, d in by_name.items():
        assert d["description"] == get_domain(name).summary and d["description"]
        assert d["advanced"] == (d["states"] != "features")
    assert sorted(n for n, d in by_name.items() if not d["advanced"]) == [
        "lane_change", "manipulator", "snake", "toy", "walker"]
    assert by_name["walker_raw"]["description"].startswith(by_name["walker"]["description"] + " Research view:")
    assert by_name["toy"]["available"] == [{"method": "global", "rep": "onehot", "label": "RBA-Global",
                                            "description": get_method("global").description, "advanced": False}]
    language = method_public("local", "language")
    assert language.advanced and language.label == "RBA-Local"
    assert language.description.startswith(get_method("local").description + " Research variant:")
    assert all(get_method(m).description for m in ("global", "local", "pbrl"))


# -- creating and reading sessions -----------------------------------------------------------------

def test_create_session_returns_the_first_clip(client, session):
    assert session["status"] == "active" and session["step"] == 0 and session["history"] == []
    assert (session["domain"], session["method"], session["rep"]) == ("toy", "global", "onehot")
    clip = session["clip"]
    assert clip["rollout_id"].startswith("serve-")
    assert clip["url"] == f"/api/clips/toy/{clip['rollout_id']}.mp4"
    assert set(clip["measured"]) == {"amplitude", "pace"}
    assert session["model_version"]
    assert session["created_at"].endswith("Z")
    amp = session["attributes"][0]
    assert amp["low"] < clip["measured"]["amplitude"] < amp["high"]
    assert client.get(f"/api/sessions/{session['id']}").json() == session


@pytest.mark.parametrize(("body", "message"), [
    ({"domain": "atlantis"}, "unknown domain 'atlantis'; valid: walker, lane_change"),
    ({"domain": "toy", "method": "magic"}, f"unknown method 'magic'; valid: {', '.join(attribute_methods())}"),
    ({"domain": "toy", "rep": "braille"}, "unknown rep 'braille'; valid: onehot, language"),
    ({"domain": "toy", "rep": "language"}, "no trained global/language models for toy; available: global/onehot"),
    ({"domain": "walker"}, "no trained global/onehot models for walker; available: none (no skill library"),
    ({}, "domain: Field required"),
    ({"domain": 3}, "domain: Input should be a valid string"),
])
def test_create_session_rejects_bad_bodies(client, body, message):
    r = client.post("/api/sessions", json=body)
    assert r.status_code == 422
    assert message in r.json()["detail"]


def test_malformed_json_is_422_with_a_reason(client):
    r = client.post("/api/sessions", content=b"{nope", headers={"Content-Type": "application/json"})
    assert r.status_code == 422
    assert "JSON decode error" in r.json()["detail"]


def test_unknown_session_is_404(client):
    for method, path, body in [("get", "/api/sessions/nope", None),
                               ("post", "/api/sessions/nope/feedback", more("pace", 0)),
                               ("post", "/api/sessions/nope/abandon", None)]:
        r = client.request(method.upper(), path, json=body)
        assert r.status_code == 404, path
        assert r.json()["detail"] == "no session 'nope'; create one with POST /api/sessions"


# -- feedback ------------------------------------------------------------------------------------

def test_feedback_moves_to_a_new_clip_and_records_history(client, session):
    sid, first = session["id"], session["clip"]
    r = client.post(f"/api/sessions/{sid}/feedback", json=more("amplitude", 0))
    assert r.status_code == 200, r.text
    s = r.json()
    assert s["step"] == 1 and s["status"] == "active"
    assert s["clip"]["rollout_id"] != first["rollout_id"]
    assert s["clip"]["measured"]["amplitude"] > first["measured"]["amplitude"]  # the toy model ranks well
    [h] = s["history"]
    assert h["step"] == 0 and h["satisfied"] is False
    assert h["feedback"] == [{"attribute": "amplitude", "direction": "more"}]
    assert h["rollout_before"]["rollout_id"] == first["rollout_id"] and h["rollout_after"] == s["clip"]["rollout_id"]
    r = client.post(f"/api/sessions/{sid}/feedback", json={"step": 1, "feedback": [
        {"attribute": "pace", "direction": "less"}, {"attribute": "amplitude", "direction": "more"}]})
    assert r.status_code == 200 and r.json()["step"] == 2
    assert client.get(f"/api/sessions/{sid}").json()["history"][1]["feedback"][0] == {"attribute": "pace",
                                                                                       "direction": "less"}


@pytest.mark.parametrize("step", [1, 7])
def test_feedback_for_another_step_is_409(client, session, step):
    r = client.post(f"/api/sessions/{session['id']}/feedback", json=more("pace", step))
    assert r.status_code == 409
    assert r.json()["detail"] == (f"step {step} is stale: session {session['id']} is at step 0; "
                                  "GET the session and answer about the clip it shows now")


def test_an_answer_about_a_clip_no_longer_shown_is_409(client, session):
    """A second press made before the new clip was shown names the old clip: refused, saying which is shown."""
    sid, first = session["id"], session["clip"]["rollout_id"]
    r = client.post(f"/api/sessions/{sid}/feedback", json=more("pace", 0, clip=first))
    assert r.status_code == 200, r.text
    now = r.json()["clip"]["rollout_id"]
    assert now != first
    r = client.post(f"/api/sessions/{sid}/feedback", json=more("pace", 1, clip=first))
    assert r.status_code == 409
    assert r.json()["detail"] == (f"the answer is about clip {first} but session {sid} now shows clip {now}; "
                                  "watch that clip and answer about it")
    r = client.post(f"/api/sessions/{sid}/feedback", json={"step": 1, "clip": first, "satisfied": True})
    assert r.status_code == 409 and f"now shows clip {now}" in r.json()["detail"]
    s = client.get(f"/api/sessions/{sid}").json()
    assert s["step"] == 1 and s["status"] == "active" and len(s["history"]) == 1


def test_session_shows_the_agents_target_interval_in_measured_values(client, session):
    """RBA-Global's belief, as measured values inside the library's range; an answer narrows it."""
    before = {t["attribute"]: t for t in session["target"]}
    ranges = {a["name"]: (a["low"], a["high"]) for a in session["attributes"]}
    assert set(before) == {"amplitude", "pace"}
    for name, t in before.items():
        assert ranges[name][0] <= t["low"] < t["high"] <= ranges[name][1]
    shown = session["clip"]["measured"]["pace"]
    after = client.post(f"/api/sessions/{session['id']}/feedback",
                        json=more("pace", 0, clip=session["clip"]["rollout_id"])).json()
    moved = next(t for t in after["target"] if t["attribute"] == "pace")
    assert moved["high"] - moved["low"] < before["pace"]["high"] - before["pace"]["low"]
    assert moved["high"] > shown  # "more pace" than the clip shown: the belief lies above it


def test_repeating_an_answer_is_409_not_a_second_step(client, session):
    sid = session["id"]
    assert client.post(f"/api/sessions/{sid}/feedback", json=more("pace", 0)).status_code == 200
    r = client.post(f"/api/sessions/{sid}/feedback", json=more("pace", 0))
    assert r.status_code == 409 and "stale" in r.json()["detail"]
    assert client.get(f"/api/sessions/{sid}").json()["step"] == 1


@pytest.mark.parametrize(("body", "message"), [
    ({"step": 0, "feedback": [{"attribute": "pace", "direction": "up"}]},
     "feedback.0.direction: Input should be 'more' or 'less'"),
    ({"step": 0, "feedback": [{"attribute": "speed", "direction": "more"}]},
     "unknown attribute 'speed' for toy; valid: amplitude, pace; directions: more, less"),
    ({"step": 0, "feedback": []}, "give 'feedback': [{'attribute': ..., 'direction': 'more' | 'less'}] or 'satisfied'"),
    ({"step": 0}, "give 'feedback'"),
    ({"step": 0, "satisfied": True, "feedback": [{"attribute": "pace", "direction": "more"}]},
     "give either 'feedback' or 'satisfied': true, not both"),
    ({"step": 0, "feedback": [{"attribute": "pace", "direction": "more"}, {"attribute": "pace", "direction": "less"}]},
     "attribute 'pace' appears more than once"),
    ({"step": -1, "satisfied": True}, "step: Input should be greater than or equal to 0"),
    ({"feedback": [{"attribute": "pace", "direction": "more"}]}, "step: Field required"),
    ({"step": 0, "feedback": [{"direction": "more"}]}, "feedback.0.attribute: Field required"),
])
def test_invalid_feedback_is_422_naming_the_valid_values(client, session, body, message):
    r = client.post(f"/api/sessions/{session['id']}/feedback", json=body)
    assert r.status_code == 422
    assert message in r.json()["detail"]
    assert client.get(f"/api/sessions/{session['id']}").json()["step"] == 0  # nothing half-written


def test_satisfied_closes_the_session(client, session):
    sid = session["id"]
    r = client.post(f"/api/sessions/{sid}/feedback", json={"step": 0, "satisfied": True})
    assert r.status_code == 200
    s = r.json()
    assert s["status"] == "satisfied" and s["step"] == 1
    assert s["clip"]["rollout_id"] == session["clip"]["rollout_id"]  # the chosen behaviour stays on screen
    assert s["history"][-1]["satisfied"] is True and s["history"][-1]["feedback"] is None
    r = client.post(f"/api/sessions/{sid}/feedback", json=more("pace", 1))
    assert r.status_code == 409
    assert r.json()["detail"] == f"session {sid} is satisfied; it takes no more feedback (start a new session)"
    r = client.post(f"/api/sessions/{sid}/abandon")
    assert r.status_code == 409
    assert r.json()["detail"] == f"session {sid} is satisfied already; only active sessions can be abandoned"


def test_abandon(client, session):
    sid = session["id"]
    r = client.post(f"/api/sessions/{sid}/abandon")
    assert r.status_code == 200 and r.json()["status"] == "abandoned"
    r = client.post(f"/api/sessions/{sid}/feedback", json=more("pace", 0))
    assert r.status_code == 409 and "is abandoned" in r.json()["detail"]


# -- clips ---------------------------------------------------------------------------------------

def test_clip_is_an_mp4_with_etag_and_ranges(client, session):
    url = session["clip"]["url"]
    r = client.get(url)
    assert r.status_code == 200
    assert r.headers["content-type"] == "video/mp4"
    assert r.content[4:8] == b"ftyp"
    assert r.content.find(b"moov") < r.content.find(b"mdat")  # faststart: playable while downloading
    etag = r.headers["etag"]
    assert r.headers["accept-ranges"] == "bytes"
    again = client.get(url, headers={"If-None-Match": etag})
    assert again.status_code == 304 and again.content == b""
    part = client.get(url, headers={"Range": "bytes=0-99"})
    assert part.status_code == 206
    assert part.headers["content-range"] == f"bytes 0-99/{len(r.content)}"
    assert part.content == r.content[:100]
    tail = client.get(url, headers={"Range": "bytes=-50"})
    assert tail.status_code == 206 and tail.content == r.content[-50:]
    bad = client.get(url, headers={"Range": f"bytes={len(r.content) + 10}-"})
    assert bad.status_code == 416
    head = client.head(url)
    assert head.status_code == 200 and head.headers["etag"] == etag
    assert client.get(f"/api/sessions/{session['id']}").json()["clip"]["ready"] is True


@pytest.mark.parametrize(("path", "message"), [
    ("/api/clips/toy/serve-99999.mp4", "unknown rollout id 'serve-99999' in toy/serve; ids look like serve-00000"),
    ("/api/clips/toy/..%5C..%5Cetc%5Cpasswd.mp4", r"unknown rollout id '..\\..\\etc\\passwd' in toy/serve"),
    ("/api/clips/toy/..%2F..%2Fetc%2Fpasswd.mp4", "no API route /api/clips/toy/../../etc/passwd.mp4"),
    ("/api/clips/toy/train-00001.mp4", "unknown rollout id 'train-00001' in toy/serve"),
    ("/api/clips/walker/serve-00001.mp4", "no serve library for 'walker'"),
])
def test_unknown_clips_are_404(client, path, message):
    r = client.get(path)
    assert r.status_code == 404
    assert message in r.json()["detail"]


def test_clip_status_says_ready_once_rendered_and_404s_unknown_clips(client, session):
    rid = session["clip"]["rollout_id"]
    url = f"/api/clips/toy/{rid}/status"
    before = client.get(url)
    assert before.status_code == 200 and before.json()["state"] in {"absent", "queued", "rendering"}
    assert client.get(session["clip"]["url"]).status_code == 200
    after = client.get(url).json()
    assert after["rollout_id"] == rid and after["state"] == "ready" and after["typical_seconds"] > 0
    r = client.get("/api/clips/toy/serve-99999/status")
    assert r.status_code == 404
    assert r.json()["detail"] == "unknown rollout id 'serve-99999' in toy/serve; ids look like serve-00000"
    r = client.get("/api/clips/atlantis/serve-00001/status")
    assert r.status_code == 422 and "domain: unknown domain 'atlantis'; valid: walker" in r.json()["detail"]


def test_clip_of_an_unknown_domain_is_422_naming_the_domains(client):
    r = client.get("/api/clips/atlantis/serve-00001.mp4")
    assert r.status_code == 422
    assert "domain: unknown domain 'atlantis'; valid: walker, lane_change" in r.json()["detail"]


# -- the rest of the app -----------------------------------------------------------------------

def test_page_docs_and_unknown_routes(client):
    page = client.get("/")
    assert page.status_code == 200 and "RBA Studio" in page.text and "/static/app.js" in page.text
    assert client.get("/static/app.js").status_code == 200
    assert client.get("/static/app.css").status_code == 200
    icon = client.get("/favicon.ico")
    assert icon.status_code == 200 and icon.headers["content-type"].startswith("image/svg+xml")
    assert icon.content.startswith(b"<svg")
    assert client.get("/docs").status_code == 200
    spec = client.get("/openapi.json").json()
    assert {"/api/domains", "/api/sessions", "/api/sessions/{session_id}", "/api/sessions/{session_id}/feedback",
            "/api/sessions/{session_id}/abandon", "/api/clips/{domain}/{rollout_id}.mp4"} <= set(spec["paths"])
    r = client.get("/api/nothing/here")
    assert r.status_code == 404 and r.json()["detail"] == "no API route /api/nothing/here; see /docs for the routes"


def test_attributes_say_how_to_read_them_and_with_how_many_decimals():
    """Walker softness is minus a landing speed: shown as the speed; snake speed changes in the third decimal."""
    from rba.data.library import SkillLibrary
    from rba.domains import get_domain
    from server.db.tables import ReadingPublic
    from server.ops.views import attributes_public, epsilon_decimals, range_decimals

    walker = {a.name: a for a in attributes_public(get_domain("walker"))}
    assert walker["softness"].reading == ReadingPublic(label="landing speed", sign=-1, note="lower is softer")
    assert walker["step_size"].reading is None

    def fine(name: str) -> dict[str, int]:
        domain = get_domain(name)
        eps = domain.epsilons(SkillLibrary.load(name, "serve").proxies, "high")
        return {a: epsilon_decimals(e) for a, e in zip(domain.attribute_names, eps, strict=True)}

    assert fine("walker")["step_size"] == 2 and fine("snake")["speed"] == 3
    assert range_decimals(0.0, 0.08) == 3 and range_decimals(0.0, 50.0) == 0 and range_decimals(None, 1.0) == 2
