"""WebSocket ``/v1/sessions/{id}/live``: every new fix of the session, as it is made.

Who may open it: the session's own token, or an API key with the ``viewer`` scope for the
session's site (a console following a floor's walkers), which follows only: batches it
sends are refused. The credential never goes in the URL (URLs end up in logs): it comes
as a bearer ``Authorization`` header, or, from a browser (which cannot set headers on a
socket), as the first message ``{"type": "auth", "token": "..."}`` within
``AUTH_TIMEOUT_S``. The old ``?token=`` query parameter is refused unless
``INDOORPOS_LIVE_QUERY_TOKEN`` is set (deprecated; ``server.logs`` scrubs it from every
log line either way).
Messages out: ``{"type": "ready"}`` once the socket follows the session (fixes
of batches posted after it are never missed), ``{"type": "fix", "seq", "fix"}``,
``{"type": "zone", "session_id", "seq", "event"}`` after the fix that confirmed a zone
entry or exit (``event`` as the fix's ``zone_events`` hold it),
``{"type": "navigation", "session_id", "seq", "event"}`` after a fix whose navigation
re-routed, changed floor or arrived (``event`` as its ``navigation.events`` hold it),
``{"type": "batch_result", ...}`` (the fields of a batch's HTTP answer) for batches sent
over the socket, and ``{"type": "error", "status", "detail", "message"}`` (with the
``seq`` of the batch it answers, when it answers one).
Fan-out goes through the session store's pub/sub, so any replica can serve the socket.
A socket opened with an API key is closed (an ``error`` message with status 401, then
code 4401) within a second once the key is revoked or rotated, through any replica
(``server.services.revocations``); an ended session closes its sockets with 1000.
"""

from __future__ import annotations

import contextlib
import logging
from typing import Annotated, Any, Literal

import anyio
import orjson
from fastapi import APIRouter, Depends, Query, WebSocket, WebSocketDisconnect
from pydantic import Field, ValidationError
from uvicorn.protocols.utils import ClientDisconnected

from server.api.convert import to_events
from server.api.deps import IdPath, client_address, get_ws_runtime
from server.api.errors import problem, service_detail, validation_detail
from server.api.gated_route import GatedRoute
from server.api.schemas.common import StrictIn
from server.api.schemas.sessions import LiveBatch
from server.logs import session_context
from server.services import batches, limits, revocations, sessions, telemetry
from server.services.errors import ServiceError, Unauthorized
from server.services.runtime import Runtime

router = APIRouter(prefix="/v1/sessions", tags=["sessions"], route_class=GatedRoute)

CLOSE_CODES = {401: 4401, 403: 4403, 404: 4404, 429: 4429}
# what a send or receive raises once the client has gone
GONE = (WebSocketDisconnect, ClientDisconnected, RuntimeError)
logger = logging.getLogger(__name__)


class _Socket:
    """Serialises sends from the forwarder and the reader onto one socket."""

    def __init__(self, ws: WebSocket) -> None:
        self.ws = ws
        self.lock = anyio.Lock()

    async def send(self, message: dict[str, Any]) -> None:
        async with self.lock:
            await self.ws.send_text(orjson.dumps(message).decode())

    async def refuse(self, exc: ServiceError) -> None:
        """An ``error`` message for ``exc``, then the close code of its status."""
        async with self.lock:
            message = {"type": "error", "status": exc.status, **service_detail(exc)}
            await self.ws.send_text(orjson.dumps(message).decode())
            await self.ws.close(code=CLOSE_CODES.get(exc.status, 1008))


AUTH_TIMEOUT_S = 10.0
FOLLOW_ONLY = "a key follows the session; only the session's token sends batches"
KEY_STOPPED = "the key that opened this socket was revoked or rotated"
KEY_STOPPED_SEND_S = 0.5  # what the refusal of a stopped key may take to go out


class AuthMessage(StrictIn):
    type: Literal["auth"]
    token: Annotated[str, Field(min_length=1, max_length=256)]


async def _token(ws: WebSocket, query_token: str | None, allow_query: bool) -> str:
    header = ws.headers.get("authorization", "")
    if header.lower().startswith("bearer ") and header[7:].strip():
        return header[7:].strip()
    if query_token:
        if allow_query:
            return query_token
        raise Unauthorized(
            "a token in the URL is refused (URLs are logged): send it as a bearer header "
            'or as the first message {"type": "auth", "token": ...}',
            field="token",
        )
    with anyio.move_on_after(AUTH_TIMEOUT_S):
        message = await ws.receive()
        if message["type"] == "websocket.disconnect":
            raise WebSocketDisconnect(message.get("code", 1000))
        text = message.get("text") or (message.get("bytes") or b"").decode("utf-8", "replace")
        try:
            return AuthMessage.model_validate_json(text).token
        except ValidationError:
            raise Unauthorized(
                'the first message must be {"type": "auth", "token": ...}', field="token"
            ) from None
    raise Unauthorized(f"no token within {AUTH_TIMEOUT_S:.0f} s", field="token")


@router.websocket("/{session_id}/live")
async def live(
    websocket: WebSocket,
    session_id: IdPath,
    rt: Annotated[Runtime, Depends(get_ws_runtime)],
    token: Annotated[
        str | None, Query(deprecated=True, description="refused unless enabled; use a header")
    ] = None,
) -> None:
    with session_context(session_id):  # every log line of the socket names the session
        await _serve(websocket, session_id, rt, token)


async def _serve(websocket: WebSocket, session_id: str, rt: Runtime, token: str | None) -> None:
    await websocket.accept()
    sock = _Socket(websocket)
    address = client_address(websocket)
    try:
        await limits.refuse_failing_address(rt, address)
        secret = await _token(websocket, token, rt.settings.live_query_token)
        try:
            owner = await sessions.authorize_reader(rt, session_id, secret)
        except ServiceError:
            await limits.check_auth_failure(rt, address)  # TooMany past the limit
            raise
    except ServiceError as exc:
        with contextlib.suppress(*GONE):
            await sock.refuse(exc)
        return
    except GONE:
        return
    # a key's socket ends when the key stops working; the session's own token is not a key
    key = revocations.watch(rt, secret) if not owner else contextlib.nullcontext(anyio.Event())
    async with key as key_stopped:
        if key_stopped.is_set():  # revoked since it was let in: refused, never ready
            with contextlib.suppress(*GONE):
                await sock.refuse(Unauthorized(KEY_STOPPED, field="authorization"))
            return
        await _follow(sock, rt, session_id, secret, owner, key_stopped)


async def _follow(
    sock: _Socket,
    rt: Runtime,
    session_id: str,
    secret: str,
    owner: bool,
    key_stopped: anyio.Event,
) -> None:
    """Push the session's fixes and read batches until the client goes, the session
    ends (1000) or ``key_stopped`` is set (4401)."""
    websocket = sock.ws
    async with sessions.follow(rt, session_id) as messages, anyio.create_task_group() as tg:
        # the subscription is live from here on: tell the client nothing will be missed
        await sock.send({"type": "ready", "session_id": session_id})

        forwarding = anyio.CancelScope()

        async def forward() -> None:
            # the client may be gone by the time a fix arrives: that ends the socket quietly
            with forwarding, contextlib.suppress(*GONE):
                async for message in messages:
                    if message.get("closed"):
                        break
                    for fix in message["fixes"]:
                        await sock.send({"type": "fix", "seq": message["seq"], "fix": fix})
                        for event in fix.get("zone_events", ()):
                            await sock.send(zone_message(session_id, message["seq"], event))
                        for event in (fix.get("navigation") or {}).get("events", ()):
                            await sock.send(navigation_message(session_id, message["seq"], event))
                    for event in message.get("zone_events", ()):  # the session ended inside
                        await sock.send(zone_message(session_id, message["seq"], event))
                await websocket.close(code=1000)
            if not forwarding.cancel_called:
                tg.cancel_scope.cancel()

        async def end_when_key_stops() -> None:
            await key_stopped.wait()
            # a client that stopped reading may hold the socket's lock in a send of fixes:
            # those stop first, and the refusal gets a bounded time to go out
            forwarding.cancel()
            with anyio.move_on_after(KEY_STOPPED_SEND_S), contextlib.suppress(*GONE):
                await sock.refuse(Unauthorized(KEY_STOPPED, field="authorization"))
            tg.cancel_scope.cancel()

        tg.start_soon(forward)
        tg.start_soon(end_when_key_stops)
        with contextlib.suppress(*GONE):
            await _read(sock, rt, session_id, secret, owner)
        tg.cancel_scope.cancel()


def navigation_message(session_id: str, seq: int, event: dict[str, Any]) -> dict[str, Any]:
    """A navigation event (rerouted, floor_change, arrived) as the socket sends it, after
    the fix that made it."""
    return {"type": "navigation", "session_id": session_id, "seq": seq, "event": event}


def zone_message(session_id: str, seq: int, event: dict[str, Any]) -> dict[str, Any]:
    """A zone event as the socket sends it, after the fix that confirmed it."""
    return {"type": "zone", "session_id": session_id, "seq": seq, "event": event}


async def _read(sock: _Socket, rt: Runtime, session_id: str, secret: str, owner: bool) -> None:
    """Batches sent over the socket, applied in turn; ``owner``: the socket was opened
    with the session's token (a key's socket follows only)."""
    while True:
        message = await sock.ws.receive()
        if message["type"] == "websocket.disconnect":
            return
        text = message.get("text")
        if text is None:
            text = (message.get("bytes") or b"").decode("utf-8", errors="replace")
        try:
            batch = LiveBatch.model_validate_json(text)
        except ValidationError as exc:
            errors = [dict(e) for e in exc.errors()]
            await sock.send({"type": "error", "status": 422, **validation_detail(errors)})
            continue
        if not owner:
            detail = problem("authorization", FOLLOW_ONLY, "Forbidden")
            await sock.send({"type": "error", "status": 403, "seq": batch.seq, **detail})
            continue
        try:
            events = to_events(batch.events)
            result = await batches.apply_batch(
                rt, session_id, secret, batch.seq, events, client_address(sock.ws)
            )
        except ServiceError as exc:
            detail = service_detail(exc)
            await sock.send({"type": "error", "status": exc.status, "seq": batch.seq, **detail})
            continue
        except Exception as exc:  # one bad batch must not end the socket
            telemetry.count_store_error(exc)
            logger.exception("batch over the live socket failed")
            text = "internal error; the batch may not have been applied: send the same seq"
            await sock.send({"type": "error", "status": 500, "seq": batch.seq, "message": text})
            continue
        telemetry.count_batch(
            "ws", events, result, session_id=session_id, idle_s=rt.settings.session_idle_s
        )
        await sock.send(
            {
                "type": "batch_result",
                "session_id": session_id,
                "seq": result.seq,
                "replayed": result.replayed,
                "fixes": orjson.Fragment(result.fixes),
                "reinitialised": result.reinitialised,
                "not_used": result.not_used,
            }
        )
