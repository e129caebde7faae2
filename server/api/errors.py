"""Error responses: every 4xx names the field it is about.

Body: ``{"detail": [{"loc": [...], "msg": ..., "type": ...}], "message": "field: text"}``.
A failure talking to a store (Redis, the database, the upload queue) is counted in
``indoorpos_store_errors_total`` and answered 503 with ``Retry-After``; any other
unexpected error stays a 500.
"""

from __future__ import annotations

import logging
from typing import Any

import orjson
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException
from starlette.routing import Match
from starlette.types import Send

from server.api.deps import client_address
from server.services import limits, telemetry
from server.services.errors import ServiceError, TooMany

logger = logging.getLogger(__name__)
STORE_RETRY_AFTER_S = 1


def _field(loc: tuple[Any, ...] | list[Any]) -> str:
    parts = [str(p) for p in loc if p not in ("body", "query", "path", "header")]
    return ".".join(parts) or "body"


# pydantic puts the tag of a tagged-union member into the location ("events", 1, "step",
# "length_m"); clients think of it as events.1.length_m
EVENT_TAGS = frozenset({"step", "wifi", "ble", "mag", "imu", "gnss"})


def _clean_loc(loc: tuple[Any, ...] | list[Any]) -> list[Any]:
    out: list[Any] = []
    for item in loc:
        after_event = len(out) >= 2 and isinstance(out[-1], int) and out[-2] == "events"
        if item in EVENT_TAGS and after_event:
            continue
        out.append(item)
    return out


def validation_detail(errors: list[Any]) -> dict[str, Any]:
    detail = []
    for err in errors:
        loc = _clean_loc(err.get("loc", ()))
        msg = err.get("msg", "invalid")
        if err.get("type") == "union_tag_invalid":
            loc.append("type")
        elif err.get("type") == "json_invalid":  # FastAPI puts the character offset in loc
            offset = loc[1] if len(loc) > 1 else None
            loc = ["body"]
            msg = f"{msg} (the body is not JSON; at character {offset})"
        detail.append({"loc": loc, "msg": msg, "type": err.get("type")})
    message = "; ".join(f"{_field(d['loc'])}: {d['msg']}" for d in detail[:5])
    return {"detail": detail, "message": message}


def problem(field: str, msg: str, kind: str) -> dict[str, Any]:
    """The error body about one field (dotted path)."""
    return {
        "detail": [{"loc": field.split("."), "msg": msg, "type": kind}],
        "message": f"{field}: {msg}",
    }


async def send_closing_problem(send: Send, status: int, field: str, msg: str, kind: str) -> None:
    """Answer ``status`` with the error body about ``field`` straight through ASGI, and
    close the connection after it (for middleware that refuses a request mid-body)."""
    body = orjson.dumps(problem(field, msg, kind))
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                (b"connection", b"close"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


def service_detail(exc: ServiceError) -> dict[str, Any]:
    return problem(exc.field or "request", exc.message, type(exc).__name__)


async def _on_validation(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    return JSONResponse(validation_detail(list(exc.errors())), status_code=422)


async def _on_service(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ServiceError)
    if exc.status in (401, 403) and exc.field == "authorization":
        # a wrong key or session token: counted per address, refused once too many
        try:
            await limits.check_auth_failure(request.app.state.runtime, client_address(request))
        except TooMany as refused:
            exc = refused
    headers = {"WWW-Authenticate": "Bearer"} if exc.status == 401 else None
    if isinstance(exc, TooMany):
        headers = {"Retry-After": str(exc.retry_after_s)}
    return JSONResponse(service_detail(exc), status_code=exc.status, headers=headers)


async def _on_store_error(_request: Request, exc: Exception) -> JSONResponse:
    store = telemetry.count_store_error(exc)
    if store is None:
        raise exc  # not a store failure: the usual 500, logged by the server
    logger.warning("the %s store failed", store, exc_info=exc)
    msg = f"the {store} store is unavailable; retry later"
    return JSONResponse(
        problem("request", msg, "StoreUnavailable"),
        status_code=503,
        headers={"Retry-After": str(STORE_RETRY_AFTER_S)},
    )


# what the framework itself refuses (no route, wrong method, a body that is not JSON or
# not UTF-8, nested past the parser's depth): the field it is about
HTTP_FIELDS = {400: "body", 404: "path", 405: "method", 413: "body", 415: "content-type"}


async def _on_http(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, HTTPException)
    field = HTTP_FIELDS.get(exc.status_code, "request")
    msg = str(exc.detail) if exc.detail else "refused"
    if exc.status_code == 400 and "parsing the body" in msg:
        msg = "the body is not valid JSON (bad UTF-8, a syntax error or nesting too deep)"
    body = problem(field, msg[:1].lower() + msg[1:], "HTTPError")
    headers = dict(exc.headers or {})
    if exc.status_code == 405:
        headers["Allow"] = ", ".join(allowed_methods(request))
    return JSONResponse(body, status_code=exc.status_code, headers=headers or None)


METHODS = ("DELETE", "GET", "HEAD", "PATCH", "POST", "PUT")


def allowed_methods(request: Request) -> list[str]:
    """Every method some route takes at the request's path (the router's own 405 names
    only the first route's, where one path has a route per method): each method asked
    of the router's routes as the request with that method."""
    routes = request.app.router.routes
    return [
        method
        for method in METHODS
        if any(r.matches({**request.scope, "method": method})[0] is Match.FULL for r in routes)
    ]


async def _on_unexpected(_request: Request, _exc: Exception) -> JSONResponse:
    # logged with its traceback by the server (Starlette re-raises after answering)
    msg = "internal error; nothing of this request can be assumed applied: retry it"
    return JSONResponse(problem("request", msg, "InternalError"), status_code=500)


def install(app: FastAPI) -> None:
    app.add_exception_handler(HTTPException, _on_http)
    app.add_exception_handler(Exception, _on_unexpected)
    app.add_exception_handler(RequestValidationError, _on_validation)
    app.add_exception_handler(ServiceError, _on_service)
    for error_type in telemetry.STORE_ERROR_TYPES:
        app.add_exception_handler(error_type, _on_store_error)
