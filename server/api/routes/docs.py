"""GET /docs (Swagger UI) and /redoc (ReDoc) built on assets the app serves itself, so they work offline.

FastAPI's own pages load their scripts from a CDN and stay blank without a network. The scripts,
stylesheet and icon come from the ``fastapi-offline`` package (pinned in pyproject.toml), served
under ``ASSETS_URL``; only its files are used, not its app class.
"""

from __future__ import annotations

from fastapi import APIRouter, FastAPI, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

ASSETS_URL = "/docs-assets"
ASSETS_PACKAGE = ("fastapi_offline", "static")  # swagger-ui-bundle.js, swagger-ui.css, redoc.standalone.js

router = APIRouter(include_in_schema=False)


def _title(request: Request) -> str:
    return f"{request.app.title} — API"


@router.get("/docs")
def swagger_ui(request: Request) -> HTMLResponse:
    return get_swagger_ui_html(openapi_url=request.app.openapi_url, title=_title(request),
                               swagger_js_url=f"{ASSETS_URL}/swagger-ui-bundle.js",
                               swagger_css_url=f"{ASSETS_URL}/swagger-ui.css",
                               swagger_favicon_url=f"{ASSETS_URL}/favicon.png")


@router.get("/redoc")
def redoc(request: Request) -> HTMLResponse:
    return get_redoc_html(openapi_url=request.app.openapi_url, title=_title(request),
                          redoc_js_url=f"{ASSETS_URL}/redoc.standalone.js",
                          redoc_favicon_url=f"{ASSETS_URL}/favicon.png", with_google_fonts=False)


def install(app: FastAPI) -> None:
    """The two pages and their assets; the app must be made with ``docs_url=None, redoc_url=None``."""
    app.include_router(router)
    app.mount(ASSETS_URL, StaticFiles(packages=[ASSETS_PACKAGE]), name="docs-assets")
