"""The web console (``/console/``) and the API's documentation pages (``/docs``,
``/redoc``), served from files inside the package: nothing is fetched from another host,
so all three work on a closed network.

The console is plain ES modules in ``server/console/static`` (no build step); it runs in
the browser and calls this API with the key it asks for. Swagger UI and ReDoc come from
``server/console/static/vendor`` (versions and licences in the NOTICE there). None of
these routes is in the OpenAPI document.
"""

from __future__ import annotations

import os
from pathlib import Path

from fastapi import APIRouter, FastAPI, Request, Response
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from starlette.types import Scope

STATIC_DIR = Path(__file__).resolve().parent.parent / "console" / "static"
STATIC_PATH = "/console/static"
VENDOR_PATH = f"{STATIC_PATH}/vendor"

# the console page: its scripts, styles, images, requests and sockets from this origin only
CONSOLE_POLICY = (
    "default-src 'self'; img-src 'self' data:; base-uri 'none'; form-action 'self'; "
    "frame-ancestors 'none'"
)
# the docs pages run FastAPI's inline start-up script; images only from here (ReDoc's
# sidebar would otherwise ask its vendor's CDN for a logo)
DOCS_POLICY = "img-src 'self' data:"

router = APIRouter(include_in_schema=False)


class _Revalidated(StaticFiles):
    """Static files the browser checks again on every load (a cheap 304 while unchanged),
    so a new release's modules are never mixed with an old one's."""

    def file_response(
        self,
        full_path: str | os.PathLike[str],
        stat_result: os.stat_result,
        scope: Scope,
        status_code: int = 200,
    ) -> Response:
        response = super().file_response(full_path, stat_result, scope, status_code)
        response.headers.setdefault("Cache-Control", "no-cache")
        return response


def _root(request: Request) -> str:
    """The path prefix the app is served under (behind a proxy), empty by default."""
    return str(request.scope.get("root_path", "")).rstrip("/")


@router.get("/")
async def root_redirect() -> RedirectResponse:
    # a browser pointed at the service lands on the console
    return RedirectResponse("console/")


@router.get("/console")
async def console_redirect() -> RedirectResponse:
    # the page's URLs are relative to /console/, so that a path prefix keeps working
    return RedirectResponse("console/")


@router.get("/console/")
async def console_page() -> FileResponse:
    return FileResponse(
        STATIC_DIR / "index.html",
        headers={"Content-Security-Policy": CONSOLE_POLICY, "Cache-Control": "no-cache"},
    )


@router.get("/docs")
async def swagger_ui(request: Request) -> HTMLResponse:
    root = _root(request)
    page = get_swagger_ui_html(
        openapi_url=f"{root}{request.app.openapi_url}",
        title=f"{request.app.title} - Swagger UI",
        swagger_js_url=f"{root}{VENDOR_PATH}/swagger-ui/swagger-ui-bundle.js",
        swagger_css_url=f"{root}{VENDOR_PATH}/swagger-ui/swagger-ui.css",
        swagger_favicon_url=f"{root}{VENDOR_PATH}/swagger-ui/favicon-32x32.png",
        # no badge from the public validator service
        swagger_ui_parameters={"validatorUrl": None},
    )
    page.headers["Content-Security-Policy"] = DOCS_POLICY
    return page


@router.get("/redoc")
async def redoc(request: Request) -> HTMLResponse:
    root = _root(request)
    page = get_redoc_html(
        openapi_url=f"{root}{request.app.openapi_url}",
        title=f"{request.app.title} - ReDoc",
        redoc_js_url=f"{root}{VENDOR_PATH}/redoc/redoc.standalone.js",
        redoc_favicon_url=f"{root}{VENDOR_PATH}/swagger-ui/favicon-32x32.png",
        with_google_fonts=False,
    )
    page.headers["Content-Security-Policy"] = DOCS_POLICY
    return page


def install(app: FastAPI) -> None:
    """Serve the console and the docs pages (the app is made with ``docs_url=None`` and
    ``redoc_url=None``, so that these replace FastAPI's pages, which use a CDN)."""
    app.include_router(router)
    app.mount(STATIC_PATH, _Revalidated(directory=STATIC_DIR), name="console-static")
