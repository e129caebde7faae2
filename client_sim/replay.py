"""Replay recorded traces through a running service over HTTP.

Used to show that the figures of an in-process evaluation also come out of the API: the
training scans go up as a survey (the server grids them into its radio map), with the floor
plans and the training magnetometer samples for engines that read them, then each
test trace is posted as batches of one session and the fixes of every answer are kept.
Everything crosses the wire as JSON in the service's own format.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import httpx

from client_sim.api import ApiClient
from client_sim.survey import survey_bodies

REQUEST_TIMEOUT_S = 30.0
MAGNETIC_POINTS_PER_REQUEST = 50_000


async def replay_over_http(
    base_url: str,
    admin_key: str,
    *,
    site_name: str,
    levels: Sequence[int],
    survey_points: Sequence[Mapping[str, Any]],
    engine: str,
    traces: Sequence[Sequence[Sequence[Mapping[str, Any]]]],
    plans: Mapping[int, Mapping[str, Any]] | None = None,
    magnetic_points: Mapping[int, Sequence[Mapping[str, Any]]] | None = None,
    on_progress: Callable[[str, int, int], None] | None = None,
    concurrency: int = 4,
) -> list[list[dict[str, Any]]]:
    """Provision a site with ``levels``, their floor ``plans`` (GeoJSON by level), the
    survey and the ``magnetic_points`` (``MagneticPointIn`` bodies by level), replay each
    trace (a list of batches, each a list of wire events) in its own session; the fixes
    per trace."""
    async with httpx.AsyncClient(base_url=base_url, timeout=REQUEST_TIMEOUT_S) as http:
        api = ApiClient(http, admin_key)
        site = await api.create_site(site_name)
        building = await api.create_building(site["id"], site_name)
        floor_ids = {}
        for level in levels:
            floor = await api.create_floor(building["id"], level, f"level {level}")
            floor_ids[level] = floor["id"]
            if plans and level in plans:
                await api.put_plan(floor["id"], plans[level])
        magnetic = magnetic_points or {}
        for done, (level, points) in enumerate(magnetic.items(), start=1):
            for start in range(0, len(points), MAGNETIC_POINTS_PER_REQUEST):
                chunk = list(points[start : start + MAGNETIC_POINTS_PER_REQUEST])
                await api.post_magnetic_survey(floor_ids[level], {"points": chunk})
            if on_progress:
                on_progress("magnetic survey upload", done, len(magnetic))
        bodies = list(survey_bodies([dict(p) for p in survey_points]))
        for done, body in enumerate(bodies, start=1):
            await api.post_survey(building["id"], body)
            if on_progress:
                on_progress("survey upload", done, len(bodies))

        gate = asyncio.Semaphore(concurrency)
        finished = 0

        async def one(batches: Sequence[Sequence[Mapping[str, Any]]]) -> list[dict[str, Any]]:
            nonlocal finished
            async with gate:
                session = await api.create_session(site["id"], engine)
                fixes: list[dict[str, Any]] = []
                for seq, batch in enumerate(batches, start=1):
                    result = await api.post_batch(session, seq, list(batch))
                    fixes += [dict(f.raw) for f in result.fixes]
                await api.delete_session(session)
            finished += 1
            if on_progress:
                on_progress("replay over HTTP", finished, len(traces))
            return fixes

        return list(await asyncio.gather(*(one(t) for t in traces)))
