"""GET /api/clips/{domain}/{rollout_id}.mp4: a rollout of the serve library, or one a session generated
(``gen-<hash>``), as H.264 video (and ``/status``: how far its render is, for the page's progress while a
person waits).

The rollout id is resolved by ``server.runtime.clip_sources`` (404 if unknown) and never used as a path; a
generated rollout no longer in memory is simulated again from its params and seed, unless its clip is stored. The
file is rendered on first request and cached; responses carry a content ETag and honour
``If-None-Match`` (304), ``Range`` (206, so browsers can seek and stream) and ``If-Range`` (RFC 9110).
"""

from __future__ import annotations

import asyncio
import os
from typing import Annotated

import anyio
from fastapi import APIRouter, Header, Path, Response
from fastapi.responses import FileResponse
from starlette.datastructures import Headers
from starlette.responses import MalformedRangeHeader, RangeNotSatisfiable
from starlette.types import Receive, Scope, Send

from server.api.deps import DbDep, ServicesDep
from server.common.errors import error_response, not_found, responses
from server.db.tables import ClipStatusPublic, DomainName
from server.ops.views import clip_status
from server.runtime.clip_sources import UnknownRollout

router = APIRouter(prefix="/api/clips", tags=["clips"], responses=responses(413, 422))


def none_match(header: str, etag: str) -> bool:
    """``If-None-Match`` matches: ``*`` (the clip exists) or one of its tags by weak comparison (RFC 9110 §13.1.2),
    as browsers may send back ``W/"…"`` after a proxy weakened the tag."""
    tags = {t.strip().removeprefix("W/") for t in header.split(",")}
    return "*" in tags or etag in tags


class ClipFile(FileResponse):
    """A FileResponse whose refusals of a ``Range`` header (400, 416) have the app's error body, not plain text."""

    def _should_use_range(self, http_if_range: str) -> bool:
        """Serve the range only if ``If-Range`` is the clip's current strong ETag (RFC 9110 §13.1.5); a weak tag, an
        other tag or a date gets the whole clip. (Starlette's own check also reads Last-Modified, set only once the
        response starts: the range checks below run before that.)"""
        return http_if_range.strip() == self.headers["etag"]

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        headers = Headers(scope=scope)
        wanted, if_range = headers.get("range"), headers.get("if-range")
        if wanted is not None and (if_range is None or self._should_use_range(if_range)):
            size = (await anyio.to_thread.run_sync(os.stat, self.path)).st_size
            try:
                self._parse_range_header(wanted, size)
            except MalformedRangeHeader as exc:
                await error_response(400, f"bad Range header {wanted!r}: {exc.content}")(scope, receive, send)
                return
            except RangeNotSatisfiable:
                await error_response(416, f"range {wanted!r} starts outside the clip's {size} bytes",
                                     {"Content-Range": f"bytes */{size}"})(scope, receive, send)
                return
        await super().__call__(scope, receive, send)


@router.get("/{domain}/{rollout_id}.mp4", response_class=ClipFile,
            responses={200: {"content": {"video/mp4": {}}, "description": "the clip"},
                       206: {"content": {"video/mp4": {}, "multipart/byteranges": {}},
                             "description": "the requested byte range(s)"},
                       304: {"description": "not modified"},
                       **responses(400, 404, 416, said={400: "a malformed Range header",
                                                        404: "no serve library, no such rollout in it, or no "
                                                             "such generated rollout"})},
            summary="A rollout's clip as MP4 (rendered on first request, then cached)")
async def get_clip(domain: Annotated[DomainName, Path()], rollout_id: Annotated[str, Path(max_length=128)],
                   svc: ServicesDep, db: DbDep, if_none_match: Annotated[str | None, Header()] = None) -> Response:
    await anyio.to_thread.run_sync(svc.catalog.domain, domain)  # the first call imports the simulator
    try:  # in a thread: the first call loads the serve library
        clip = await anyio.to_thread.run_sync(svc.sources.resolve, db, domain, rollout_id)
    except UnknownRollout as exc:
        raise not_found(str(exc)) from exc
    key = clip.key
    # The URL outlives a library rebuild; the ETag (a hash of the key) does not: browsers revalidate.
    headers = {"ETag": key.etag, "Cache-Control": "no-cache"}
    if if_none_match and none_match(if_none_match, key.etag):
        return Response(status_code=304, headers=headers)
    source = clip.source(simulate=False)
    if source is None and not svc.clips.cached(key):
        # a made clip no longer in memory: simulated again on the compute layer, in a thread (the loop stays free)
        source = await anyio.to_thread.run_sync(clip.source)
    # Rendered on the compute layer (or already in flight there): waiting holds no thread.
    path = await asyncio.wrap_future(svc.clips.request(key, source))
    return ClipFile(path, media_type="video/mp4", headers=headers)


router.add_api_route("/{domain}/{rollout_id}.mp4", get_clip, methods=["HEAD"], include_in_schema=False)


@router.get("/{domain}/{rollout_id}/status", response_model=ClipStatusPublic,
            responses=responses(404, said={404: "no serve library, no such rollout in it, or no such generated "
                                                "rollout"}),
            summary="How far a clip's render is: ready, queued, rendering (elapsed and typical seconds) or absent")
def get_clip_status(domain: Annotated[DomainName, Path()], rollout_id: Annotated[str, Path(max_length=128)],
                    svc: ServicesDep, db: DbDep) -> ClipStatusPublic:
    return clip_status(svc, db, domain, rollout_id)
