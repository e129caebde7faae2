"""``GET /metrics`` (Prometheus text format, no auth) and the middleware timing requests.

The metrics themselves are defined in ``server.services.telemetry``.
"""

from __future__ import annotations

import time

import anyio
from fastapi import APIRouter, Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.api.gated_route import GatedRoute
from server.services import telemetry

METRICS_PATH = "/metrics"

router = APIRouter(tags=["metrics"], route_class=GatedRoute)


@router.get(METRICS_PATH, include_in_schema=False)
async def metrics() -> Response:
    # off the event loop: rendering ~130 labelled histograms takes about 17 ms
    body, content_type = await anyio.to_thread.run_sync(telemetry.exposition)
    return Response(body, media_type=content_type)


def route_template(scope: Scope) -> str | None:
    """The template of the route that matched (``/v1/sessions/{session_id}``), set in
    ``scope["route"]`` by the router (Starlette, FastAPI); None when nothing matched."""
    route = scope.get("route")
    template = getattr(route, "path_format", None) or getattr(route, "path", None)
    return template if isinstance(template, str) else None


class RequestTimer:
    """Pure ASGI middleware: observes every HTTP request in
    ``indoorpos_http_request_duration_seconds`` with its route template and status (500
    when the app raised before answering). WebSocket scopes and ``/metrics`` pass through."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["path"] == METRICS_PATH:
            await self.app(scope, receive, send)
            return
        status = 500
        start = time.perf_counter()

        async def send_status(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_status)
        finally:
            seconds = time.perf_counter() - start
            telemetry.observe_request(scope["method"], route_template(scope), status, seconds)
