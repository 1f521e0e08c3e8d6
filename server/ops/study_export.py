"""A study's data out: four tidy tables (participants, trials, answers, questionnaires), read from the database
without the withdrawn participants, written as CSVs in a zip with ``codebook.json`` (every column), ``study.json``
and ``software.json``; ``results_from_export`` recomputes the results page from such a zip alone.

The results page runs ``study_stats.results`` on the same rows the CSVs hold (``study_tables``), so the two agree
exactly: floats are written with ``repr`` (they read back bit for bit), booleans as true/false, empty for null.
"""

from __future__ import annotations

import csv
import importlib.metadata
import io
import json
import subprocess
import zipfile
from pathlib import Path
from typing import Any

from sqlmodel import Session, select

from rba.interact import SATISFIED
from server.db.study_tables import Participant, Questionnaire, Study, StudyAnswer, StudyTrial
from server.db.tables import TuningSession, as_utc
from server.ops import study_stats
from server.ops.studies import study_config

REPO = Path(__file__).resolve().parents[2]


def _col(kind: str, unit: str, meaning: str) -> dict[str, str]:
    return {"type": kind, "unit": unit, "meaning": meaning}


def _codebook() -> dict[str, dict[str, dict[str, str]]]:
    """Every column of every CSV: type (string, integer, number, boolean, datetime), unit and meaning."""
    sat = {f"sat_{i + 1}": _col("integer", "1-7", f"satisfaction item {i + 1}: {t}")
           for i, t in enumerate(study_stats.SATISFACTION)}
    sus = {f"sus_{i + 1}": _col("integer", "1-5", f"System Usability Scale item {i + 1} (Brooke 1996): {t}")
           for i, t in enumerate(study_stats.SUS)}
    return {
        "participants.csv": {
            "participant_id": _col("string", "", "the participant (not their link: only its hash is stored)"),
            "number": _col("integer", "", "order the links were made in; picks the Latin square's row"),
            "consented": _col("boolean", "", "gave consent"),
            "consented_at": _col("datetime", "UTC, ISO 8601", "when they consented (empty: not yet)"),
            "trials_done": _col("integer", "trials", "trials ended (satisfied or budget spent)"),
            "trials_total": _col("integer", "trials", "trials planned for them"),
            "finished": _col("boolean", "", "every trial done and the questionnaire answered")},
        "trials.csv": {
            "trial_id": _col("string", "", "the trial"),
            "participant_id": _col("string", "", "participants.csv's participant"),
            "position": _col("integer", "", "0-based order in which the participant met it"),
            "condition": _col("integer", "", "index into study.json's config.conditions"),
            "method": _col("string", "", "the condition's method (random: the reference floor)"),
            "rep": _col("string", "", "the condition's attribute representation"),
            "label": _col("string", "", "the blinded name the participant saw (Agent A, ...)"),
            "target_rollout_id": _col("string", "", "the test-split rollout to reach (empty: free task)"),
            "ended": _col("string", "", "satisfied | budget (empty: not ended)"),
            "answers": _col("integer", "answers", "more/less answers given (the budget counts these)"),
            "feedbacks": _col("integer", "feedbacks", "attribute feedbacks given (one per attribute per "
                              "answer: the paper's AF unit)"),
            "final_rollout_id": _col("string", "", "the serve clip shown at the end"),
            "distance": _col("number", "ε units", "Euclidean distance of the final clip's true proxies to the "
                             "target's, each attribute divided by its ε at the study's precision (never shown)"),
            "success": _col("boolean", "", "ended satisfied with every true proxy within ε of the target's "
                            "(free task: ended satisfied)"),
            "model_version": _col("string", "", "the models the trial's agent used"),
            "started_at": _col("datetime", "UTC, ISO 8601", "first clip served"),
            "ended_at": _col("datetime", "UTC, ISO 8601", "the trial ended")},
        "answers.csv": {
            "trial_id": _col("string", "", "trials.csv's trial"),
            "step": _col("integer", "", "0-based answer number within the trial"),
            "rollout_id": _col("string", "", "the clip the answer is about"),
            "kind": _col("string", "", "attribute | satisfied"),
            "feedback": _col("string", "", "attribute:direction pairs joined by ';' (empty when satisfied)"),
            "feedbacks": _col("integer", "feedbacks", "attribute feedbacks in this answer"),
            "ms": _col("integer", "ms", "time from the clip's start to the answer"),
            "replays": _col("integer", "", "times the participant replayed the clip"),
            "created_at": _col("datetime", "UTC, ISO 8601", "when the answer arrived")},
        "questionnaires.csv": {
            "participant_id": _col("string", "", "participants.csv's participant"), **sat, **sus,
            "satisfaction_score": _col("number", "1-7", "mean of the satisfaction items"),
            "sus_score": _col("number", "0-100", "System Usability Scale score (Brooke 1996)"),
            "created_at": _col("datetime", "UTC, ISO 8601", "when it was answered")},
    }


CODEBOOK = _codebook()


def _iso(value: Any) -> str | None:
    return None if value is None else as_utc(value).isoformat()


def _trial_rows(db: Session, config: Any, people: list[Participant]) -> list[dict[str, Any]]:
    rows = []
    for p in people:
        trials = db.exec(select(StudyTrial).where(StudyTrial.participant_id == p.id).order_by(StudyTrial.position))
        trials = list(trials.all())
        labels = {c: f"Agent {chr(ord('A') + i)}" for i, c in enumerate(dict.fromkeys(t.condition for t in trials))}
        for t in trials:
            cond = config.conditions[t.condition]
            session = db.get(TuningSession, t.session_id) if t.session_id else None
            rows.append({"trial_id": t.id, "participant_id": p.id, "position": t.position, "condition": t.condition,
                         "method": cond.method, "rep": cond.rep, "label": labels[t.condition],
                         "target_rollout_id": t.target_rollout_id, "ended": t.ended, "answers": t.answers,
                         "feedbacks": t.feedbacks, "final_rollout_id": t.final_rollout_id, "distance": t.distance,
                         "success": t.success, "model_version": session.model_version if session else None,
                         "started_at": _iso(t.started_at), "ended_at": _iso(t.ended_at)})
    return rows


def _answer_row(a: StudyAnswer) -> dict[str, Any]:
    satisfied = a.feedback == SATISFIED
    pairs = [] if satisfied else [f"{c['attribute']}:{c['direction']}" for c in a.feedback]
    return {"trial_id": a.trial_id, "step": a.step, "rollout_id": a.rollout_id,
            "kind": "satisfied" if satisfied else "attribute", "feedback": ";".join(pairs) or None,
            "feedbacks": len(pairs), "ms": a.ms, "replays": a.replays, "created_at": _iso(a.created_at)}


def _questionnaire_row(q: Questionnaire) -> dict[str, Any]:
    return {"participant_id": q.participant_id, **{f"sat_{i + 1}": x for i, x in enumerate(q.satisfaction)},
            **{f"sus_{i + 1}": x for i, x in enumerate(q.usability)},
            "satisfaction_score": study_stats.satisfaction_score(q.satisfaction),
            "sus_score": study_stats.sus_score(q.usability), "created_at": _iso(q.created_at)}


def study_rows(db: Session, study: Study) -> dict[str, list[dict[str, Any]]]:
    """The four tables of a study (the withdrawn left out), rows in a fixed order, typed as the codebook says."""
    config = study_config(study)
    people = list(db.exec(select(Participant).where(Participant.study_id == study.id,
                                                    Participant.withdrawn_at.is_(None))
                          .order_by(Participant.number)).all())
    trials = _trial_rows(db, config, people)
    order = {t["trial_id"]: i for i, t in enumerate(trials)}
    answers = db.exec(select(StudyAnswer).where(StudyAnswer.trial_id.in_(list(order)))).all()
    answers = sorted(answers, key=lambda a: (order[a.trial_id], a.step))
    number = {p.id: p.number for p in people}
    asked = db.exec(select(Questionnaire).where(Questionnaire.participant_id.in_(list(number)))).all()
    participants = []
    for p in people:
        mine = [t for t in trials if t["participant_id"] == p.id]
        done = sum(bool(t["ended"]) for t in mine)
        participants.append({"participant_id": p.id, "number": p.number, "consented": p.consented_at is not None,
                             "consented_at": _iso(p.consented_at), "trials_done": done, "trials_total": len(mine),
                             "finished": done == len(mine) and p.questionnaire_at is not None})
    return {"participants": participants, "trials": trials, "answers": [_answer_row(a) for a in answers],
            "questionnaires": [_questionnaire_row(q) for q in sorted(asked, key=lambda q: number[q.participant_id])]}


def results(db: Session, study: Study) -> dict[str, Any]:
    """The results page's numbers (``study_stats.results`` over ``study_rows``)."""
    return {"study_id": study.id, **study_stats.results(study.config, study_rows(db, study))}


# -- the zip --------------------------------------------------------------------------------------

def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _csv(table: str, rows: list[dict[str, Any]]) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    columns = list(CODEBOOK[table])
    writer.writerow(columns)
    for row in rows:
        writer.writerow([_cell(row[c]) for c in columns])
    return out.getvalue()


def _parse(kind: str, text: str) -> Any:
    if text == "":
        return None
    if kind == "integer":
        return int(text)
    if kind == "number":
        return float(text)
    if kind == "boolean":
        return text == "true"
    return text


def _git_commit() -> str | None:
    try:
        done = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=5, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() or None if done.returncode == 0 else None


def software(tables: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    def version(name: str) -> str | None:
        try:
            return importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            return None

    models = sorted({(t["method"], t["rep"], t["model_version"]) for t in tables["trials"] if t["model_version"]})
    return {"package": "rba-studio", "version": version("rba-studio"), "git_commit": _git_commit(),
            "numpy": version("numpy"), "scipy": version("scipy"),
            "model_versions": [{"method": m, "rep": r, "model_version": v} for m, r, v in models]}


def export_zip(db: Session, study: Study) -> bytes:
    """The whole export in memory (the route sends it at once: never half a file)."""
    tables = study_rows(db, study)
    meta = {"id": study.id, "name": study.name, "domain": study.domain, "created": _iso(study.created_at),
            "config": study.config}
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for table, rows in tables.items():
            z.writestr(f"{table}.csv", _csv(f"{table}.csv", rows))
        z.writestr("codebook.json", json.dumps(CODEBOOK, indent=2))
        z.writestr("study.json", json.dumps(meta, indent=2))
        z.writestr("software.json", json.dumps(software(tables), indent=2))
    return buf.getvalue()


def results_from_export(path: Path | str) -> dict[str, Any]:
    """The results page's numbers recomputed from an export zip alone (its CSVs typed by its codebook)."""
    with zipfile.ZipFile(path) as z:
        codebook = json.loads(z.read("codebook.json"))
        meta = json.loads(z.read("study.json"))
        tables = {}
        for name, columns in codebook.items():
            reader = csv.DictReader(io.StringIO(z.read(name).decode()))
            tables[name.removesuffix(".csv")] = [{c: _parse(columns[c]["type"], row[c]) for c in columns}
                                                 for row in reader]
    return {"study_id": meta["id"], **study_stats.results(meta["config"], tables)}
