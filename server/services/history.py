"""A session's history: every fix it made, kept in SQL (``session_fixes``, one row per
applied batch, written off the batch path by ``services.history_writer``) for
``history_retention_days`` after it was made, whether or not the session lives on.

Who reads it: the session's own token while the session lives (as its track), and an API
key with the ``viewer`` scope for the session's site, also once the session ended (the
site is read off the session's SQL row, not its live record). Anyone else is answered as
``GET /v1/sessions/{id}/track`` answers them. Reading flushes this process's unwritten
batches first: a process reads back every fix it answered; another process's reach SQL
within about a second.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta
from typing import Any, Literal

import anyio
import orjson

from server.services import auth, sessions, track_export
from server.services.errors import Conflict, NotFound
from server.services.runtime import Runtime
from server.storage.models import utcnow
from server.storage.repositories import history as repo
from server.storage.repositories import sessions as session_repo

READ_BATCHES = 2000  # batches read per query by an export
Form = Literal["geojson", "mfjson"]


@dataclass(frozen=True)
class HistoryPage:
    fixes: list[dict[str, Any]]  # FixOut, oldest first (whole batches)
    last_seq: int | None  # the seq of the page's last batch; None for an empty page
    more: bool  # batches past last_seq are kept already


async def authorize(rt: Runtime, session_id: str, secret: str) -> None:
    """Let a reader of the session's history in (module docstring), else raise what
    ``sessions.authorize_reader`` raises for the same reader: Forbidden for a token or
    key that may not read it, NotFound for a viewer key and a session unknown or of a
    site the key is not for."""
    try:
        await sessions.authorize_reader(rt, session_id, secret)
        return
    except NotFound:
        pass  # a viewer key, and a session not live: its SQL row says whose it is
    async with rt.read() as s:
        principal = await auth.authenticate(s, rt.settings, secret)
        row = await session_repo.get_session_record(s, session_id)
        site_id = row.site_id if row is not None else None
    missing = NotFound(f"no session {session_id}", field="session_id")
    if principal is None or site_id is None:
        raise missing
    principal.require("viewer", site_id, missing=missing)


async def page(
    rt: Runtime, session_id: str, secret: str, after_seq: int, limit: int
) -> HistoryPage:
    """The session's fixes of the batches past ``after_seq``, in seq order: whole batches,
    at most ``limit`` fixes (unless the first batch alone holds more)."""
    await authorize(rt, session_id, secret)
    await rt.history.flush(rt.transaction)
    async with rt.read() as s:
        rows = await repo.fixes_after(s, session_id, after_seq, limit + 1)
    fixes: list[dict[str, Any]] = []
    last_seq = None
    for seq, body in rows:
        batch = orjson.loads(body)
        if fixes and len(fixes) + len(batch) > limit:
            return HistoryPage(fixes, last_seq, True)
        fixes += batch
        last_seq = seq
    return HistoryPage(fixes, last_seq, len(rows) > limit)


async def _all_batches(rt: Runtime, session_id: str) -> list[bytes]:
    """The JSON arrays of fixes of every batch kept of the session, in seq order."""
    await rt.history.flush(rt.transaction)
    bodies: list[bytes] = []
    after = 0
    while True:
        async with rt.read() as s:
            rows = await repo.fixes_after(s, session_id, after, READ_BATCHES)
        bodies += [body for _, body in rows]
        if len(rows) < READ_BATCHES:
            return bodies
        after = rows[-1][0]


async def export(rt: Runtime, session_id: str, secret: str, form: Form) -> bytes:
    """The session's whole history as GeoJSON (``form`` "geojson") or MF-JSON ("mfjson"),
    encoded (``services.track_export``); Conflict naming the building when its fixes have
    no WGS84 position."""
    await authorize(rt, session_id, secret)
    bodies = await _all_batches(rt, session_id)
    build = track_export.geojson_track if form == "geojson" else track_export.mfjson_track

    def encode() -> bytes:
        fixes = [fix for body in bodies for fix in orjson.loads(body)]
        return orjson.dumps(build(session_id, fixes))

    try:
        # a long history is a lot of dicts: off the event loop (100,000 fixes, about a day
        # of one phone's walking, take seconds)
        return await anyio.to_thread.run_sync(encode)
    except track_export.NoWorldPosition as e:
        where = f"building {e.building_id}" if e.building_id else "a floor of no building"
        raise Conflict(
            f"the session's fixes on {where} have no WGS84 position: the building had no "
            "geo-reference (origin_lat, origin_lon) when they were made. GET "
            f"/v1/sessions/{session_id}/history has them in the floor's frame",
            field="session_id",
        ) from None


async def purge(rt: Runtime) -> int:
    """Delete the history older than ``history_retention_days`` (all of it for 0; nothing
    for None); how many batches."""
    days = rt.settings.history_retention_days
    if days is None:
        return 0
    before = utcnow() - timedelta(days=days) if days > 0 else None
    async with rt.transaction() as s:
        return await repo.delete_fixes(s, before)
