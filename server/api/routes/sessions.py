"""Sessions: create one, read it, answer its clip with more/less feedback or "this is it", export what was chosen."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path
from fastapi.responses import Response

from server.api.deps import DbDep, ServicesDep
from server.common.errors import responses
from server.db.tables import FeedbackCreate, GenerationPublic, SessionCreate, SessionPublic
from server.ops import prerender, session_export, session_searches, session_steps, views

router = APIRouter(prefix="/api/sessions", tags=["sessions"], responses=responses(413, 422))

SessionId = Annotated[str, Path(description="the id POST /api/sessions returned", max_length=64)]

SAID = {404: "no such session", 409: "stale step, the session is closed, or it is still making a new behaviour",
        422: "invalid body: the message names the valid values"}


@router.post("", response_model=SessionPublic, status_code=201, responses=responses(422, said=SAID),
             summary="Start a session; the response holds the first clip")
def create_session(body: SessionCreate, svc: ServicesDep, db: DbDep) -> SessionPublic:
    return session_steps.create_session(svc, db, body)


@router.get("/{session_id}", response_model=SessionPublic, responses=responses(404, said=SAID),
            summary="A session: status, step, current clip (with measured values) and history")
def read_session(session_id: SessionId, svc: ServicesDep, db: DbDep) -> SessionPublic:
    s = session_steps.load_session(db, session_id)
    prerender.resume_prerender(svc, s)
    return views.session_public(svc, db, s)


@router.post("/{session_id}/feedback", response_model=SessionPublic, responses={
    202: {"model": SessionPublic, "description": "a generating session's answer started a search for a new "
          "behaviour: the session is still at its step; poll the Location (GET …/generation)"},
    **responses(404, 409, 422, said=SAID)}, summary="Answer the current clip: more/less of attributes, or satisfied")
def give_feedback(session_id: SessionId, body: FeedbackCreate, svc: ServicesDep, db: DbDep,
                  response: Response) -> SessionPublic:
    session, searching = session_steps.give_feedback(svc, db, session_id, body)
    if searching:
        response.status_code = 202
        response.headers["Location"] = f"/api/sessions/{session_id}/generation"
    return session


@router.get("/{session_id}/generation", response_model=GenerationPublic, responses=responses(404, said={
    404: "no such session, or no search of it in this server"}),
    summary="How far the search for a generating session's next behaviour is (generation k of K)")
def read_generation(session_id: SessionId, svc: ServicesDep, db: DbDep) -> GenerationPublic:
    return session_searches.latest(svc, session_steps.load_session(db, session_id))


@router.post("/{session_id}/abandon", response_model=SessionPublic, responses=responses(404, 409, said=SAID),
             summary="Stop a session without choosing a behaviour")
def abandon_session(session_id: SessionId, svc: ServicesDep, db: DbDep) -> SessionPublic:
    return session_steps.abandon_session(svc, db, session_id)


EXPORT_SAID = {404: "no such session", 409: "the session did not end satisfied, or its models changed since"}


@router.get("/{session_id}/export", response_class=Response, responses={
    200: {"content": {"application/zip": {}}, "description": "the export zip (rba.data.export_zip): profile.json, "
          "clip.mp4, the reward for the chosen behaviour"}, **responses(404, 409, said=EXPORT_SAID)},
    summary="Download a satisfied session's chosen behaviour: profile, clip and reward model (a zip)")
def export_session(session_id: SessionId, svc: ServicesDep, db: DbDep) -> Response:
    profile, data = session_export.export_session(svc, db, session_id)
    name = f"rba-{profile.domain}-{session_id}.zip"
    return Response(data, media_type="application/zip",
                    headers={"Content-Disposition": f'attachment; filename="{name}"'})
