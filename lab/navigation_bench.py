"""What navigation adds to a batch (``indoorpos bench navigation``; issue 40: "navigation
adds at most 5 % to a batch's CPU").

Measured in one process, through the service's own code:

1. **Service.** The app of a throw-away embedded service (SQLite in a temporary directory,
   the in-memory session store, the in-process worker and history writer), driven
   through ``httpx.ASGITransport`` as the API tests drive it: every batch takes the whole
   path from the body's parsing to the answer (``batches.apply_batch``: the engine's
   step, ``navigation_state.navigate``, the log entry, the store's compare-and-set). Left
   out are uvicorn's HTTP parsing and the Redis round trip, which navigation does not
   change: the batch here is cheaper than under ``indoorpos serve``, so the share
   navigation takes of it is, if anything, overstated.
2. **Site.** The simulator's building (``client_sim.building``: floors of rooms and
   corridors joined by stairs and a lift), its plans and a survey every 2 m posted through
   the admin API; with ``geo`` (the default) the building is geo-referenced, as a real
   site is, so every point on the wire carries WGS84 too.
3. **Walkers.** ``sessions`` sessions per engine in two groups: walker ``i`` in group
   ``i % 2``, on level ``levels[(i // 2) % len(levels)]``. Each batch is one step
   (``STRIDE_M`` along the walker's path, its length and heading with a phone's noise) and
   one WiFi scan where the step ends (the simulated radio), ``STEP_PERIOD_MS`` apart on
   the phone's clock. A session's first batch is a scan alone, for a fix to navigate from.
4. **Blocks.** A warm-up block (every session navigating, untimed), then ``blocks`` timed
   blocks of ``batches`` batches per session, sent one at a time, round robin over the
   sessions, so that the two groups' batches alternate. In each block one group navigates
   and the other does not, the roles swapping as ABBA (group 0 navigates in blocks 0, 3,
   4, 7, ...): both kinds of batch meet the machine in the same state, and every session
   counts for both. Before each block, untimed, every session is sent towards the node of
   its floor farthest from its walker (``PUT /navigation``, from its latest fix) and its
   walker follows the route the answer gives; the group that is not to navigate stops
   again (``DELETE``), so both groups walk alike. The bodies of a block are made before it
   starts.
5. **CPU.** ``server_cpu_us``: the CPU time of the event loop's thread inside the app
   per batch (``time.thread_time`` around the ASGI call: a batch of one step runs inline
   on the loop, and the client's own work stays outside); ``process_cpu_us``: the whole
   process's CPU time around each request (``time.process_time``: the client's side of
   it, and whatever other threads did meanwhile -- a navigation that may re-route runs in
   a worker thread, the history writer flushes in its own -- included). Of each, the mean
   of the plain batches and of the navigating ones over all timed blocks; ``overhead_us``
   is their difference and ``overhead_pct`` its share of the plain batch, judged against
   ``TARGET_PCT`` (``target_met``); ``overhead_us_by_block``: the difference within each
   block, for the spread. ``navigate_cpu_us``: how much of the difference
   ``navigation_state.navigate`` itself took, timed where the service calls it (the
   module's function wrapped for the run, thread CPU time); ``overhead_outside_navigate_us``
   the rest (the larger answer, log entry and snapshot to encode and keep, and the caches
   and garbage collections navigation's work costs the rest of the batch).
6. **Bytes.** After each block, from each navigating session's state as this process
   keeps it: the log entry of its last batch (``LogEntry.to_bytes``) against the same
   entry without navigation (no navigation state, ``navigation`` null in the answer's
   fixes and the newest fix), and likewise the snapshot
   (``SessionState.to_bytes``). ``store_bytes_added`` per batch: the entry's difference on
   ``SNAPSHOT_EVERY - 1`` batches in ``SNAPSHOT_EVERY`` and the snapshot's on the other,
   plus the answer's difference twice (the track and the live message carry the fixes).
7. **Navigation alone.** The navigating batches' fixes replayed in order, per session and
   block, through ``navigation_state.navigate`` in this thread, back to back (its caches
   warm): ``navigate_us_per_fix``, a median of ``time.perf_counter``. Then once more under
   ``cProfile``, per fix: ``profile`` lists the functions with the most own time,
   ``profile_cumulative`` the service's functions with the most time inside them (the
   profiler's own cost inflates both, most where the calls are many and small).
"""

from __future__ import annotations

import asyncio
import contextlib
import cProfile
import gc
import math
import pstats
import secrets
import statistics
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Coroutine, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import orjson
from numpy.typing import NDArray
from pydantic import SecretStr
from starlette.types import ASGIApp, Receive, Scope, Send

from client_sim.api import ApiClient
from client_sim.building import Floor, synthesize_building
from client_sim.seeding import stream
from client_sim.survey import survey_bodies, survey_points
from client_sim.world import SyntheticWorld, synthesize_world
from server import worker
from server.api.convert import fix_from_wire, to_events
from server.api.schemas.sessions import BatchIn
from server.app import create_app
from server.config import Settings
from server.positioning.engines.registry import get_engine
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.model.events import Fix
from server.services import navigation_state
from server.services.batches import SNAPSHOT_EVERY
from server.services.maps import site_maps
from server.services.runtime import Runtime
from server.services.session_records import LogEntry, SessionMeta, SessionState

FloatArray = NDArray[np.float64]
Guidance = tuple[bytes, list[dict[str, Any] | None]]  # what ``navigate`` answers
Navigate = Callable[[SiteMaps, bytes, Sequence[Fix]], Coroutine[Any, Any, Guidance]]

TARGET_PCT = 5.0
"""Navigation adds at most this share to a batch's CPU (issue 40)."""

STRIDE_M = 0.7
STEP_PERIOD_MS = 670  # Shao et al.'s step period, as client_sim.run walks
LENGTH_NOISE_M = 0.05  # as client_sim.walker's phone reports a step
HEADING_NOISE_RAD = 0.05
GEO_ORIGIN = (48.137, 11.575, 0.3)  # lat, lon (degrees), rotation (rad) of the building
PROFILE_TOP = 12  # functions listed in ``profile``
REQUEST_TIMEOUT_S = 300.0  # a survey builds its radio map before it answers
_SERVER = str(Path(navigation_state.__file__).parents[1])  # the service's package


def navigation_bench(
    *,
    sessions: int = 50,
    batches: int = 20,
    blocks: int = 6,
    engines: Sequence[str] = ("auto", "wknn"),
    geo: bool = True,
    levels: Sequence[int] = (0, 1),
    seed: int = 0,
) -> dict[str, Any]:
    """Measure what navigation adds to a batch (module docstring).

    Parameters
    ----------
    sessions : int
        Sessions per engine, in two groups.
    batches : int
        Batches each session sends in a block.
    blocks : int
        Timed blocks, an even number: each group navigates in half of them.
    engines : sequence of str
        Engines measured, one after the other (each with sessions of its own).
    geo : bool
        Geo-reference the building.
    levels : sequence of int
        The building's levels (walkers spread over them).
    seed : int
        Seed of the building, its radio, the survey and the walkers.

    Returns
    -------
    dict
        The settings (``sessions, batches, blocks, geo, levels, seed, target_pct``) and
        ``engines``: per engine, the figures of the module docstring.
    """
    if sessions < 2 or batches < 1:
        raise ValueError("sessions must be at least 2 (two groups) and batches at least 1")
    if blocks < 2 or blocks % 2:
        raise ValueError(f"blocks must be an even number of at least 2, got {blocks}")
    if not engines:
        raise ValueError("name at least one engine")
    for name in engines:
        get_engine(name)  # KeyError naming the known ones
    building = synthesize_building(stream(seed, "building"), levels=tuple(levels))
    world = synthesize_world(seed, building)
    figures = asyncio.run(_bench(world, sessions, batches, blocks, list(engines), geo, seed))
    return {
        "sessions": sessions,
        "batches": batches,
        "blocks": blocks,
        "geo": geo,
        "levels": list(building.levels),
        "seed": seed,
        "target_pct": TARGET_PCT,
        "engines": figures,
    }


class _Metered:
    """The app, counting the CPU time its requests take on the calling thread."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self.cpu_s = 0.0

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        started = time.thread_time()
        try:
            await self.app(scope, receive, send)
        finally:
            self.cpu_s += time.thread_time() - started


class _NavigateMeter:
    """``navigation_state.navigate`` as the service calls it (the module's attribute,
    replaced while ``installed``), counting its CPU time on the calling thread."""

    def __init__(self) -> None:
        self.navigate = navigation_state.navigate
        self.cpu_s = 0.0

    async def __call__(self, maps: SiteMaps, data: bytes, fixes: Sequence[Fix]) -> Guidance:
        started = time.thread_time()
        try:
            return await self.navigate(maps, data, fixes)
        finally:
            self.cpu_s += time.thread_time() - started

    @contextlib.contextmanager
    def installed(self) -> Iterator[None]:
        navigation_state.navigate = self
        try:
            yield
        finally:
            navigation_state.navigate = self.navigate


@dataclass(frozen=True)
class _Site:
    site_id: str
    building_id: str
    floor_ids: dict[int, str]  # level -> floor id


@dataclass(frozen=True)
class _Service:
    """The service in this process, and what every engine's run walks in."""

    http: httpx.AsyncClient
    meter: _Metered
    navigate_meter: _NavigateMeter
    rt: Runtime
    api: ApiClient
    site: _Site
    world: SyntheticWorld


@dataclass
class _Walker:
    """One session and the walker whose phone sends its batches."""

    session_id: str
    auth: dict[str, str]
    floor: Floor
    floor_id: str
    xy: FloatArray
    t_ms: int
    rng: np.random.Generator
    seq: int = 0
    heading_rad: float = 0.0
    path: deque[FloatArray] = field(default_factory=deque)
    cut_short: int = 0  # steps taken with no path left to walk

    def step(self, world: SyntheticWorld) -> list[dict[str, Any]]:
        """The next batch's events: a step along the path, a scan where it ends."""
        start, left = self.xy.copy(), STRIDE_M
        while left > 1e-9 and self.path:
            gap = self.path[0] - self.xy
            d = float(np.hypot(gap[0], gap[1]))
            if d <= left:
                self.xy, left = self.path.popleft(), left - d
            else:
                self.xy, left = self.xy + gap * (left / d), 0.0
        self.cut_short += left > 1e-9
        chord = self.xy - start
        length = float(np.hypot(chord[0], chord[1]))
        if length > 1e-9:
            self.heading_rad = math.atan2(chord[0], chord[1])  # clockwise from north (y)
        self.t_ms += STEP_PERIOD_MS
        step = {
            "type": "step",
            "t": self.t_ms,
            "length_m": round(min(3.0, max(0.05, length + LENGTH_NOISE_M * self.normal())), 3),
            "heading_rad": round(self.heading_rad + HEADING_NOISE_RAD * self.normal(), 5),
        }
        return [step, self.scan(world)]

    def scan(self, world: SyntheticWorld) -> dict[str, Any]:
        rssi = world.radio.wifi.scan(self.xy[None, :], self.floor.level, self.rng)[0]
        return {"type": "wifi", "t": self.t_ms, "readings": world.radio.wifi.readings(rssi)}

    def normal(self) -> float:
        return float(self.rng.standard_normal())

    def body(self, events: list[dict[str, Any]]) -> bytes:
        self.seq += 1
        return orjson.dumps({"seq": self.seq, "events": events})


@dataclass(frozen=True)
class _Block:
    """One block as it was sent and answered; per batch, in the order sent."""

    navigating: frozenset[int]  # the walkers navigating in it
    senders: list[int]  # the walker of each batch
    bodies: list[bytes]
    answers: list[bytes]
    server_cpu_s: list[float]
    process_cpu_s: list[float]
    navigate_cpu_s: list[float]
    start_navigation: dict[int, bytes]  # navigating walker -> its state before the block
    sizes: dict[str, list[int]]  # ``_sizes`` after the block

    def cpu_s(self, navigating: bool, spent: Sequence[float] | None = None) -> list[float]:
        """Of the batches of one kind, ``spent`` (default: ``server_cpu_s``)."""
        pairs = zip(self.senders, self.server_cpu_s if spent is None else spent, strict=True)
        return [t for i, t in pairs if (i in self.navigating) == navigating]


async def _bench(
    world: SyntheticWorld,
    sessions: int,
    batches: int,
    blocks: int,
    engines: list[str],
    geo: bool,
    seed: int,
) -> list[dict[str, Any]]:
    key = secrets.token_urlsafe(24)
    with tempfile.TemporaryDirectory(prefix="indoorpos-navigation-bench-") as data_dir:
        settings = Settings(
            data_dir=Path(data_dir),
            database_url=None,
            redis_url=None,
            admin_key=SecretStr(key),
            rate_limits=False,  # one local client opening many sessions on purpose
        )
        app = create_app(settings)
        meter = _Metered(app)
        async with (
            app.router.lifespan_context(app),
            httpx.AsyncClient(
                transport=httpx.ASGITransport(app=meter),
                base_url="http://navigation-bench",
                timeout=REQUEST_TIMEOUT_S,
            ) as http,
        ):
            rt: Runtime = app.state.runtime
            api = ApiClient(http, key)
            site = await _provision(api, key, world, geo, seed)
            # the survey's maps built now, not by the worker in the middle of the timings
            await worker.build_maps(rt, building_id=site.building_id)
            for thread in threading.enumerate():  # server.app's warm-up of compiled loops
                if thread.name == "kernels":
                    thread.join()
            service = _Service(http, meter, _NavigateMeter(), rt, api, site, world)
            with service.navigate_meter.installed():
                return [
                    await _measure(service, engine, sessions, batches, blocks, seed)
                    for engine in engines
                ]


async def _provision(
    api: ApiClient, key: str, world: SyntheticWorld, geo: bool, seed: int
) -> _Site:
    """The building as ``client_sim.site.provision_site`` provisions it, and with ``geo``
    geo-referenced (which that cannot do)."""
    site = await api.create_site(f"bench navigation seed {seed}")
    created: dict[str, Any] = {"name": "synthetic building"}
    if geo:
        lat, lon, rotation = GEO_ORIGIN
        created |= {"origin_lat": lat, "origin_lon": lon, "rotation_rad": rotation}
    answer = await api.http.post(
        f"/v1/sites/{site['id']}/buildings", json=created, headers=_bearer(key)
    )
    _check(answer, "create the building")
    building_id = str(answer.json()["id"])
    floor_ids = {}
    for floor in world.building.floors:
        row = await api.create_floor(building_id, floor.level, f"level {floor.level}")
        floor_ids[floor.level] = str(row["id"])
        await api.put_plan(floor_ids[floor.level], floor.plan_geojson())
    points = survey_points(world, stream(seed, "survey"), t0_ms=int(time.time() * 1000))
    for body in survey_bodies(points):
        await api.post_survey(building_id, body)
    return _Site(str(site["id"]), building_id, floor_ids)


async def _measure(
    service: _Service, engine: str, sessions: int, batches: int, blocks: int, seed: int
) -> dict[str, Any]:
    """One engine's figures (module docstring)."""
    world, site = service.world, service.site
    walkers = []
    t0_ms = int(time.time() * 1000)  # a phone's clock: the wire takes times of 2000-2099
    levels = world.building.levels
    for i in range(sessions):
        floor = world.building.floor(levels[(i // 2) % len(levels)])
        rng = stream(seed, "walker", i)
        session = await service.api.create_session(site.site_id, engine)
        start = floor.nodes[int(rng.integers(len(floor.nodes)))].astype(np.float64)
        walker = _Walker(
            session.id, _bearer(session.token), floor, site.floor_ids[floor.level], start,
            t0_ms, rng,
        )  # fmt: skip
        walkers.append(walker)
        answer = await _post(service.http, walker, walker.body([walker.scan(world)]))
        _check(answer, "first batch")
    await _block(service, walkers, batches, frozenset(range(sessions)))  # warm-up
    done = []
    for k in range(blocks):
        group = 0 if k % 4 in (0, 3) else 1  # ABBA
        navigating = frozenset(i for i in range(sessions) if i % 2 == group)
        done.append(await _block(service, walkers, batches, navigating))
    sizes = _bytes(done)
    maps = await _maps(service.rt, site.site_id)
    alone = _apart(_navigation_alone(service.navigate_meter.navigate, maps, done))
    for walker in walkers:
        await service.http.delete(f"/v1/sessions/{walker.session_id}", headers=walker.auth)
    return {"engine": engine, **_cpu(done), **_walks(done, walkers), **sizes, **alone}


async def _block(
    service: _Service, walkers: list[_Walker], batches: int, navigating: frozenset[int]
) -> _Block:
    """Head every session somewhere far (and stop those not in ``navigating``), make the
    block's bodies, then send them (timed)."""
    http, meter = service.http, service.meter
    start_navigation = {}
    for i, walker in enumerate(walkers):
        await _head_far(http, walker)
        if i in navigating:
            start_navigation[i] = _cached(service.rt, walker.session_id)[2].navigation
        else:
            url = f"/v1/sessions/{walker.session_id}/navigation"
            _check(await http.delete(url, headers=walker.auth), "stop navigating")
    senders, bodies = [], []
    for _ in range(batches):
        for i, walker in enumerate(walkers):
            senders.append(i)
            bodies.append(walker.body(walker.step(service.world)))
    server, process, navigate, answers = [], [], [], []
    gc.collect()
    for i, body in zip(senders, bodies, strict=True):
        # one request at a time: only this one ran in the app meanwhile
        before, started = meter.cpu_s, time.process_time()
        navigate_before = service.navigate_meter.cpu_s
        answer = await _post(http, walkers[i], body)
        process.append(time.process_time() - started)
        server.append(meter.cpu_s - before)
        navigate.append(service.navigate_meter.cpu_s - navigate_before)
        answers.append(answer.content)
        if answer.status_code != 200:
            _check(answer, "batch")
    # sized now: the next block's start replaces the navigation
    sizes = _sizes(service.rt, walkers, navigating, senders, bodies)
    return _Block(
        navigating, senders, bodies, answers, server, process, navigate, start_navigation, sizes
    )


async def _post(http: httpx.AsyncClient, walker: _Walker, body: bytes) -> httpx.Response:
    return await http.post(
        f"/v1/sessions/{walker.session_id}/batches",
        content=body,
        headers={**walker.auth, "Content-Type": "application/json"},
    )


async def _head_far(http: httpx.AsyncClient, walker: _Walker) -> None:
    """Navigate the session to the node of its floor farthest from its walker, and put
    the walker on the route (after the route's first point: the session's fix)."""
    nodes = walker.floor.nodes
    far = nodes[int(np.argmax(np.hypot(*(nodes - walker.xy).T)))]
    destination = {"floor_id": walker.floor_id, "x_m": float(far[0]), "y_m": float(far[1])}
    answer = await http.put(
        f"/v1/sessions/{walker.session_id}/navigation",
        json={"destination": destination},
        headers=walker.auth,
    )
    _check(answer, "start navigating")
    legs = answer.json()["route"]["legs"]
    walker.path = deque(
        np.array(xy, dtype=np.float64)
        for leg in legs
        if leg["floor_id"] == walker.floor_id
        for xy in leg["geometry"]["coordinates"][1:]
    )


def _cached(rt: Runtime, session_id: str) -> tuple[int, SessionMeta, SessionState]:
    """The session's version, record and state as this process wrote them last."""
    found = rt.states.current(session_id)
    if found is None:
        raise RuntimeError(f"session {session_id} is not in this process's cache")
    return found


async def _maps(rt: Runtime, site_id: str) -> SiteMaps:
    async with rt.transaction() as s:
        return await site_maps(s, rt.maps, site_id)


def _cpu(done: list[_Block]) -> dict[str, Any]:
    """The CPU figures of the timed blocks (module docstring, 5)."""

    def mean_us(navigating: bool, which: str) -> float:
        spent = (b.cpu_s(navigating, getattr(b, which)) for b in done)
        return 1e6 * statistics.fmean(t for batch in spent for t in batch)

    out: dict[str, Any] = {"batches_per_kind": sum(len(b.cpu_s(True)) for b in done)}
    for name, which in (("server", "server_cpu_s"), ("process", "process_cpu_s")):
        plain, navigating = mean_us(False, which), mean_us(True, which)
        prefix = "" if name == "server" else "process_"
        out |= {
            f"{name}_cpu_us_plain": plain,
            f"{name}_cpu_us_navigating": navigating,
            f"{prefix}overhead_us": navigating - plain,
            f"{prefix}overhead_pct": 100.0 * (navigating - plain) / plain,
        }
    out["overhead_us_by_block"] = [
        1e6 * (statistics.fmean(b.cpu_s(True)) - statistics.fmean(b.cpu_s(False))) for b in done
    ]
    navigate = mean_us(True, "navigate_cpu_s") - mean_us(False, "navigate_cpu_s")
    out["navigate_cpu_us"] = navigate
    out["overhead_outside_navigate_us"] = out["overhead_us"] - navigate
    out["target_met"] = bool(out["overhead_pct"] <= TARGET_PCT)
    return out


def _walks(done: list[_Block], walkers: list[_Walker]) -> dict[str, Any]:
    """Fixes per batch, and what the navigating batches' answers said: that the walks
    went as meant (on the route, no arrival, no re-route)."""
    fixes = {True: 0, False: 0}
    batches = {True: 0, False: 0}
    guided = off_route = unguided = 0
    events: dict[str, int] = {}
    for block in done:
        for i, answer in zip(block.senders, block.answers, strict=True):
            kind = i in block.navigating
            batch_fixes = orjson.loads(answer)["fixes"]
            batches[kind] += 1
            fixes[kind] += len(batch_fixes)
            if not kind:
                continue
            navs = [f["navigation"] for f in batch_fixes if f.get("navigation")]
            guided += len(navs)
            unguided += not navs
            off_route += sum(not nav["on_route"] for nav in navs)
            for event in (e["type"] for nav in navs for e in nav["events"]):
                events[event] = events.get(event, 0) + 1
    return {
        "fixes_per_batch_plain": fixes[False] / batches[False],
        "fixes_per_batch_navigating": fixes[True] / batches[True],
        "navigating_batches_without_navigation": unguided,
        "off_route_share": off_route / max(1, guided),
        "reroutes": events.get("rerouted", 0),
        "arrivals": events.get("arrived", 0),
        "steps_without_path": sum(w.cut_short for w in walkers),
    }


def _sizes(
    rt: Runtime,
    walkers: list[_Walker],
    navigating: frozenset[int],
    senders: list[int],
    bodies: list[bytes],
) -> dict[str, list[int]]:
    """The bytes navigation adds to what the store keeps, from each navigating session's
    state after a block whose batches were ``bodies`` (module docstring, 6)."""
    last_body = dict(zip(senders, bodies, strict=True))  # each walker's last
    sizes: dict[str, list[int]] = {}

    def add(**values: int) -> None:
        for name, value in values.items():
            sizes.setdefault(name, []).append(value)

    for i in sorted(navigating):
        _, meta, state = _cached(rt, walkers[i].session_id)
        if not state.navigation or not state.replies:
            continue  # arrived: nothing left to size
        spec = get_engine(meta.engine)
        reply = state.replies[-1]
        events = to_events(BatchIn.model_validate_json(last_body[i]).events)
        entry = LogEntry(
            state.last_seq, reply.digest, tuple(events), reply.body, state.last_fix,
            state.touched_ms, state.zones, state.navigation,
        )  # fmt: skip
        bare = replace(
            entry,
            body=_without_navigation(reply.body),
            last_fix=_without_navigation(state.last_fix),
            navigation=b"",
        )
        bare_state = replace(
            state,
            replies=tuple(replace(r, body=_without_navigation(r.body)) for r in state.replies),
            last_fix=bare.last_fix,
            navigation=b"",
        )
        add(
            navigation_state=len(state.navigation),
            answer_added=len(entry.body) - len(bare.body),
            entry_plain=len(bare.to_bytes()),
            entry_added=len(entry.to_bytes()) - len(bare.to_bytes()),
            snapshot_plain=len(bare_state.to_bytes(spec)),
            snapshot_added=len(state.to_bytes(spec)) - len(bare_state.to_bytes(spec)),
        )
        for fix in orjson.loads(reply.body):
            if fix.get("navigation"):
                add(fix_navigation=len(orjson.dumps(fix["navigation"])))
    return sizes


def _bytes(done: list[_Block]) -> dict[str, Any]:
    """The medians of the blocks' ``_sizes``, and ``store_bytes_added``."""
    names = {name for b in done for name in b.sizes}
    m = {name: statistics.median(v for b in done for v in b.sizes.get(name, [])) for name in names}
    if not m:
        return {}
    every = SNAPSHOT_EVERY
    return {
        "navigation_state_bytes": m["navigation_state"],
        "fix_navigation_bytes": m["fix_navigation"],
        "answer_bytes_added": m["answer_added"],
        "log_entry_bytes_plain": m["entry_plain"],
        "log_entry_bytes_added": m["entry_added"],
        "snapshot_bytes_plain": m["snapshot_plain"],
        "snapshot_bytes_added": m["snapshot_added"],
        "store_bytes_added": ((every - 1) * m["entry_added"] + m["snapshot_added"]) / every
        + 2 * m["answer_added"],
    }


def _without_navigation(data: bytes) -> bytes:
    """A fix (a JSON object) or an answer's fixes (a JSON array) as a session that is not
    navigating has them: ``navigation`` null."""
    if not data:
        return data
    value = orjson.loads(data)
    for fix in value if isinstance(value, list) else [value]:
        if "navigation" in fix:
            fix["navigation"] = None
    return orjson.dumps(value)


async def _navigation_alone(
    navigate: Navigate, maps: SiteMaps, done: list[_Block]
) -> dict[str, Any]:
    """Navigation's part of the navigating batches, replayed through ``navigate``
    (``navigation_state.navigate`` itself, not the meter; module docstring, 7)."""
    floor_index = {f.level: i for i, f in enumerate(maps.floors)}
    runs: list[tuple[bytes, list[list[Fix]]]] = []
    for block in done:
        by_walker: dict[int, list[list[Fix]]] = {i: [] for i in block.start_navigation}
        for i, answer in zip(block.senders, block.answers, strict=True):
            if i in block.navigating:
                fixes = orjson.loads(answer)["fixes"]
                by_walker[i].append([fix_from_wire(f, floor_index) for f in fixes])
        runs += [(block.start_navigation[i], batches) for i, batches in by_walker.items()]

    async def replay(timed: list[float] | None = None) -> int:
        """Each run through ``navigate``, batch by batch (until it arrives); the fixes."""
        fixes_in = 0
        for data, batches in runs:
            for fixes in batches:
                if not data:
                    break
                started = time.perf_counter()
                data, _ = await navigate(maps, data, fixes)
                if timed is not None:
                    timed.append((time.perf_counter() - started) / max(1, len(fixes)))
                fixes_in += len(fixes)
        return fixes_in

    per_fix: list[float] = []
    fixes_in = await replay(per_fix)
    profiler = cProfile.Profile()
    profiler.enable()
    await replay()
    profiler.disable()
    return {
        "navigate_us_per_fix": 1e6 * statistics.median(per_fix) if per_fix else None,
        **_top(profiler, fixes_in),
    }


def _apart(replay: Coroutine[Any, Any, dict[str, Any]]) -> dict[str, Any]:
    """``replay`` run in an event loop of its own, in a thread of its own, while this
    thread (and the service's loop in it) waits: nothing of the service's runs meanwhile,
    not even its loop's other tasks, which would land in the timings and the profile."""
    out: list[dict[str, Any]] = []
    failed: list[BaseException] = []

    def run() -> None:
        try:
            out.append(asyncio.run(replay))
        except BaseException as e:  # raised again in the caller's thread
            failed.append(e)

    thread = threading.Thread(target=run, name="navigation-replay")
    thread.start()
    thread.join()
    if failed:
        raise failed[0]
    return out[0]


def _top(profiler: cProfile.Profile, fixes: int) -> dict[str, list[dict[str, Any]]]:
    """The functions with the most own time (``profile``), and the service's with the most
    time inside them (``profile_cumulative``), per fix."""
    stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
    per = 1e6 / max(1, fixes)

    def rows(keys: list[Any]) -> list[dict[str, Any]]:
        return [
            {
                "function": f"{Path(file).name}:{line}({name})" if line else name,
                "calls_per_fix": stats[(file, line, name)][1] / max(1, fixes),
                "own_us_per_fix": stats[(file, line, name)][2] * per,
                "cumulative_us_per_fix": stats[(file, line, name)][3] * per,
            }
            for file, line, name in keys
        ]

    own = sorted(stats, key=lambda k: -stats[k][2])[:PROFILE_TOP]
    ours = [k for k in stats if k[0].startswith(_SERVER)]
    inside = sorted(ours, key=lambda k: -stats[k][3])[:PROFILE_TOP]
    return {"profile": rows(own), "profile_cumulative": rows(inside)}


def _bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def _check(answer: httpx.Response, doing: str) -> None:
    if not answer.is_success:
        raise RuntimeError(f"{doing}: {answer.status_code} {answer.text}")
