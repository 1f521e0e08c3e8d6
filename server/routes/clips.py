"""GET /api/clips/{domain}/{rollout_id}.mp4: a rollout of the serve library as H.264 video (and ``/status``:
how far its render is, for the page's progress while a person waits).

The rollout id is looked up in the library (404 if absent) and never used as a path. The
file is rendered on first request and cached; responses carry a content ETag and honour
``If-None-Match`` (304) and ``Range`` (206, so browsers can seek and stream).
"""

from __future__ import annotations

import asyncio
from typing import Annotated

import anyio
from fastapi import APIRouter, Header, Path, Response
from fastapi.responses import FileResponse

from rba.library import LibraryNotFoundError
from server.deps import ServicesDep
from server.errors import not_found
from server.models import ClipStatusPublic
from server.views import clip_status

router = APIRouter(prefix="/api/clips", tags=["clips"])


@router.get("/{domain}/{rollout_id}.mp4", response_class=FileResponse,
            responses={200: {"content": {"video/mp4": {}}, "description": "the clip"},
                       206: {"description": "the requested byte range"}, 304: {"description": "not modified"},
                       404: {"description": "unknown domain or rollout id"}},
            summary="A rollout's clip as MP4 (rendered on first request, then cached)")
async def get_clip(domain: Annotated[str, Path(max_length=64)], rollout_id: Annotated[str, Path(max_length=128)],
                   svc: ServicesDep, if_none_match: Annotated[str | None, Header()] = None) -> Response:
    await anyio.to_thread.run_sync(svc.catalog.domain, domain)  # the first call imports the simulator
    try:
        library = await anyio.to_thread.run_sync(svc.catalog.library, domain)
    except LibraryNotFoundError as exc:
        raise not_found(str(exc)) from exc
    if rollout_id not in library:
        raise not_found(f"unknown rollout id {rollout_id!r} in {domain}/serve; ids look like {library.ids[0]}")
    key = svc.clips.key(library, rollout_id)
    # The URL outlives a library rebuild; the ETag (a hash of the key) does not: browsers revalidate.
    headers = {"ETag": key.etag, "Cache-Control": "no-cache"}
    if if_none_match and key.etag in {t.strip() for t in if_none_match.split(",")}:
        return Response(status_code=304, headers=headers)
    # Rendered on the compute layer (or already in flight there): waiting holds no thread.
    path = await asyncio.wrap_future(svc.clips.request(key, library))
    return FileResponse(path, media_type="video/mp4", headers=headers)


router.add_api_route("/{domain}/{rollout_id}.mp4", get_clip, methods=["HEAD"], include_in_schema=False)


@router.get("/{domain}/{rollout_id}/status", response_model=ClipStatusPublic,
            responses={404: {"description": "unknown domain or rollout id"}},
            summary="How far a clip's render is: ready, queued, rendering (elapsed and typical seconds) or absent")
def get_clip_status(domain: Annotated[str, Path(max_length=64)], rollout_id: Annotated[str, Path(max_length=128)],
                    svc: ServicesDep) -> ClipStatusPublic:
    return clip_status(svc, domain, rollout_id)
