"""The FastAPI application factory."""

from __future__ import annotations

import gc
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import anyio
from fastapi import FastAPI
from fastapi.routing import APIRoute
from starlette.middleware.cors import CORSMiddleware

from server import worker
from server.api import (
    admin,
    body_deadline,
    body_limit,
    console,
    engines,
    errors,
    health,
    keys,
    live,
    locate,
    metrics,
    navigation,
    quality,
    routes,
    sessions,
    uploads,
    webhooks,
    zones,
)
from server.api.schemas.errors import ErrorOut
from server.config import Settings, get_settings
from server.positioning.filters import particle_kernels
from server.services import telemetry
from server.services.runtime import open_runtime, writing_history
from server.storage import db

# how long shutdown waits for the in-process worker to finish what it is doing (a queue
# read lasts up to a second); a map build's thread is not stopped: the process exits
# when it ends (its result is not kept; the version is built again)
WORKER_STOP_S = 3.0

DESCRIPTION = (
    "Indoor positioning service. Phones post batches of steps, sensor samples and "
    "WiFi/BLE scans; the server fuses them into fixes per session and pushes them live."
)


# what any route may answer besides its own success (server.api.errors makes each of them);
# JSON also where a route's own answer is not (the GeoJSON exports)
ERROR_OUT = {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorOut"}}}
ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    status: {"model": ErrorOut, "description": description, "content": ERROR_OUT}
    for status, description in {
        400: "the body could not be read",
        401: "no valid key or session token",
        403: "the key or token may not do this (or the session does not exist)",
        404: "no such thing, or no such route",
        405: "the route does not take this method",
        408: "the headers or the body came too slowly (header_timeout_s, body_timeout_s)",
        409: "conflicts with the current state; read it back and retry",
        413: "the body is over the route's limit",
        422: "a field is invalid; the message names it",
        429: "a rate limit was reached; see Retry-After",
        500: "an internal error; nothing of the request can be assumed applied",
        503: "a store is unavailable; see Retry-After",
    }.items()
}


def _operation_id(route: APIRoute) -> str:
    return f"{route.tags[0]}-{route.name}" if route.tags else route.name


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or get_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        if settings.resolved_database_url.startswith("sqlite"):
            # embedded mode keeps itself migrated; the production shape runs `indoorpos migrate`
            await anyio.to_thread.run_sync(db.migrate, settings.resolved_database_url)
        async with (
            open_runtime(settings) as runtime,
            writing_history(runtime),
            anyio.create_task_group() as tasks,
        ):
            app.state.runtime = runtime
            # the compiled particle-filter loops, in the background (seconds when their disk
            # cache is cold): a session that needs one first waits for it, neither start-up
            # nor shutdown does
            threading.Thread(target=particle_kernels.warm_up, name="kernels", daemon=True).start()
            # what start-up made lives as long as the process: keep it out of the garbage
            # collector's full passes, which otherwise walk ~170,000 objects (40-75 ms on
            # the event loop, every few seconds under load; bench/performance.md)
            gc.collect()
            gc.freeze()
            stop, stopped = anyio.Event(), anyio.Event()

            async def run_worker() -> None:
                try:
                    await worker.run(runtime, worker.consumer_name(), stop)
                finally:
                    stopped.set()

            if settings.runs_worker_in_process:
                tasks.start_soon(run_worker)
            else:
                stopped.set()
            yield
            # the worker ends its transaction and stops; cancelled if it takes too long
            stop.set()
            with anyio.move_on_after(WORKER_STOP_S):
                await stopped.wait()
            tasks.cancel_scope.cancel()
        telemetry.process_exited()

    app = FastAPI(
        title="indoorpos",
        version="0.1.0",
        description=DESCRIPTION,
        lifespan=lifespan,
        generate_unique_id_function=_operation_id,
        responses=ERROR_RESPONSES,
        docs_url=None,  # server.api.console serves /docs and /redoc from the package
        redoc_url=None,
    )
    errors.install(app)
    console.install(app)
    routers = (
        health,
        admin,
        engines,
        keys,
        sessions,
        live,
        locate,
        uploads,
        quality,
        zones,
        routes,
        navigation,
        webhooks,
        metrics,
    )
    for module in routers:
        app.include_router(module.router)
    app.add_middleware(
        body_limit.BodyLimit,
        json_max_bytes=settings.json_max_bytes,
        bulk_max_bytes=settings.upload_max_bytes,
    )
    app.add_middleware(
        body_deadline.BodyDeadline,
        timeout_s=settings.body_timeout_s,
        min_rate_bytes_s=settings.body_min_rate_bytes_s,
    )
    app.add_middleware(metrics.RequestTimer)
    if settings.cors_origins:  # outermost: a preflight is answered before anything else
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["GET", "POST", "PUT", "DELETE"],
            allow_headers=["Authorization", "Content-Type", "Content-Encoding", "Idempotency-Key"],
            expose_headers=["Location", "Retry-After"],
            max_age=600,
        )
    _with_hand_read_schemas(app)
    return app


def _with_hand_read_schemas(app: FastAPI) -> None:
    """Add the schemas of bodies read by hand to the OpenAPI document's components."""
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            document = generate()  # FastAPI keeps it as app.openapi_schema
            components = document.setdefault("components", {}).setdefault("schemas", {})
            for name, schema in uploads.openapi_schemas().items():
                components.setdefault(name, schema)
        assert app.openapi_schema is not None
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
