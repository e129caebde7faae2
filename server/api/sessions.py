"""Device routes: positioning sessions and their batches; reading and listing them with a
``viewer`` key (``services.sessions`` says who may do what)."""

from __future__ import annotations

import json
from collections.abc import Callable, Coroutine
from email.message import Message
from typing import Annotated, Any

import orjson
from fastapi import APIRouter, Depends, HTTPException, Query, Request, Response, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import ValidationError

from server.api.convert import to_events
from server.api.deps import (
    BEFORE_BODY,
    ID,
    AddressDep,
    BearerDep,
    Device,
    IdPath,
    PageQuery,
    RuntimeDep,
    Viewer,
    client_address,
    get_bearer,
    page_query,
)
from server.api.gated_route import GatedRoute
from server.api.schemas.common import EARLIEST_MS, ID_PATTERN, LATEST_MS
from server.api.schemas.history import SessionHistory, TrackGeoJSON, TrackMovingFeatures
from server.api.schemas.pages import CREATED, encode_cursor
from server.api.schemas.sessions import (
    BatchIn,
    BatchOut,
    FixOut,
    SessionCreate,
    SessionCreated,
    SessionList,
    SessionRead,
    SessionSummary,
    SessionTrack,
)
from server.logs import session_context
from server.services import batches, history, limits, sessions, telemetry
from server.services.runtime import Runtime

router = APIRouter(prefix="/v1/sessions", tags=["sessions"], route_class=GatedRoute)
SessionPage = Annotated[PageQuery, page_query("sessions", CREATED)]
MAX_TRACK = 5000  # Settings.session_track_len's bound


@router.post("", status_code=status.HTTP_201_CREATED)
async def create_session(
    body: SessionCreate, rt: RuntimeDep, principal: Device, address: AddressDep
) -> SessionCreated:
    """Open a session with a ``device`` key (``contribute`` too for ``contribute: true``)."""
    principal.require("device", body.site_id)
    if body.contribute:
        principal.require("contribute", body.site_id)
    await limits.check(rt, "sessions", address, principal.key_id)
    created = await sessions.create_session(
        rt,
        body.site_id,
        body.engine,
        contribute=body.contribute,
        device_model=body.device_model,
        params=body.params,
        seed=body.seed,
    )
    telemetry.touch_session(created.id, created.idle_timeout_s)
    return SessionCreated(
        id=created.id,
        token=created.token,
        site_id=created.site_id,
        engine=created.engine,
        idle_timeout_s=created.idle_timeout_s,
    )


async def session_token(request: Request, rt: RuntimeDep, token: BearerDep) -> str:
    """The token of the session the path names, checked (before the batch's body is read;
    an id that is not one is refused first, 422 naming it)."""
    if getattr(request.state, "session_token", None) != token:
        session_id = request.path_params["session_id"]
        if not ID.fullmatch(session_id):
            msg = f"String should match pattern '{ID.pattern}'"
            error = {"loc": ("path", "session_id"), "msg": msg, "type": "string_pattern_mismatch"}
            raise RequestValidationError([error])
        with session_context(session_id):
            await sessions.check_token(rt, session_id, token)
        request.state.session_token = token
    return token


async def _session_token_before_body(request: Request) -> str:
    token: str = await BEFORE_BODY[get_bearer](request)
    return await session_token(request, request.app.state.runtime, token)


BEFORE_BODY[session_token] = _session_token_before_body
SessionToken = Annotated[str, Depends(session_token)]


async def post_batch(
    session_id: IdPath, body: BatchIn, rt: RuntimeDep, token: SessionToken, address: AddressDep
) -> Response:
    """Apply the next batch of the session; its fixes in the answer. The answer is written
    straight from the fixes the service made (already in the ``FixOut`` shape), without a
    second validation on the way out."""
    with session_context(session_id):
        events = to_events(body.events)
        result = await batches.apply_batch(rt, session_id, token, body.seq, events, address)
        telemetry.count_batch(
            "http", events, result, session_id=session_id, idle_s=rt.settings.session_idle_s
        )
    answer = {
        "session_id": session_id,
        "seq": result.seq,
        "replayed": result.replayed,
        "fixes": orjson.Fragment(result.fixes),
        "reinitialised": result.reinitialised,
        "not_used": result.not_used,
    }
    return Response(orjson.dumps(answer), media_type="application/json")


async def _batch_body(request: Request) -> BatchIn:
    """The body as the framework would read it for ``post_batch`` (JSON only under a JSON
    content type; errors located under ``body``, as it words them), parsed and validated
    in one pass."""
    try:
        raw = await request.body()
    except Exception as e:  # the client went away, or a limit cut the body off (answered)
        raise _unreadable() from e
    if not raw:
        raise RequestValidationError(
            [{"type": "missing", "loc": ("body",), "msg": "Field required", "input": None}]
        )
    content_type = Message()
    content_type["content-type"] = request.headers.get("content-type", "")
    subtype = content_type.get_content_subtype()
    is_json = content_type.get_content_maintype() == "application" and (
        subtype == "json" or subtype.endswith("+json")
    )
    try:
        # not JSON: refused as the framework would (the bytes are no object)
        return BatchIn.model_validate_json(raw) if is_json else BatchIn.model_validate(raw)
    except ValidationError as e:
        if any(error["type"] == "json_invalid" for error in e.errors()):
            return _framework_json(raw)  # its words and its character offset
        raise _in_body(e) from None


def _framework_json(raw: bytes) -> BatchIn:
    """What the framework makes of a body the fast parser refused as JSON."""
    try:
        parsed = json.loads(raw)
    except json.JSONDecodeError as e:
        error = {"type": "json_invalid", "loc": ("body", e.pos), "msg": "JSON decode error"}
        raise RequestValidationError([{**error, "input": {}, "ctx": {"error": e.msg}}]) from None
    except Exception as e:  # not UTF-8, nested too deep
        raise _unreadable() from e
    try:
        return BatchIn.model_validate(parsed)
    except ValidationError as e:
        raise _in_body(e) from None


def _unreadable() -> HTTPException:
    return HTTPException(400, "There was an error parsing the body")  # the framework's words


def _in_body(e: ValidationError) -> RequestValidationError:
    errors = e.errors(include_url=False)
    return RequestValidationError([{**error, "loc": ("body", *error["loc"])} for error in errors])


async def _serve_batch(request: Request) -> Response:
    """``post_batch`` without the framework's run of its dependencies, which costs a
    batch more than the rest of the route (``bench/performance.md``): the credentials
    first, as every gated route does, then the body in one pass."""
    token = await _session_token_before_body(request)
    body = await _batch_body(request)
    return await post_batch(
        request.path_params["session_id"],
        body,
        request.app.state.runtime,
        token,
        client_address(request),
    )


class BatchRoute(GatedRoute):
    """The batch route: documented from ``post_batch``'s signature like any other, served
    by ``_serve_batch``."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        return _serve_batch


router.add_api_route(
    "/{session_id}/batches",
    post_batch,
    methods=["POST"],
    response_model=BatchOut,
    route_class_override=BatchRoute,
)


@router.get("")
async def list_sessions(
    rt: RuntimeDep,
    principal: Viewer,
    page: SessionPage,
    site_id: Annotated[str | None, Query(pattern=ID_PATTERN, description="one site's only")] = None,
    active: Annotated[
        bool | None,
        Query(description="true: active ones only (possibly live); false: ended or idle only"),
    ] = None,
) -> SessionList:
    """Sessions newest first, from their records (a key of one site sees that site's).
    Follow one with a viewer key over GET /v1/sessions/{id}/live."""
    if site_id is not None and not principal.sees(site_id):
        # another site's sessions are as invisible as a site that does not exist
        return SessionList(items=[], count=0, next_cursor=None)
    site_id = site_id or principal.site_id
    found = await sessions.list_sessions(rt, site_id, active, page.after, page.limit)
    items = [SessionSummary.model_validate(x, from_attributes=True) for x in found.rows]
    cursor = encode_cursor("sessions", found.next_key) if found.next_key is not None else None
    return SessionList(items=items, count=len(items), next_cursor=cursor)


@router.get("/{session_id}")
async def get_session(session_id: IdPath, rt: RuntimeDep, token: BearerDep) -> SessionRead:
    """The session's state, for its token or for a key with the viewer scope for its
    site."""
    with session_context(session_id):
        info = await sessions.get_session(rt, session_id, token)
    return SessionRead(
        id=info.id,
        site_id=info.site_id,
        engine=info.engine,
        last_seq=info.last_seq,
        last_fix=FixOut.model_validate(info.last_fix) if info.last_fix else None,
        idle_timeout_s=info.idle_timeout_s,
    )


@router.get("/{session_id}/track")
async def get_track(
    session_id: IdPath,
    rt: RuntimeDep,
    token: BearerDep,
    limit: Annotated[int, Query(ge=1, le=MAX_TRACK, description="newest fixes wanted")] = 200,
) -> SessionTrack:
    """The session's newest fixes, oldest first: at most ``limit``, and at most the
    server keeps (``max_fixes``), for its token or for a key with the viewer scope for
    its site."""
    with session_context(session_id):
        fixes = await sessions.get_track(rt, session_id, token, limit)
    items = [FixOut.model_validate(f) for f in fixes]
    return SessionTrack(items=items, count=len(items), max_fixes=rt.settings.session_track_len)


FromQuery = Annotated[
    int | None,
    Query(
        alias="from",
        ge=EARLIEST_MS,
        lt=LATEST_MS,
        description="fixes at or after this time only, ms since the epoch",
    ),
]
ToQuery = Annotated[
    int | None,
    Query(
        alias="to",
        ge=EARLIEST_MS,
        lt=LATEST_MS,
        description="fixes at or before this time only, ms since the epoch",
    ),
]


@router.get("/{session_id}/history", response_model=SessionHistory)
async def get_history(
    session_id: IdPath,
    rt: RuntimeDep,
    token: BearerDep,
    after_seq: Annotated[
        int, Query(ge=0, lt=2**63, description="last_seq of the previous page; 0: the first")
    ] = 0,
    limit: Annotated[
        int,
        Query(ge=1, le=MAX_TRACK, description="most fixes wanted (a page holds whole batches)"),
    ] = 1000,
    from_ms: FromQuery = None,
    to_ms: ToQuery = None,
) -> Response:
    """Every fix the session made (between ``from`` and ``to``, when given), kept for the
    history's retention (the first batches may have gone before it), a page at a time in
    seq order: for its token while it lives, for a key with the viewer scope for its site
    also once it ended.

    While the session lives, a page stops before a batch that follows a gap in seq and
    was written in the last two seconds (another process may not have written the batch
    before it yet), and says no ``more``: ask again with the same ``after_seq`` a moment
    later. A process cut off from SQL for longer still writes its batches later, behind
    a cursor that moved on: ``last_seq`` is not a safe tail cursor for a live session;
    read again from an earlier seq, or after the session ends. The fixes are served as
    the batches answered them."""
    with session_context(session_id):
        within = history.window(from_ms, to_ms)
        found = await history.page(rt, session_id, token, after_seq, limit, within)
    answer = {
        "items": orjson.Fragment(found.fixes),
        "count": found.count,
        "last_seq": found.last_seq,
        "more": found.more,
        "retention_days": rt.settings.history_retention_days,
    }
    return Response(orjson.dumps(answer), media_type="application/json")


class GeoJSONResponse(JSONResponse):
    """What documents an answer as GeoJSON with its model's schema (the route writes the
    bytes itself, unchecked)."""

    media_type = "application/geo+json"


async def _export(
    rt: Runtime,
    session_id: str,
    token: str,
    form: history.Form,
    from_ms: int | None,
    to_ms: int | None,
) -> Response:
    with session_context(session_id):
        within = history.window(from_ms, to_ms)
        body = await history.export(rt, session_id, token, form, within)
    disposition = f'attachment; filename="session-{session_id}.{form}"'
    headers = {"Content-Disposition": disposition}
    return Response(body, media_type=GeoJSONResponse.media_type, headers=headers)


@router.get(
    "/{session_id}/track.geojson", response_model=TrackGeoJSON, response_class=GeoJSONResponse
)
async def get_track_geojson(
    session_id: IdPath,
    rt: RuntimeDep,
    token: BearerDep,
    from_ms: FromQuery = None,
    to_ms: ToQuery = None,
) -> Response:
    """The session's history (as GET /v1/sessions/{id}/history, the same readers; between
    ``from`` and ``to`` when given) as RFC 7946 GeoJSON in WGS84: a LineString per run of
    fixes on one floor, with each vertex's time and accuracy. At most 100,000 fixes (422
    past them: ask for less with ``from`` and ``to``); 409 naming the building when it
    had no geo-reference."""
    return await _export(rt, session_id, token, "geojson", from_ms, to_ms)


@router.get(
    "/{session_id}/track.mfjson",
    response_model=TrackMovingFeatures,
    response_class=GeoJSONResponse,
)
async def get_track_mfjson(
    session_id: IdPath,
    rt: RuntimeDep,
    token: BearerDep,
    from_ms: FromQuery = None,
    to_ms: ToQuery = None,
) -> Response:
    """The session's history (between ``from`` and ``to`` when given) as OGC Moving
    Features JSON (a MovingPoint with the fixes' times, linear interpolation; a single
    fix's instant, discrete; accuracy and floor as temporal properties), in WGS84. At
    most 100,000 fixes (422 past them); 409 naming the building when it had no
    geo-reference."""
    return await _export(rt, session_id, token, "mfjson", from_ms, to_ms)


@router.delete("/{session_id}", status_code=status.HTTP_204_NO_CONTENT)
async def end_session(session_id: IdPath, rt: RuntimeDep, token: BearerDep) -> Response:
    """End the session. A session opened with ``contribute`` leaves its walk to the map
    builder: the ``Location`` header names the upload made of it."""
    with session_context(session_id):
        upload_id = await sessions.end_session(rt, session_id, token)
    telemetry.forget_session(session_id)
    headers = {"Location": f"/v1/uploads/{upload_id}"} if upload_id else None
    return Response(status_code=status.HTTP_204_NO_CONTENT, headers=headers)
