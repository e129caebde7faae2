"""Device routes: positioning sessions and their batches."""

from __future__ import annotations

import orjson
from fastapi import APIRouter, Response, status

from server.api.convert import to_events
from server.api.deps import AddressDep, BearerDep, Device, IdPath, RuntimeDep
from server.api.schemas.sessions import (
    BatchIn,
    BatchOut,
    FixOut,
    SessionCreate,
    SessionCreated,
    SessionRead,
)
from server.logs import session_context
from server.services import limits, sessions, telemetry

router = APIRouter(prefix="/v1/sessions", tags=["sessions"])


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
    )
    telemetry.touch_session(created.id, created.idle_timeout_s)
    return SessionCreated(
        id=created.id,
        token=created.token,
        site_id=created.site_id,
        engine=created.engine,
        idle_timeout_s=created.idle_timeout_s,
    )


@router.post("/{session_id}/batches", response_model=BatchOut)
async def post_batch(
    session_id: IdPath, body: BatchIn, rt: RuntimeDep, token: BearerDep, address: AddressDep
) -> Response:
    """Apply the next batch of the session; its fixes in the answer. The answer is written
    straight from the fixes the service made (already in the ``FixOut`` shape), without a
    second validation on the way out."""
    with session_context(session_id):
        events = to_events(body.events)
        result = await sessions.apply_batch(rt, session_id, token, body.seq, events, address)
        telemetry.count_batch(
            "http", events, result, session_id=session_id, idle_s=rt.settings.session_idle_s
        )
    answer = {
        "session_id": session_id,
        "seq": result.seq,
        "replayed": result.replayed,
        "fixes": result.fixes,
        "reinitialised": result.reinitialised,
    }
    return Response(orjson.dumps(answer), media_type="application/json")


@router.get("/{session_id}")
async def get_session(session_id: IdPath, rt: RuntimeDep, token: BearerDep) -> SessionRead:
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


@router.delete("/{session_id}", status_code=status.HTTP_204_NO_CONTENT)
async def end_session(session_id: IdPath, rt: RuntimeDep, token: BearerDep) -> Response:
    """End the session. A session opened with ``contribute`` leaves its walk to the map
    builder: the ``Location`` header names the upload made of it."""
    with session_context(session_id):
        upload_id = await sessions.end_session(rt, session_id, token)
    telemetry.forget_session(session_id)
    headers = {"Location": f"/v1/uploads/{upload_id}"} if upload_id else None
    return Response(status_code=status.HTTP_204_NO_CONTENT, headers=headers)
