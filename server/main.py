"""The FastAPI app (``create_app``) and ``rba serve`` (``run``)."""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager, contextmanager
from pathlib import Path

from fastapi import Depends, FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

from rba.compute import Compute
from server.api.admission import Admission
from server.api.auth import AdminGate, FailureLimiter
from server.api.deps import known_query
from server.api.limits import BodyLimit, Cap
from server.api.routes import (
    admin_datasets,
    admin_labels,
    admin_training,
    clips,
    docs,
    domains,
    interpret,
    participate,
    sessions,
    studies,
)
from server.common import errors
from server.common.app_settings import Settings
from server.db.admin_tables import DatasetUpload
from server.ops.prerender import warm_up
from server.runtime.services import Services

os.environ.setdefault("MUJOCO_GL", "egl")
log = logging.getLogger(__name__)

FRONTEND = Path(__file__).resolve().parents[1] / "frontend"


def create_app(settings: Settings | None = None, compute: Compute | None = None) -> FastAPI:
    """A new app; its database schema, clip cache and background workers start with its lifespan.

    ``compute`` (tests, benchmarks) is used and left running; without it the app makes its own from the settings.
    """
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        svc = Services.start(settings, compute)
        app.state.services = svc
        if settings.warm_start:  # its own thread: the thinker stays free for the first sessions
            svc.warming = threading.Thread(target=warm_up, args=(svc,), name="rba-warm-up", daemon=True)
            svc.warming.start()
        store = svc.store
        log.info("RBA Studio: data %s, models %s, clips %s", store.data_dir, store.models_dir, store.cache_dir)
        try:
            yield
        finally:
            svc.stop()

    app = FastAPI(title="RBA Studio", version="0.1.0", lifespan=lifespan, docs_url=None, redoc_url=None,
                  description="Tune how an agent behaves by saying more / less of an attribute "
                              "(Relative Behavioral Attributes, ICLR 2023).")
    errors.install(app)
    docs.install(app)  # /docs and /redoc on the app's own copies of their scripts: no CDN
    # The last added runs first: the admin token before anything reads a body, then the body cap (the upload
    # streams under its own limit), then the heavy routes' slots (server.api.admission).
    app.add_middleware(Admission, workers=settings.heavy_workers, queue=settings.heavy_queue,
                       per_client=settings.heavy_per_client)
    json_cap = Cap(settings.json_max_bytes, "RBA_JSON_MAX_BYTES", hint="; datasets go to POST /api/admin/datasets")
    upload_cap = Cap(settings.upload_max_bytes, "RBA_UPLOAD_MAX_BYTES", what="upload")
    app.add_middleware(BodyLimit, default=json_cap, routes={("POST", admin_datasets.router.prefix): upload_cap})
    app.add_middleware(AdminGate, token=settings.admin_token,
                       failures=FailureLimiter(settings.admin_failures_per_minute))
    for router in (domains.router, interpret.router, sessions.router, clips.router, admin_labels.router,
                   admin_datasets.router, admin_training.router, studies.router, participate.router):
        app.include_router(router, dependencies=[Depends(known_query)])  # the API's, not the pages' (?utm_… is fine)
    _document_upload_form(app)
    _pages(app)
    return app


def _pages(app: FastAPI) -> None:
    """The pages, their files and the health check (outside the API: no query check, no OpenAPI entry)."""

    @app.get("/healthz", include_in_schema=False)
    def healthz() -> dict[str, str]:
        return {"status": "ok"}

    @app.get("/favicon.ico", include_in_schema=False)
    def favicon() -> FileResponse:
        """Browsers ask for it whatever the page links: an SVG (every current browser reads one here)."""
        return FileResponse(FRONTEND / "favicon.svg", media_type="image/svg+xml")

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(FRONTEND / "index.html", headers={"Cache-Control": "no-cache"})

    @app.get("/admin", include_in_schema=False)
    def admin_page() -> FileResponse:
        """The page itself holds no data: everything on it comes from token-checked /api/admin routes."""
        return FileResponse(FRONTEND / "admin.html", headers={"Cache-Control": "no-cache"})

    @app.get("/study/{token}", include_in_schema=False)
    def study_page(token: str) -> FileResponse:
        """A study participant's page: the same file for every link; the page reads its token from the address and
        calls /api/participate/{token}. No referrer leaves the page, so the token stays in it."""
        del token  # never a path: the page, not the server, uses it
        return FileResponse(FRONTEND / "study.html",
                            headers={"Cache-Control": "no-cache", "Referrer-Policy": "no-referrer"})

    app.mount("/static/vendor", VendorFiles(directory=FRONTEND / "vendor"), name="vendor")  # before /static
    app.mount("/static", StaticFiles(directory=FRONTEND), name="static")


class VendorFiles(StaticFiles):
    """Vendored libraries: each folder's name carries its version (``three-0.187.0``), so a file never changes."""

    async def get_response(self, path: str, scope):  # type: ignore[no-untyped-def]
        response = await super().get_response(path, scope)
        if response.status_code == 200:
            response.headers["Cache-Control"] = "public, max-age=31536000, immutable"
        return response


def _document_upload_form(app: FastAPI) -> None:
    """Add the upload's form (which its route parses itself) to the OpenAPI document when it is first made."""
    make = app.openapi

    def openapi() -> dict:
        if app.openapi_schema is None:
            schemas = make().setdefault("components", {}).setdefault("schemas", {})
            schemas["DatasetUpload"] = DatasetUpload.model_json_schema(ref_template="#/components/schemas/{model}")
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def run(host: str | None = None, port: int | None = None, ray_address: str | None = None) -> None:
    """``rba serve``: uvicorn with the app on ``host:port`` (defaults from the settings), computing on Ray at
    ``ray_address`` if given."""
    import uvicorn

    settings = Settings(**({"ray_address": ray_address} if ray_address else {}))
    logging.basicConfig(level=settings.log_level.upper(), format="%(asctime)s %(name)s %(levelname)s %(message)s",
                        force=True)  # `rba serve` set up the CLI's logging already: RBA_LOG_LEVEL decides here
    uvicorn.run(create_app(settings), host=host or settings.host, port=port or settings.port,
                log_level=settings.log_level.lower())


@contextmanager
def serve_in_thread(settings: Settings, timeout: float = 30.0, compute: Compute | None = None) -> Iterator[str]:
    """The app (on ``compute`` if given) on a free loopback port in a thread of this process (browser tests,
    screenshots); its base URL until the block ends."""
    import uvicorn

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    app = create_app(settings, compute)
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, name="rba-serve-in-thread", daemon=True)
    thread.start()
    deadline = time.monotonic() + timeout
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            raise RuntimeError(f"the server did not start within {timeout:g} s")
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout)
