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
UPLOAD_POLL_S = 1.0
MAP_BUILD_TIMEOUT_S = 3600.0
# how long an api process may serve the map set it cached before it asks for a newer
# version (the service's VERSION_CHECK_S)
MAP_REFRESH_S = 2.0


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
    uploads: Sequence[tuple[int, bytes]] = (),
    on_progress: Callable[[str, int, int], None] | None = None,
    concurrency: int = 4,
    upload_reports: list[dict[str, Any]] | None = None,
    params: Mapping[str, Any] | None = None,
) -> list[list[dict[str, Any]]]:
    """``provision_site`` then ``replay_sessions`` in one client: the fixes per trace."""
    async with httpx.AsyncClient(base_url=base_url, timeout=REQUEST_TIMEOUT_S) as http:
        api = ApiClient(http, admin_key, wait_when_limited=True)
        site_id = await provision_site(
            api,
            site_name=site_name,
            levels=levels,
            survey_points=survey_points,
            plans=plans,
            magnetic_points=magnetic_points,
            uploads=uploads,
            on_progress=on_progress,
            upload_reports=upload_reports,
        )
        return await replay_sessions(
            api,
            site_id,
            engine,
            traces,
            on_progress=on_progress,
            concurrency=concurrency,
            params=params,
        )


async def provision_site(
    api: ApiClient,
    *,
    site_name: str,
    levels: Sequence[int],
    survey_points: Sequence[Mapping[str, Any]],
    plans: Mapping[int, Mapping[str, Any]] | None = None,
    magnetic_points: Mapping[int, Sequence[Mapping[str, Any]]] | None = None,
    uploads: Sequence[tuple[int, bytes]] = (),
    on_progress: Callable[[str, int, int], None] | None = None,
    upload_reports: list[dict[str, Any]] | None = None,
) -> str:
    """Create a site with ``levels``, their floor ``plans`` (GeoJSON by level), the
    survey and the ``magnetic_points`` (``MagneticPointIn`` bodies by level), and wait
    until the service has built the maps of its current radio map version; the site id.
    ``uploads`` (floor level, ILC 2.0 trace text) go through ``/v1/uploads``, and the
    wait covers them too; their final states are appended to ``upload_reports``."""
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

    settled = await upload_and_wait(api, site["id"], uploads, on_progress)
    if upload_reports is not None:
        upload_reports.extend(settled)
    await maps_built(api, building["id"], on_progress)
    return str(site["id"])


class MapBuildFailed(RuntimeError):
    """The service's worker gave up building a radio map version's maps."""


async def maps_built(
    api: ApiClient,
    building_id: str,
    on_progress: Callable[[str, int, int], None] | None = None,
    poll_s: float = UPLOAD_POLL_S,
    timeout_s: float = MAP_BUILD_TIMEOUT_S,
) -> dict[str, Any] | None:
    """Wait until the worker has built the maps of the building's current radio map
    version, and until the service's processes have seen it (``MAP_REFRESH_S``); that
    version (None: the building has no radio map). ``MapBuildFailed`` when the worker gave
    up, ``TimeoutError`` when nothing was built in ``timeout_s`` (is a worker running?)."""
    deadline = asyncio.get_running_loop().time() + timeout_s
    while True:
        versions = (await api.list_radio_maps(building_id))["items"]
        if not versions:
            return None
        current = max(versions, key=lambda v: v["activated_at"])
        if current["build_status"] == "built":
            if on_progress:
                on_progress("maps built", 1, 1)
            await asyncio.sleep(MAP_REFRESH_S)
            return dict(current)
        if current["build_status"] == "failed":
            raise MapBuildFailed(
                f"the worker could not build radio map v{current['version']} of building "
                f"{building_id}"
            )
        if asyncio.get_running_loop().time() > deadline:
            raise TimeoutError(
                f"radio map v{current['version']} of building {building_id} was not built in "
                f"{timeout_s:.0f} s: is a worker running?"
            )
        if on_progress:
            on_progress("maps built", 0, 1)
        await asyncio.sleep(poll_s)


async def replay_sessions(
    api: ApiClient,
    site_id: str,
    engine: str,
    traces: Sequence[Sequence[Sequence[Mapping[str, Any]]]],
    *,
    on_progress: Callable[[str, int, int], None] | None = None,
    concurrency: int = 4,
    params: Mapping[str, Any] | None = None,
    seed: int | None = None,
) -> list[list[dict[str, Any]]]:
    """Replay each trace (a list of batches, each a list of wire events) in its own
    session of ``engine`` (with ``params`` over its defaults, nested overrides as ``POST
    /v1/sessions`` takes them, and ``seed`` as every session's random stream: the one an
    in-process replay of the same seed draws); the fixes per trace."""
    gate = asyncio.Semaphore(concurrency)
    finished = 0

    async def one(batches: Sequence[Sequence[Mapping[str, Any]]]) -> list[dict[str, Any]]:
        nonlocal finished
        async with gate:
            session = await api.create_session(site_id, engine, params, seed)
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


async def upload_and_wait(
    api: ApiClient,
    site_id: str,
    uploads: Sequence[tuple[int, bytes]],
    on_progress: Callable[[str, int, int], None] | None = None,
    poll_s: float = UPLOAD_POLL_S,
) -> list[dict[str, Any]]:
    """Upload each trace (floor level, text) and wait until the service settled them all;
    their final states, in upload order."""
    ids = []
    for done, (level, text) in enumerate(uploads, start=1):
        ids.append((await api.post_upload(site_id, text, floor=level))["id"])
        if on_progress:
            on_progress("upload", done, len(uploads))
    states: dict[str, dict[str, Any]] = {}
    while len(states) < len(ids):
        for upload_id in ids:
            if upload_id not in states:
                state = await api.get_upload(upload_id)
                if state["status"] not in ("queued", "processing"):
                    states[upload_id] = state
        if on_progress:
            on_progress("maps built from uploads", len(states), len(ids))
        if len(states) < len(ids):
            await asyncio.sleep(poll_s)
    return [states[i] for i in ids]


def keep_end_anchors(trace: str) -> str:
    """An ILC 2.0 trace as a crowd walk: every waypoint dropped but the first and the last
    (where a walk enters and leaves: an entrance, an elevator)."""
    lines = trace.splitlines(keepends=True)
    marks = [i for i, line in enumerate(lines) if "\tTYPE_WAYPOINT\t" in line]
    dropped = set(marks[1:-1])
    return "".join(line for i, line in enumerate(lines) if i not in dropped)
