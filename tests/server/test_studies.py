"""Studies with people (docs/studies.md): the experimenter's routes, the participant's link, and the guarantees
between them: consent first, resuming, one participant never reaching another's trials or the admin API, withdrawal
removing their rows; the results equal those recomputed from the export of a study driven by simulated users.

Each route test runs on SQLite and on PostgreSQL (``database_url``).
"""

from __future__ import annotations

import csv
import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
import scipy.stats
from fastapi.testclient import TestClient
from sqlmodel import Session, select

from rba.data.library import SkillLibrary
from rba.domains import get_domain
from rba.interact import SATISFIED
from rba.interact.users import parse_user
from server.common.app_settings import Settings
from server.db.study_tables import Participant, StudyAnswer, StudyConfig, StudyTrial
from server.db.tables import TuningSession
from server.main import create_app
from server.ops import study_stats
from server.ops.studies import balanced_latin_square, plan
from server.ops.study_export import results_from_export
from server.runtime.catalog import Catalog

REPO = Path(__file__).resolve().parents[2]
TOKEN = "study-admin-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
CONFIG = {"name": "pilot", "domain": "toy", "conditions": [{"method": "global"}, {"method": "random"}],
          "targets_per_condition": 2, "answer_budget": 8, "consent_text": "I agree to take part.", "seed": 3}


@pytest.fixture
def client(make_settings, database_url):
    with TestClient(create_app(make_settings(database_url=database_url, admin_token=TOKEN))) as c:
        yield c


def make_study(c: TestClient, **changes) -> dict:
    r = c.post("/api/admin/studies", json={**CONFIG, **changes}, headers=AUTH)
    assert r.status_code == 201, r.text
    return r.json()


def make_links(c: TestClient, study_id: str, count: int) -> list[str]:
    r = c.post(f"/api/admin/studies/{study_id}/participants", json={"count": count}, headers=AUTH)
    assert r.status_code == 201, r.text
    return [p["token"] for p in r.json()["participants"]]


def consent(c: TestClient, token: str) -> dict:
    r = c.post(f"/api/participate/{token}/consent")
    assert r.status_code == 200, r.text
    return r.json()


def more(trial: dict, attribute: str = "pace", direction: str = "more", ms: int = 900, replays: int = 0) -> dict:
    return {"trial_id": trial["id"], "feedback": {"kind": "attribute",
                                                 "feedback": [{"attribute": attribute, "direction": direction}]},
            "ms": ms, "replays": replays}


def satisfied(trial: dict, ms: int = 700) -> dict:
    return {"trial_id": trial["id"], "feedback": {"kind": "satisfied"}, "ms": ms, "replays": 1}


def answer(c: TestClient, token: str, body: dict) -> dict:
    r = c.post(f"/api/participate/{token}/answer", json=body)
    assert r.status_code == 200, r.text
    return r.json()


def export(c: TestClient, study_id: str) -> zipfile.ZipFile:
    r = c.get(f"/api/admin/studies/{study_id}/export", headers=AUTH)
    assert r.status_code == 200 and r.headers["content-type"] == "application/zip", r.text
    return zipfile.ZipFile(io.BytesIO(r.content))


# -- setting up -----------------------------------------------------------------------------------

def test_create_list_read_and_draw_targets_from_the_test_split(client, toy_roots):
    study = make_study(client)
    config = study["config"]
    assert config["seed"] == 3 and [c["rep"] for c in config["conditions"]] == ["onehot", "onehot"]
    test_ids = set(SkillLibrary.load("toy", "test", toy_roots[0]).ids)
    first, second = config["targets"]  # every condition chases the same targets: a paired comparison is fair
    assert first == second and len(set(first)) == 2 and set(first) <= test_ids
    again = make_study(client)  # the same seed draws the same targets
    assert again["config"]["targets"] == config["targets"] and again["id"] != study["id"]
    listed = client.get("/api/admin/studies", headers=AUTH).json()
    assert {s["id"] for s in listed} == {study["id"], again["id"]}
    assert client.get(f"/api/admin/studies/{study['id']}", headers=AUTH).json()["config"] == config
    assert client.get("/api/admin/studies/nope", headers=AUTH).status_code == 404
    free = make_study(client, task="free", seed=None)
    assert free["config"]["targets"] == [[], []] and isinstance(free["config"]["seed"], int)


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_a_bad_configuration_is_a_422_saying_what_is_valid(client):
    cases = [
        ({"conditions": [{"method": "nope"}, {"method": "random"}]}, "unknown method 'nope'; valid: global"),
        ({"conditions": [{"method": "global"}, {"method": "oracle"}]}, "unknown method 'oracle'"),
        ({"conditions": [{"method": "pbrl"}, {"method": "random"}]}, "unknown method 'pbrl'"),
        ({"conditions": [{"method": "global"}]}, "at least 2 items"),
        ({"conditions": [{"method": "global"}, {"method": "global", "rep": "onehot"}]}, "repeat a method/rep pair"),
        ({"conditions": [{"method": "global", "rep": "words"}, {"method": "random"}]}, "unknown rep 'words'"),
        ({"conditions": [{"method": "local"}, {"method": "random"}]}, "no trained local/onehot models for toy"),
        ({"answer_budget": 0}, "greater than or equal to 1"),
        ({"targets_per_condition": 45}, "the test split of toy has 40 rollouts; ask for at most 40"),
        ({"precision": "exact"}, "'normal' or 'high'"),
        ({"task": "race"}, "'target' or 'free'"),
        ({"consent_text": ""}, "at least 1 character"),
        ({"domain": "atlantis"}, "unknown domain 'atlantis'"),
        ({"colour": "red"}, "Extra inputs are not permitted"),
    ]
    for change, said in cases:
        r = client.post("/api/admin/studies", json={**CONFIG, **change}, headers=AUTH)
        assert r.status_code == 422 and said in r.text, (change, r.text)
    assert client.get("/api/admin/studies", headers=AUTH).json() == []


def test_links_are_unguessable_and_stored_only_as_hashes(client):
    study = make_study(client)
    r = client.post(f"/api/admin/studies/{study['id']}/participants", json={"count": 3}, headers=AUTH)
    links = r.json()["participants"]
    assert [p["number"] for p in links] == [0, 1, 2] and all(p["link"] == f"/study/{p['token']}" for p in links)
    assert len({p["token"] for p in links}) == 3 and all(len(p["token"]) >= 32 for p in links)
    with Session(client.app.state.services.engine) as db:
        stored = db.exec(select(Participant)).all()
        trials = db.exec(select(StudyTrial)).all()
    assert {p.token_hash for p in stored}.isdisjoint(p["token"] for p in links)
    assert len(trials) == 3 * 4  # every participant's trials planned at once
    more_links = client.post(f"/api/admin/studies/{study['id']}/participants", json={"count": 1}, headers=AUTH)
    assert more_links.json()["participants"][0]["number"] == 3
    assert client.get(f"/api/admin/studies/{study['id']}", headers=AUTH).json()["participants"] == 4
    assert client.post(f"/api/admin/studies/{study['id']}/participants", json={"count": 0},
                       headers=AUTH).status_code == 422


# -- the participant ------------------------------------------------------------------------------

def test_consent_comes_first_and_the_link_resumes(client):
    study = make_study(client)
    token, = make_links(client, study["id"], 1)
    before = client.get(f"/api/participate/{token}").json()
    assert before["consented"] is False and before["trial"] is None and before["study"]["consent_text"] == \
        CONFIG["consent_text"]
    assert [a["name"] for a in before["study"]["attributes"]] == ["amplitude", "pace"]
    with Session(client.app.state.services.engine) as db:
        first = db.exec(select(StudyTrial).order_by(StudyTrial.position)).first()
    r = client.post(f"/api/participate/{token}/answer", json=more({"id": first.id}))
    assert r.status_code == 409 and "consent first" in r.json()["detail"]
    view = consent(client, token)
    assert consent(client, token)["trial"]["id"] == view["trial"]["id"]  # idempotent
    trial = view["trial"]
    assert trial["index"] == 0 and trial["of"] == 4 and trial["label"] == "Agent A" and trial["answers_used"] == 0
    assert trial["target"]["rollout_id"].startswith("test-") and trial["clip"]["rollout_id"].startswith("serve-")
    assert trial["clip"]["url"] == f"/api/clips/toy/{trial['clip']['rollout_id']}.mp4"
    assert trial["clip"]["data_url"] is None  # the toy's clips are MP4s only: no data URL that would 404
    target = client.get(f"/api/clips/toy/{trial['target']['rollout_id']}/status")  # the clip route serves targets
    assert target.status_code == 200 and client.get("/api/clips/toy/test-99999/status").status_code == 404
    assert "distance" not in str(view) and "success" not in str(view) and "method" not in str(view)
    moved = answer(client, token, more(trial, ms=1234, replays=2))
    resumed = client.get(f"/api/participate/{token}").json()
    assert resumed == moved and resumed["trial"]["answers_used"] == 1 and resumed["trial"]["id"] == trial["id"]


def test_a_trial_ends_satisfied_or_when_its_budget_is_spent(client):
    study = make_study(client, answer_budget=2)
    token, = make_links(client, study["id"], 1)
    trial = consent(client, token)["trial"]
    view = answer(client, token, more(trial))
    view = answer(client, token, more(view["trial"], direction="less"))
    assert view["trial"]["index"] == 1  # the budget is spent: the next trial
    view = answer(client, token, satisfied(view["trial"]))
    assert view["trial"]["index"] == 2
    with Session(client.app.state.services.engine) as db:
        ended = db.exec(select(StudyTrial).where(StudyTrial.ended.is_not(None)).order_by(StudyTrial.position)).all()
        sessions = {s.id: s.status for s in db.exec(select(TuningSession)).all()}
        answers = db.exec(select(StudyAnswer).order_by(StudyAnswer.id)).all()
    assert (ended[0].ended, ended[0].answers, ended[0].success) == ("budget", 2, False)
    assert ended[1].ended == "satisfied" and ended[1].answers == 0 and ended[1].distance is not None
    assert [sessions[t.session_id] for t in ended] == ["abandoned", "satisfied"]
    assert [(a.step, a.feedback == SATISFIED) for a in answers] == [(0, False), (1, False), (0, True)]
    assert answers[0].feedback == [{"attribute": "pace", "direction": "more"}] and answers[0].ms == 900


def test_the_questionnaire_comes_last_and_is_scored(client):
    study = make_study(client, targets_per_condition=1)
    token, = make_links(client, study["id"], 1)
    view = consent(client, token)
    body = {"satisfaction": [5, 6, 7], "usability": [5, 1] * 5}
    r = client.post(f"/api/participate/{token}/questionnaire", json=body)
    assert r.status_code == 409 and "after every trial" in r.json()["detail"]
    while view["trial"] is not None:
        view = answer(client, token, satisfied(view["trial"]))
    items = view["questionnaire"]
    assert len(items["satisfaction"]) == 3 and len(items["usability"]) == 10 and view["finished"] is False
    assert items["usability"][1]["text"] == "I found the system unnecessarily complex."
    r = client.post(f"/api/participate/{token}/questionnaire", json={**body, "usability": [3] * 9})
    assert r.status_code == 422 and "10 usability answers" in r.json()["detail"]
    r = client.post(f"/api/participate/{token}/questionnaire", json={**body, "satisfaction": [8, 1, 1]})
    assert r.status_code == 422
    done = client.post(f"/api/participate/{token}/questionnaire", json=body)
    assert done.status_code == 200 and done.json()["finished"] is True and done.json()["questionnaire"] is None
    assert client.post(f"/api/participate/{token}/questionnaire", json=body).status_code == 409
    scores = client.get(f"/api/admin/studies/{study['id']}/results", headers=AUTH).json()["questionnaires"]
    assert scores["usability"]["value"] == 100.0 and scores["satisfaction"]["value"] == 6.0 and scores["n"] == 1


def test_a_link_never_reaches_another_participants_trials(client):
    study = make_study(client)
    mine, theirs = make_links(client, study["id"], 2)
    my_trial = consent(client, mine)["trial"]
    their_trial = consent(client, theirs)["trial"]
    assert my_trial["id"] != their_trial["id"]
    r = client.post(f"/api/participate/{mine}/answer", json=more(their_trial))
    assert r.status_code == 409 and "not this participant's current trial" in r.json()["detail"]
    answer(client, mine, more(my_trial))
    assert client.get(f"/api/participate/{theirs}").json()["trial"] == their_trial  # untouched
    past = answer(client, mine, satisfied(client.get(f"/api/participate/{mine}").json()["trial"]))
    assert past["trial"]["id"] != my_trial["id"]
    r = client.post(f"/api/participate/{mine}/answer", json=more(my_trial))  # a trial that ended
    assert r.status_code == 409
    stranger = "x" * 32
    routes = [("GET", ""), ("POST", "/consent"), ("POST", "/answer"), ("POST", "/questionnaire"), ("DELETE", "")]
    bodies = {"/answer": more(my_trial), "/questionnaire": {"satisfaction": [4, 4, 4], "usability": [3] * 10}}
    for method, tail in routes:
        r = client.request(method, f"/api/participate/{stranger}{tail}", json=bodies.get(tail))
        assert r.status_code == 404 and "no study participant has this link" in r.json()["detail"], (method, tail)


def test_a_participant_token_is_refused_by_every_admin_route(client):
    study = make_study(client)
    token, = make_links(client, study["id"], 1)
    consent(client, token)
    sid = study["id"]
    routes = [("POST", "/api/admin/studies", CONFIG), ("GET", "/api/admin/studies", None),
              ("GET", f"/api/admin/studies/{sid}", None), ("POST", f"/api/admin/studies/{sid}/participants",
                                                            {"count": 1}),
              ("GET", f"/api/admin/studies/{sid}/results", None), ("GET", f"/api/admin/studies/{sid}/export", None)]
    for method, path, body in routes:
        for headers in ({"Authorization": f"Bearer {token}"}, {}):
            r = client.request(method, path, json=body, headers=headers)
            assert r.status_code == 401, (method, path, r.text)
    assert client.get(f"/api/admin/studies/{sid}", headers=AUTH).json()["participants"] == 1


def test_withdrawing_deletes_the_participants_rows_from_results_and_export(client):
    study = make_study(client)
    leaving, staying = make_links(client, study["id"], 2)
    for token in (leaving, staying):
        trial = consent(client, token)["trial"]
        answer(client, token, more(trial))
        answer(client, token, satisfied(client.get(f"/api/participate/{token}").json()["trial"]))
    before = client.get(f"/api/admin/studies/{study['id']}/results", headers=AUTH).json()
    assert before["participants"] == 2 and sum(c["trials"] for c in before["conditions"]) == 2
    assert client.delete(f"/api/participate/{leaving}").status_code == 204
    for method, tail in [("GET", ""), ("POST", "/consent"), ("DELETE", "")]:
        r = client.request(method, f"/api/participate/{leaving}{tail}")
        assert r.status_code == 410 and "withdrew" in r.json()["detail"]
    after = client.get(f"/api/admin/studies/{study['id']}/results", headers=AUTH).json()
    assert after["participants"] == 1 and sum(c["trials"] for c in after["conditions"]) == 1
    with Session(client.app.state.services.engine) as db:
        left = db.exec(select(Participant).where(Participant.withdrawn_at.is_not(None))).one()
        assert db.exec(select(StudyTrial).where(StudyTrial.participant_id == left.id)).all() == []
        assert len(db.exec(select(TuningSession)).all()) == 2 and len(db.exec(select(StudyAnswer)).all()) == 2
    z = export(client, study["id"])
    tables = "".join(z.read(f"{t}.csv").decode() for t in ("participants", "trials", "answers", "questionnaires"))
    assert left.id not in tables


# -- results and export from a study driven by simulated users ------------------------------------

def _say(trial: dict, said, ms: int, replays: int) -> dict:
    if said == SATISFIED:
        return {"trial_id": trial["id"], "feedback": {"kind": "satisfied"}, "ms": ms, "replays": replays}
    choices = [{"attribute": f.attribute, "direction": "more" if f.direction > 0 else "less"} for f in said]
    return {"trial_id": trial["id"], "feedback": {"kind": "attribute", "feedback": choices}, "ms": ms,
            "replays": replays}


def drive(c: TestClient, token: str, libraries: tuple, eps: np.ndarray, user: str, seed: int) -> list[tuple]:
    """One participant answering through the API as a simulated user who reads the true proxies of every clip
    shown; returns (trial id, whether the user's own rule says the last clip is within ε) per trial."""
    serve, test = libraries
    view, users, judged = consent(c, token), {}, []
    while view["trial"] is not None:
        trial = view["trial"]
        if trial["id"] not in users:
            target = test.proxies[test.index_of(trial["target"]["rollout_id"])]
            users[trial["id"]] = parse_user(user).build(target, eps, serve, seed + trial["index"])
        shown = serve.index_of(trial["clip"]["rollout_id"])
        said = users[trial["id"]].respond(shown)
        judged.append((trial["id"], users[trial["id"]].succeeded(shown)))
        view = answer(c, token, _say(trial, said, 400 + 50 * trial["answers_used"], trial["index"] % 3))
    body = {"satisfaction": [1 + seed % 7, 4, 6], "usability": [(seed + i) % 5 + 1 for i in range(10)]}
    assert c.post(f"/api/participate/{token}/questionnaire", json=body).json()["finished"] is True
    return judged


def test_results_equal_those_recomputed_from_the_export(client, toy_roots, tmp_path):
    study = make_study(client, answer_budget=12)
    serve, test = (SkillLibrary.load("toy", split, toy_roots[0]) for split in ("serve", "test"))
    eps = get_domain("toy").epsilons(serve.proxies, "normal")
    judged = []
    for n, token in enumerate(make_links(client, study["id"], 4)):
        judged += drive(client, token, (serve, test), eps, "paper" if n % 2 else "mistake:0.1", seed=n)
    results = client.get(f"/api/admin/studies/{study['id']}/results", headers=AUTH).json()
    path = tmp_path / "study.zip"
    path.write_bytes(client.get(f"/api/admin/studies/{study['id']}/export", headers=AUTH).content)
    assert results_from_export(path) == results
    assert [c["trials"] for c in results["conditions"]] == [8, 8] and results["questionnaires"]["n"] == 4
    assert all(p["finished"] for p in results["progress"])
    with zipfile.ZipFile(path) as z:
        assert sorted(z.namelist()) == ["answers.csv", "codebook.json", "participants.csv", "questionnaires.csv",
                                        "software.json", "study.json", "trials.csv"]
        codebook = json.loads(z.read("codebook.json"))
        for name, columns in codebook.items():
            assert z.read(name).decode().splitlines()[0].split(",") == list(columns)
            assert all({"type", "unit", "meaning"} == set(v) for v in columns.values())
        trials = list(csv.DictReader(io.StringIO(z.read("trials.csv").decode())))
        assert json.loads(z.read("software.json"))["model_versions"]
    # the recorded success is the protocol's: satisfied on a clip truly within ε of the target (the user's own rule)
    last = {trial_id: within for trial_id, within in judged}
    for t in trials:
        assert (t["success"] == "true") == (t["ended"] == "satisfied" and last[t["trial_id"]]), t
    assert sum(t["success"] == "true" for t in trials) >= 4  # the paper user finds most toy targets in 12 answers


@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_the_latin_square_is_balanced(n):
    rows = balanced_latin_square(n)
    assert len(rows) == (n if n % 2 == 0 else 2 * n) and all(sorted(r) == list(range(n)) for r in rows)
    for position in range(n):  # each condition equally often in each position
        assert sorted(r[position] for r in rows) == sorted(list(range(n)) * (len(rows) // n))
    follows = [(r[i], r[i + 1]) for r in rows for i in range(n - 1)]  # each ordered pair adjacent equally often
    assert len(set(follows)) == n * (n - 1) and len(follows) == len(set(follows)) * (len(rows) // n)


def test_each_participants_plan_rotates_conditions_and_targets():
    config = StudyConfig(**{**CONFIG, "conditions": [{"method": "global"}, {"method": "random"}], "seed": 0,
                            "targets_per_condition": 3, "targets": [["a", "b", "c"], ["a", "b", "c"]]})
    plans = [plan(config, number) for number in range(4)]
    assert plans[0] == [(0, "a"), (0, "b"), (0, "c"), (1, "b"), (1, "c"), (1, "a")]
    assert plans[1] == [(1, "c"), (1, "a"), (1, "b"), (0, "b"), (0, "c"), (0, "a")]
    assert [p[0][0] for p in plans] == [0, 1, 0, 1]
    reseeded = config.model_copy(update={"seed": 1})  # the seed shifts the square's rows
    assert plan(reseeded, 0) == [(1, "b"), (1, "c"), (1, "a"), (0, "a"), (0, "b"), (0, "c")]


def test_the_paired_test_on_constructed_differences():
    same_size = study_stats.paired_test([1 / 3] * 6)
    assert same_size["test"].startswith("exact sign test") and same_size["p_value"] == pytest.approx(2 * 0.5**6)
    mixed = [0.5, 1.0, 1.0, 0.5, 1.0, 1.0, 0.5, -0.5, 0.0]
    result = study_stats.paired_test(mixed)
    expected = scipy.stats.wilcoxon([d for d in mixed if d], alternative="two-sided")
    assert result["test"].startswith("Wilcoxon signed-rank test") and result["n"] == 9
    assert result["p_value"] == pytest.approx(expected.pvalue) and result["statistic"] == expected.statistic
    assert result["p_value"] < 0.05 and result["median_difference"] == 0.5
    none = study_stats.paired_test([0.0, 0.0])
    assert none["p_value"] == 1.0 and none["test"].startswith("none")


def test_the_scores_and_intervals():
    assert study_stats.sus_score([3] * 10) == 50.0 and study_stats.sus_score([5, 1] * 5) == 100.0
    assert study_stats.sus_score([1, 5] * 5) == 0.0
    half = study_stats.wilson(5, 10)  # Wilson (1927): 0.5 of 10 gives [0.237, 0.763]
    assert half["value"] == 0.5 and half["low"] == pytest.approx(0.2366, abs=1e-4) and \
        half["high"] == pytest.approx(0.7634, abs=1e-4)
    assert study_stats.wilson(0, 10)["low"] == 0.0 and study_stats.wilson(0, 10)["high"] == pytest.approx(0.2775,
                                                                                                        abs=1e-4)
    assert study_stats.wilson(0, 0)["value"] is None
    boot = study_stats.bootstrap([1.0, 2.0, 3.0, 4.0], seed=0)
    assert boot == study_stats.bootstrap([1.0, 2.0, 3.0, 4.0], seed=0) and boot["value"] == 2.5
    assert 1.0 <= boot["low"] < 2.5 < boot["high"] <= 4.0
    assert study_stats.sr_ks(20) == [5, 10, 20] and study_stats.sr_ks(8) == [5] and study_stats.sr_ks(3) == [3]


def test_a_walker_study_driven_by_simulated_users(tmp_path):
    """The shipped walker models and library behind a study: RBA-Global and the floor, two participants."""
    settings = Settings(data_dir=REPO / "data", models_dir=REPO / "models", database_url=f"sqlite:///{tmp_path}/s.db",
                        cache_dir=tmp_path / "clips", warm_start=False, prerender=False, prerender_library=False,
                        admin_token=TOKEN)
    if ("global", "onehot") not in Catalog(settings).available("walker"):
        pytest.skip("walker artifacts are absent: run `rba build walker` and `rba train walker` first")
    serve, test = (SkillLibrary.load("walker", split, REPO / "data") for split in ("serve", "test"))
    eps = get_domain("walker").epsilons(serve.proxies, "normal")
    with TestClient(create_app(settings)) as c:
        study = make_study(c, domain="walker", targets_per_condition=1, answer_budget=10)
        for n, token in enumerate(make_links(c, study["id"], 2)):
            drive(c, token, (serve, test), eps, "paper", seed=n)
        results = c.get(f"/api/admin/studies/{study['id']}/results", headers=AUTH).json()
        path = tmp_path / "study.zip"
        path.write_bytes(c.get(f"/api/admin/studies/{study['id']}/export", headers=AUTH).content)
        target = study["config"]["targets"][0][0]
        shown = consent(c, make_links(c, study["id"], 1)[0])["trial"]  # a new participant, after the results
        assert shown["target"]["data_url"] == f"/api/clips/walker/{shown['target']['rollout_id']}.json"
        drawn = c.get(f"/api/clips/walker/{target}.json")  # a target is drawn from its data as any clip
        assert drawn.status_code == 200 and drawn.headers["content-type"].startswith("application/json")
    assert results_from_export(path) == results
    assert [c["trials"] for c in results["conditions"]] == [2, 2] and results["comparison"]["pairs"][0]["n"] == 2
