"""Studies, the participant's side: the link's view, consent, answers, the questionnaire, withdrawal.

Every function takes the participant its token found (``by_token``) and touches only that participant's rows, so a
link can neither read nor answer another's trials. A trial's agent is an ordinary ``rba_session`` row stepped by
``svc.transitions`` (the reference floor ``random`` included), so clips and prerendering work as for any session.
Each change is one transaction; a participant's requests are serialised by ``svc.session_locks`` and the session's
step moves by compare-and-set, so a second replica's answer to the same clip is a 409, never a double step.
"""

from __future__ import annotations

import numpy as np
from fastapi import HTTPException
from sqlalchemy import delete, update
from sqlalchemy.exc import IntegrityError
from sqlmodel import Session, select

from rba.core.methods import get_method
from rba.interact import SATISFIED, Feedback
from server.common.errors import conflict, not_found
from server.common.feedback import parse_feedback
from server.db.study_tables import (
    AnswerCreate,
    ClipRef,
    Participant,
    ParticipationPublic,
    Questionnaire,
    QuestionnaireCreate,
    QuestionnaireView,
    StudyAnswer,
    StudyConfig,
    StudyTrial,
    StudyView,
    TrialView,
)
from server.db.tables import FeedbackEvent, SessionStatus, TuningSession, utcnow
from server.ops import study_stats
from server.ops.model_versions import serving_version
from server.ops.prerender import schedule_prerender, stop_prerender
from server.ops.studies import load_study, study_config, target_library, token_hash
from server.ops.views import attributes_public, clip_data_url, clip_url
from server.runtime.services import Services

WITHDRAWN = 410


def by_token(db: Session, token: str) -> Participant:
    """The link's participant: 404 for an unknown token, 410 once withdrawn."""
    p = db.exec(select(Participant).where(Participant.token_hash == token_hash(token))).first()
    if p is None:
        raise not_found("no study participant has this link; check it was copied whole")
    if p.withdrawn_at is not None:
        raise HTTPException(WITHDRAWN, "this participant withdrew from the study; their data was deleted")
    return p


def _trials(db: Session, p: Participant) -> list[StudyTrial]:
    return list(db.exec(select(StudyTrial).where(StudyTrial.participant_id == p.id)
                        .order_by(StudyTrial.position)).all())


def _current(trials: list[StudyTrial]) -> StudyTrial | None:
    return next((t for t in trials if t.ended is None), None)


def _clip(svc: Services, domain: str, rollout_id: str) -> ClipRef:
    return ClipRef(rollout_id=rollout_id, url=clip_url(domain, rollout_id),
                   data_url=clip_data_url(svc.catalog.domain(domain), rollout_id))


def _start(svc: Services, db: Session, config: StudyConfig, trial: StudyTrial) -> None:
    """Give the trial its agent (a new session at the method's first clip), if no request did first."""
    cond = config.conditions[trial.condition]
    version = serving_version(svc, db, config.domain, cond.method, cond.rep)
    ctx = svc.catalog.context(config.domain, cond.method, cond.rep, version)
    rollout_id, state = svc.transitions.first(ctx, get_method(cond.method))
    s = TuningSession(domain=config.domain, method=cond.method, rep=cond.rep, model_version=ctx.model_version,
                      model_set=version, library_version=svc.catalog.library(config.domain).version,
                      current_rollout_id=rollout_id, agent_state=state)
    db.add(s)
    db.flush()
    moved = db.exec(update(StudyTrial).where(StudyTrial.id == trial.id, StudyTrial.session_id.is_(None))
                    .values(session_id=s.id, started_at=utcnow()))
    if moved.rowcount != 1:
        db.rollback()
    else:
        db.commit()
        schedule_prerender(svc, s, None)
    db.refresh(trial)


def _labels(trials: list[StudyTrial]) -> dict[int, str]:
    """Blinded names: 'Agent A' for the first condition this participant meets, and so on."""
    order = list(dict.fromkeys(t.condition for t in trials))
    return {c: f"Agent {chr(ord('A') + i)}" for i, c in enumerate(order)}


def _trial_view(svc: Services, db: Session, config: StudyConfig, trials: list[StudyTrial],
                trial: StudyTrial) -> TrialView:
    if trial.session_id is None:
        _start(svc, db, config, trial)
    s = db.get(TuningSession, trial.session_id)
    target = trial.target_rollout_id
    return TrialView(index=trial.position, of=len(trials), id=trial.id, label=_labels(trials)[trial.condition],
                     target=None if target is None else _clip(svc, config.domain, target),
                     clip=_clip(svc, config.domain, s.current_rollout_id), answers_used=trial.answers,
                     answer_budget=config.answer_budget)


def view(svc: Services, db: Session, p: Participant) -> ParticipationPublic:
    config = study_config(load_study(db, p.study_id))
    trials = _trials(db, p)
    current = _current(trials)
    consented = p.consented_at is not None
    asking = consented and current is None and p.questionnaire_at is None
    study = StudyView(name=config.name, domain=config.domain, task=config.task, consent_text=config.consent_text,
                      answer_budget=config.answer_budget,
                      attributes=attributes_public(svc.catalog.domain(config.domain), svc))
    return ParticipationPublic(
        study=study, consented=consented, finished=current is None and p.questionnaire_at is not None,
        trial=_trial_view(svc, db, config, trials, current) if consented and current is not None else None,
        questionnaire=QuestionnaireView(**study_stats.questionnaire_items()) if asking else None)


def consent(db: Session, p: Participant) -> None:
    if p.consented_at is None:
        p.consented_at = utcnow()
        db.add(p)
        db.commit()


def _outcome(svc: Services, config: StudyConfig, trial: StudyTrial, final: str, satisfied: bool
             ) -> tuple[float | None, bool]:
    """The true distance (ε units, Euclidean) of the final clip to the target, and success: satisfied with the
    true proxies within ε at the study's precision (as ``rba.interact.evaluate``); free task: satisfied."""
    if trial.target_rollout_id is None:
        return None, satisfied
    serve, test = svc.catalog.library(config.domain), target_library(svc, config.domain)
    eps = svc.catalog.domain(config.domain).epsilons(serve.proxies, config.precision)
    x = serve.proxies[serve.index_of(final)].astype(np.float64)
    t = test.proxies[test.index_of(trial.target_rollout_id)].astype(np.float64)
    within = bool(np.all(np.abs(x - t) <= eps))
    return float(np.linalg.norm((x - t) / eps)), satisfied and within


def _answerable(db: Session, p: Participant, trial_id: str) -> tuple[StudyTrial, TuningSession]:
    db.refresh(p)  # read again under the lock: a withdrawal may have landed since the link was looked up
    if p.withdrawn_at is not None:
        raise HTTPException(WITHDRAWN, "this participant withdrew from the study; their data was deleted")
    if p.consented_at is None:
        raise conflict("consent first: POST /api/participate/{token}/consent")
    current = _current(_trials(db, p))
    if current is None:
        raise conflict("every trial of this participant is done; answer the questionnaire")
    if trial_id != current.id or current.session_id is None:
        raise conflict(f"trial {trial_id!r} is not this participant's current trial (that is {current.id}); "
                       "GET the link's state and answer the clip it shows")
    return current, db.get(TuningSession, current.session_id)


def answer(svc: Services, db: Session, p: Participant, body: AnswerCreate) -> ParticipationPublic:
    with svc.session_locks(p.id):
        trial, s = _answerable(db, p, body.trial_id)
        config = study_config(load_study(db, p.study_id))
        ctx = svc.catalog.context(s.domain, s.method, s.rep, s.model_set)
        choices = [(c.attribute, c.direction) for c in getattr(body.feedback, "feedback", ())]
        satisfied = body.feedback.kind == "satisfied"
        feedback = parse_feedback(choices, satisfied, s.domain, ctx.attribute_names)
        stored = SATISFIED if satisfied else [c.model_dump() for c in body.feedback.feedback]
        db.add(StudyAnswer(trial_id=trial.id, step=trial.answers, rollout_id=s.current_rollout_id, feedback=stored,
                           ms=body.ms, replays=body.replays))
        ended = _step(svc, db, config, trial, s, feedback, stored, ctx)
    if ended:
        stop_prerender(svc, s.id)
    else:
        schedule_prerender(svc, s, feedback)
    return view(svc, db, p)


def _step(svc: Services, db: Session, config: StudyConfig, trial: StudyTrial, s: TuningSession, feedback: Feedback,
          stored: object, ctx: object) -> bool:
    """Move the trial and its session on, in one transaction (compare-and-set on the session's step); whether the
    trial ended (satisfied, or its budget spent: the last answer is not stepped, nobody would see the clip)."""
    shown, values = s.current_rollout_id, {"updated_at": utcnow()}
    if feedback == SATISFIED:
        ended, values["status"] = "satisfied", SessionStatus.satisfied.value
        db.add(FeedbackEvent(session_id=s.id, step=s.step, feedback=stored, rollout_before=shown,
                             rollout_after=shown))
    else:
        trial.answers += 1
        trial.feedbacks += len(feedback)
        ended = "budget" if trial.answers >= config.answer_budget else None
        if ended:
            values["status"] = SessionStatus.abandoned.value
        else:
            rollout_id, state = svc.transitions.advance(ctx, get_method(s.method), s.agent_state, feedback)
            values |= {"step": s.step + 1, "current_rollout_id": rollout_id, "agent_state": state}
            db.add(FeedbackEvent(session_id=s.id, step=s.step, feedback=stored, rollout_before=shown,
                                 rollout_after=rollout_id))
    if ended:
        trial.ended, trial.ended_at, trial.final_rollout_id = ended, utcnow(), shown
        trial.distance, trial.success = _outcome(svc, config, trial, shown, ended == "satisfied")
    db.add(trial)
    moved = db.exec(update(TuningSession).where(TuningSession.id == s.id, TuningSession.step == s.step,
                                                TuningSession.status == SessionStatus.active.value).values(**values))
    if moved.rowcount != 1:
        db.rollback()
        raise conflict("this clip was answered already (another tab?); GET the link's state")
    db.commit()
    db.refresh(s)
    return ended is not None


def answer_questionnaire(db: Session, p: Participant, body: QuestionnaireCreate) -> None:
    """Store the end questionnaire once; 409 before every trial is done or when answered already."""
    study_stats.check_questionnaire(body.satisfaction, body.usability)
    if p.consented_at is None or _current(_trials(db, p)) is not None:
        raise conflict("the questionnaire comes after every trial; GET the link's state for the current trial")
    if p.questionnaire_at is not None:
        raise conflict("the questionnaire was answered already")
    db.add(Questionnaire(participant_id=p.id, satisfaction=body.satisfaction, usability=body.usability))
    p.questionnaire_at = utcnow()
    db.add(p)
    try:
        db.commit()
    except IntegrityError as exc:  # the same questionnaire sent twice at once: the other one was stored
        db.rollback()
        raise conflict("the questionnaire was answered already") from exc


def withdraw(svc: Services, db: Session, p: Participant) -> None:
    """Delete every answer, trial, session and questionnaire of the participant in one transaction; the link then
    answers 410. The participant row stays (withdrawn) so its number is not reused by the Latin square."""
    with svc.session_locks(p.id):
        trials = _trials(db, p)
        sessions = [t.session_id for t in trials if t.session_id is not None]
        ids = [t.id for t in trials]
        db.exec(delete(StudyAnswer).where(StudyAnswer.trial_id.in_(ids)))
        db.exec(delete(StudyTrial).where(StudyTrial.participant_id == p.id))
        db.exec(delete(FeedbackEvent).where(FeedbackEvent.session_id.in_(sessions)))
        db.exec(delete(TuningSession).where(TuningSession.id.in_(sessions)))
        db.exec(delete(Questionnaire).where(Questionnaire.participant_id == p.id))
        p.withdrawn_at, p.consented_at, p.questionnaire_at = utcnow(), None, None
        db.add(p)
        db.commit()
    for sid in sessions:
        stop_prerender(svc, sid)
