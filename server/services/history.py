"""A session's history: every fix it made, kept in SQL (``session_fixes``, one row per
applied batch, written off the batch path by ``services.history_writer``) for
``history_retention_days`` after it was made, whether or not the session lives on.

Who reads it: the session's own token while the session lives (as its track), and an API
key with the ``viewer`` scope for the session's site, also once the session ended (the
site is read off the session's SQL row, not its live record). Anyone else is answered as
``GET /v1/sessions/{id}/track`` answers them. Reading flushes this process's unwritten
batches first: a process reads back every fix it answered; another process's reach SQL
within about a second (``FLUSH_S``).

A page goes by seq, and batches reach SQL out of seq order when processes take turns at a
session: A applies seq 10 and holds it for up to ``FLUSH_S`` while B, applying 11, writes
it first. So a page stops before a batch that follows a gap in seq (after ``after_seq``
itself too) and was written less than ``HOLD_S`` ago: the missing batch, applied before
it, would have been written by then had it been kept. The page says no ``more``; asked
again a little later it goes on. Gaps that stay (a batch without fixes, a session rebuilt
at a later seq, batches dropped or lost to a crash) hold nothing back once ``HOLD_S`` has
passed. What this cannot see: a process that could not reach SQL for longer (its writer
backs off, ``services.history_writer``) writes its older batches later, behind a cursor
that moved on; read again from an earlier seq, or after the session ended.

The stored fixes are served as they were stored (the batch's answer, bytes), never decoded
again, except those of a batch across an end of a time window (``from``, ``to``). An
export reads at most ``MAX_EXPORT_FIXES`` fixes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Literal

import anyio
import orjson

from server.services import auth, sessions, track_export
from server.services.errors import Conflict, Invalid, NotFound
from server.services.history_writer import FLUSH_S
from server.services.runtime import Runtime
from server.storage.models import utcnow
from server.storage.repositories import history as repo
from server.storage.repositories import sessions as session_repo
from server.storage.repositories.history import BatchHead, Window

READ_BATCHES = 2000  # batches read per query by an export
MAX_EXPORT_FIXES = 100_000  # about a day of one phone's walking
PURGE_CHUNK = 5000  # batches deleted per transaction by the purge
HOLD_S = 2 * FLUSH_S  # how long a batch past a gap in seq is held back from a page
Form = Literal["geojson", "mfjson"]


@dataclass(frozen=True)
class HistoryPage:
    fixes: bytes  # a JSON array of FixOut, oldest first (whole batches)
    count: int  # the fixes in it
    last_seq: int | None  # the seq of the page's last batch; None for an empty page
    more: bool  # batches past last_seq can be read already


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


def window(from_ms: int | None, to_ms: int | None) -> Window:
    """The window of fix times asked for; Invalid when it ends before it starts."""
    if from_ms is not None and to_ms is not None and to_ms < from_ms:
        raise Invalid(f"to ({to_ms}) is before from ({from_ms})", field="to")
    return Window(from_ms, to_ms)


def page_heads(
    heads: Sequence[BatchHead], previous: int, limit: int, recent: datetime
) -> tuple[list[BatchHead], bool]:
    """Of the batches of a page's query (seq order, ``limit`` + 1 of them at most; the
    batch kept before them is ``previous``, or the page's ``after_seq``), those of the
    page: whole batches, at most ``limit`` fixes (the first batch whole, however many it
    holds), none from the first one written after ``recent`` that follows a gap in seq
    (module docstring); and whether the next page can be read already."""
    taken: list[BatchHead] = []
    fixes = 0
    for head in heads:
        if head.seq != previous + 1 and head.created_at > recent:
            return taken, False  # a batch before it may be on its way
        if taken and fixes + head.n_fixes > limit:
            return taken, True
        taken.append(head)
        fixes += head.n_fixes
        previous = head.seq
    return taken, False


def _in_window(head: BatchHead, body: bytes, within: Window) -> tuple[bytes, int]:
    """The batch's fixes in the window, as the inside of a JSON array, and how many."""
    if within.holds(head.t_first_ms, head.t_last_ms):
        return body[1:-1], head.n_fixes
    kept = [fix for fix in orjson.loads(body) if within.has(fix["t"])]
    return orjson.dumps(kept)[1:-1], len(kept)


async def page(
    rt: Runtime, session_id: str, secret: str, after_seq: int, limit: int, within: Window
) -> HistoryPage:
    """The session's fixes of the batches past ``after_seq`` (of the fixes in ``within``),
    in seq order: whole batches, at most ``limit`` fixes unless the first batch alone
    holds more (``page_heads``)."""
    await authorize(rt, session_id, secret)
    await rt.history.flush(rt.transaction)
    recent = utcnow() - timedelta(seconds=HOLD_S)
    async with rt.read() as s:
        heads = await repo.batch_heads(s, session_id, after_seq, within, limit + 1)
        previous = after_seq
        if within.from_ms is not None and heads and heads[0].seq != after_seq + 1:
            # the batches before the window are no gap
            previous = await repo.seq_before(s, session_id, heads[0].seq, after_seq)
        taken, more = page_heads(heads, previous, limit, recent)
        rows = await repo.fixes_between(s, session_id, taken[0].seq, taken[-1].seq) if taken else []
    by_seq = {head.seq: head for head in taken}
    parts: list[bytes] = []
    count = 0
    for seq, body in rows:
        head = by_seq.get(seq)
        if head is None:
            continue  # written since the heads were read
        inside, n = _in_window(head, body, within)
        if n:
            parts.append(inside)
            count += n
    last_seq = taken[-1].seq if taken else None
    return HistoryPage(b"[" + b",".join(parts) + b"]", count, last_seq, more)


async def _all_batches(rt: Runtime, session_id: str, within: Window) -> list[bytes]:
    """The JSON arrays of fixes of every batch kept of the session with a fix in
    ``within``, in seq order."""
    bodies: list[bytes] = []
    after = 0
    while True:
        async with rt.read() as s:
            rows = await repo.fixes_of(s, session_id, after, within, READ_BATCHES)
        bodies += [body for _, body in rows]
        if len(rows) < READ_BATCHES:
            return bodies
        after = rows[-1][0]


async def export(rt: Runtime, session_id: str, secret: str, form: Form, within: Window) -> bytes:
    """The session's history (its fixes in ``within``) as GeoJSON (``form`` "geojson") or
    MF-JSON ("mfjson"), encoded (``services.track_export``); Invalid past
    ``MAX_EXPORT_FIXES``; Conflict naming the building when its fixes have no WGS84
    position."""
    await authorize(rt, session_id, secret)
    await rt.history.flush(rt.transaction)
    async with rt.read() as s:
        n = await repo.count_fixes(s, session_id, within)
    if n > MAX_EXPORT_FIXES:
        raise Invalid(
            f"the session's history holds {n} fixes in the time asked for; an export holds "
            f"at most {MAX_EXPORT_FIXES}: ask for part of it with from and to (ms since the "
            f"epoch), or page through GET /v1/sessions/{session_id}/history",
            field="to",
        )
    bodies = await _all_batches(rt, session_id, within)
    build = track_export.geojson_track if form == "geojson" else track_export.mfjson_track

    def encode() -> bytes:
        fixes = [fix for body in bodies for fix in orjson.loads(body) if within.has(fix["t"])]
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
    for None), ``PURGE_CHUNK`` batches a transaction; how many batches."""
    days = rt.settings.history_retention_days
    if days is None:
        return 0
    before = utcnow() - timedelta(days=days) if days > 0 else None
    total = 0
    while True:
        async with rt.transaction() as s:
            gone = await repo.delete_fixes(s, before, PURGE_CHUNK)
        total += gone
        if gone < PURGE_CHUNK:
            return total
