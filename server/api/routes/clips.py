"""GET /api/clips/{domain}/{rollout_id}.mp4: a rollout of the serve library, or one a session generated
(``gen-<hash>``), as H.264 video (and ``/status``: how far its render is, for the page's progress while a
person waits). ``{rollout_id}.json`` is the same clip as data the page draws itself (per-frame poses,
``rba.media.clip_data``), and ``scene.json`` the domain's scene those name, once per domain.

The rollout id is resolved by ``server.runtime.clip_sources`` (404 if unknown) and never used as a path; a
generated rollout no longer in memory is simulated again from its params and seed, unless its clip is stored. The
file is rendered on first request and cached; responses carry a content ETag and honour
``If-None-Match`` (304), ``Range`` (206, so browsers can seek and stream) and ``If-Range`` (RFC 9110).
"""

from __future__ import annotations

import asyncio
import gzip
import os
from typing import Annotated

import anyio
from fastapi import APIRouter, Header, Path, Query, Response
from fastapi.responses import FileResponse
from starlette.datastructures import Headers
from starlette.responses import MalformedRangeHeader, RangeNotSatisfiable
from starlette.types import Receive, Scope, Send

from rba.media.clip_data import NoClipData
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


IMMUTABLE = "public, max-age=31536000, immutable"
JSON_RESPONSES = {200: {"content": {"application/json": {}}, "description": "the data (gzip-encoded when accepted)"},
                  304: {"description": "not modified"}}


def _gzipped(body: bytes, headers: dict[str, str], accept_encoding: str | None) -> Response:
    """Stored gzipped JSON as is to a client that accepts gzip, else decompressed."""
    headers = {**headers, "Vary": "Accept-Encoding"}
    if accept_encoding and "gzip" in accept_encoding.lower():
        return Response(body, media_type="application/json", headers={**headers, "Content-Encoding": "gzip"})
    return Response(gzip.decompress(body), media_type="application/json", headers=headers)


def _drawable(svc, domain: str) -> None:
    """404 for a domain whose clips are MP4s only."""
    if not svc.catalog.domain(domain).draws_clips:
        raise not_found(f"domain {domain!r} has no clip data: its clips are MP4s only (the clip's url)")


# before {rollout_id}.json: a rollout id never reads "scene" (library ids name their split, made ones start gen-)
@router.get("/{domain}/scene.json", response_class=Response,
            responses={**JSON_RESPONSES, **responses(404, said={404: "no such domain, or one without clip data"})},
            summary="A domain's scene for drawing its clips (geoms, camera, lights; or the road), per version")
async def get_scene(domain: Annotated[DomainName, Path()], svc: ServicesDep,
                    v: Annotated[str | None, Query(max_length=64, description="the scene's version, as a clip's "
                                                   "scene_url gives it: then cached for a year")] = None,
                    if_none_match: Annotated[str | None, Header()] = None,
                    accept_encoding: Annotated[str | None, Header()] = None) -> Response:
    await anyio.to_thread.run_sync(_drawable, svc, domain)
    try:  # computed once per process on the compute layer
        scene = await asyncio.wrap_future(svc.clips.scene(domain))
    except NoClipData as exc:
        raise not_found(str(exc)) from exc
    etag = f'"{scene.version}"'
    headers = {"ETag": etag, "Cache-Control": IMMUTABLE if v == scene.version else "no-cache"}
    if if_none_match and none_match(if_none_match, etag):
        return Response(status_code=304, headers=headers)
    return _gzipped(scene.body, headers, accept_encoding)


@router.get("/{domain}/{rollout_id}.json", response_class=Response,
            responses={**JSON_RESPONSES, **responses(404, said={404: "no serve library, no such rollout in it, no "
                                                                 "such generated rollout, or a domain without clip "
                                                                 "data"})},
            summary="A rollout's clip as per-frame data the page draws itself (computed on first request, cached)")
async def get_clip_data(domain: Annotated[DomainName, Path()], rollout_id: Annotated[str, Path(max_length=128)],
                        svc: ServicesDep, db: DbDep, if_none_match: Annotated[str | None, Header()] = None,
                        accept_encoding: Annotated[str | None, Header()] = None) -> Response:
    await anyio.to_thread.run_sync(_drawable, svc, domain)
    try:
        clip = await anyio.to_thread.run_sync(svc.sources.resolve, db, domain, rollout_id)
    except UnknownRollout as exc:
        raise not_found(str(exc)) from exc
    key = clip.key.data()
    headers = {"ETag": key.etag, "Cache-Control": "no-cache"}  # as the MP4's: the URL outlives a library rebuild
    if if_none_match and none_match(if_none_match, key.etag):
        return Response(status_code=304, headers=headers)
    source = clip.source(simulate=False)
    if source is None and not svc.clips.cached(key):  # a made clip no longer in memory: simulated again
        source = await anyio.to_thread.run_sync(clip.source)
    try:  # computed on the compute layer (or already in flight there): waiting holds no thread
        path = await asyncio.wrap_future(svc.clips.request(key, source))
    except NoClipData as exc:
        raise not_found(str(exc)) from exc
    body = await anyio.to_thread.run_sync(path.read_bytes)
    return _gzipped(body, headers, accept_encoding)


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
