"""``indoorpos bench load``: walking users per core through the real HTTP + Redis path.

Shao et al. size their cloud by one CPU core serving 130 users at a 0.67 s step period
with N = 3000 particles (``papers/001_*``, section IV-B). This measures our figure:

1. **Service.** The api runs as it does in production -- ``indoorpos serve`` with ``k``
   worker processes, sessions in Redis, maps in PostgreSQL, the access log and (unless
   ``rate_limits`` is off) the rate limits on -- as a child process
   of this one. With at least two CPUs the api is pinned to one CPU per process (CPU 0,
   then 1, ...) and this process (the simulator) to the others, keeping at least one CPU
   for the simulator, so the api has its cores to itself and "users per core" means what
   it says. On a two-CPU machine two api processes therefore share CPU 0: their figure
   measures what a second process costs or saves on the same core, not a second core.
2. **Site.** One synthetic site is set up through the admin API (``client_sim``) and
   reused by every level.
3. **Levels.** ``client_sim.run.run_walkers`` walks ``U`` users for ``hold_s`` seconds,
   each stepping every 0.67 s and posting every ``batch_steps`` steps over HTTP (or the
   session's WebSocket, ``transport="ws"``); their starts are spread over ``RAMP_S``. A
   level is **held** when no request failed and the 99th percentile of the batch latency
   (sent to answered, as the phone sees it) is at most ``p99_limit_ms``. The count grows
   by half from ``users_start`` while levels are held (at most ``users_max``), falls by a
   third from the start while they are not, and the bracket between the last held and the
   first failed count is then halved until it is narrower than ``RESOLUTION`` of the held
   count. Beside the phones' p99, each level reports the server's own: the bound of the
   first bucket of the api's batch-duration histogram (``/metrics``) holding 99 % of the
   level's batches, which leaves out the simulator's own delays (one api process only:
   each process keeps its own histogram).
4. **CPU.** The api processes' CPU time (user + system, the process and its children,
   from ``/proc``) over a level, divided by the steps the level applied:
   ``server_cpu_us_per_step``. The simulator's own CPU time is reported beside it, as the
   simulator may run out of CPU before the api does.
5. **Ceiling.** In this process, with no HTTP and no Redis, the same engine steps the
   same simulated walks (the site's maps read once from the database, engine states held
   in memory, one batch of ``batch_steps`` steps per call, as a session would): steps per
   second of engine time alone. ``ceiling_ratio`` is the steps per second the one-process
   service held, over that.
6. **Scale-out.** Steps 3-4 again with two api processes; ``two_process_ratio`` is the
   users two processes held over the users one held, and ``two_process_cpus`` the CPUs
   they had (1 on a two-CPU machine, see 1.).

The api process, its CPU time and its own latency histogram: ``load_bench_api``.

Linux only (CPU times from ``/proc``, pinning by ``sched_setaffinity``).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import platform
import secrets
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from client_sim.api import ApiClient
from client_sim.run import (
    STEP_PERIOD_S,
    Transport,
    run_walkers,
    simulated_walker,
    step_batches,
    walker_params,
)
from client_sim.site import provision_site
from client_sim.world import synthesize_world
from lab.load_bench_api import LOAD_GENERATOR_LIMITS, ApiProcesses, batch_buckets, bucket_p99_ms
from server.api.convert import to_events
from server.api.schemas.sessions import BatchIn
from server.config import Settings
from server.positioning.engines.registry import get_engine
from server.positioning.model.events import StepEvent
from server.services.maps import site_maps
from server.services.runtime import open_runtime
from server.storage import db

RAMP_S = 5.0  # users' starts spread over this much of a level
RESOLUTION = 0.1  # bisect until the bracket is narrower than this share of the held count
CEILING_WALKERS = 16
CEILING_BATCHES = 60


@dataclass(frozen=True)
class Level:
    """One hold of ``users`` users against ``processes`` api processes."""

    processes: int
    users: int
    held: bool
    p50_ms: float | None
    p95_ms: float | None
    p99_ms: float | None
    errors: int
    batches: int
    steps: int
    duration_s: float
    steps_per_s: float
    server_cpu_s: float
    server_cpu_us_per_step: float | None
    client_cpu_s: float
    mean_error_m: float | None
    first_error: str | None
    server_p99_ms: float | None = None  # the api's own histogram: an upper bound


def run_load_bench(
    *,
    users_max: int,
    database_url: str,
    redis_url: str,
    users_start: int = 50,
    hold_s: float = 30.0,
    batch_steps: int = 1,
    engine: str = "pf_magnetic",
    p99_limit_ms: float = 50.0,
    seed: int = 0,
    two_processes: bool = True,
    transport: Transport = "http",
    rate_limits: bool = True,
    on_level: Callable[[Level], None] | None = None,
    on_stage: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Measure as the module docstring says; the figures as a JSON-ready dict."""
    if users_max < 1 or users_start < 1 or not hold_s > RAMP_S:
        raise ValueError(f"users_max and users_start must be >= 1 and hold_s > {RAMP_S}")

    def stage(text: str) -> None:
        if on_stage is not None:
            on_stage(text)

    db.migrate(database_url)
    key = secrets.token_urlsafe(24)
    env = {
        "INDOORPOS_DATABASE_URL": database_url,
        "INDOORPOS_REDIS_URL": redis_url,
        "INDOORPOS_ADMIN_KEY": key,
        **(LOAD_GENERATOR_LIMITS if rate_limits else {"INDOORPOS_RATE_LIMITS": "false"}),
    }
    cpus = sorted(os.sched_getaffinity(0))
    own_cpus = set(cpus)
    configs = [1, 2] if two_processes else [1]
    runs: dict[int, list[Level]] = {}
    walk: _Walk | None = None
    try:
        for processes in configs:
            api_cpus = _api_cpus(cpus, processes)
            stage(f"starting {processes} api process(es)")
            api = ApiProcesses(processes, env, api_cpus)
            os.sched_setaffinity(0, own_cpus - api_cpus if api_cpus else own_cpus)
            try:
                if walk is None:
                    stage("setting up the synthetic site")
                    site_id = asyncio.run(_provision(api.url, key, seed))
                    walk = _Walk(key, site_id, hold_s, batch_steps, engine, seed, transport)
                this_walk = walk

                def hold(
                    users: int,
                    api: ApiProcesses = api,
                    walk: _Walk = this_walk,
                    processes: int = processes,
                ) -> Level:
                    stage(f"{processes} process(es): {users} users for {hold_s:.0f} s")
                    level = _hold(api, walk, users, processes, p99_limit_ms)
                    if on_level is not None:
                        on_level(level)
                    return level

                start = users_start if processes == 1 else _best_users(runs[1]) or users_start
                runs[processes] = find_capacity(hold, start, users_max)
            finally:
                api.stop()
                os.sched_setaffinity(0, own_cpus)
        assert walk is not None
        stage("in-process ceiling: the engine alone")
        ceiling = asyncio.run(_ceiling(database_url, walk))
    finally:
        os.sched_setaffinity(0, own_cpus)

    best = _best(runs[1])
    best_two = _best(runs[2]) if two_processes else None
    particles = _particles(engine)
    result = {
        "particles": particles,
        "users_per_core": best.users if best else 0,
        "p99_ms": best.p99_ms if best else None,
        "server_cpu_us_per_step": best.server_cpu_us_per_step if best else None,
        "ceiling_steps_per_s": ceiling,
        "ceiling_ratio": best.steps_per_s / ceiling if best else 0.0,
        "two_process_ratio": (best_two.users if best_two else 0) / best.users
        if best and two_processes
        else None,
        "two_process_users": best_two.users if best_two else None,
        "two_process_cpus": len(_api_cpus(cpus, 2) or cpus) if two_processes else None,
        "engine": engine,
        "transport": transport,
        "rate_limits": rate_limits,
        "batch_steps": batch_steps,
        "step_period_s": STEP_PERIOD_S,
        "hold_s": hold_s,
        "p99_limit_ms": p99_limit_ms,
        "users_max": users_max,
        "machine": _machine(),
        "levels": [asdict(level) for levels in runs.values() for level in levels],
    }
    return result


def _api_cpus(cpus: list[int], processes: int) -> set[int] | None:
    """The api's CPUs: one per process, leaving the simulator at least one of its own
    (None, unpinned, on a one-CPU machine)."""
    if len(cpus) < 2:
        return None
    return set(cpus[: min(processes, len(cpus) - 1)])


def find_capacity(hold: Callable[[int], Level], start: int, users_max: int) -> list[Level]:
    """Levels run to find the largest user count held (module docstring, step 3)."""
    levels: list[Level] = []
    held: int | None = None
    failed: int | None = None
    users = min(start, users_max)
    while True:  # grow while held, shrink while not, until a bracket (or a bound) is found
        level = hold(users)
        levels.append(level)
        if level.held:
            held = users
            if failed is not None or users >= users_max:
                break
            users = min(users_max, math.ceil(users * 1.5))
        else:
            failed = users
            if held is not None or users <= 1:
                break
            users = max(1, math.floor(users / 1.5))
    while held is not None and failed is not None and failed - held > max(1, RESOLUTION * held):
        users = (held + failed) // 2
        level = hold(users)
        levels.append(level)
        if level.held:
            held = users
        else:
            failed = users
    return levels


@dataclass(frozen=True)
class _Walk:
    """What every level walks."""

    key: str
    site_id: str
    hold_s: float
    batch_steps: int
    engine: str
    seed: int
    transport: Transport


def _hold(api: ApiProcesses, walk: _Walk, users: int, processes: int, p99_limit_ms: float) -> Level:
    buckets_before = batch_buckets(api.url) if processes == 1 else {}
    server_before, client_before = api.cpu_seconds(), time.process_time()
    summary = asyncio.run(
        run_walkers(
            api.url,
            walk.key,
            walkers=users,
            duration_s=walk.hold_s,
            seed=walk.seed,
            engine=walk.engine,
            batch_steps=walk.batch_steps,
            transport=walk.transport,
            live_socket=False,
            site_id=walk.site_id,
            ramp_s=RAMP_S,
        )
    )
    server_cpu = api.cpu_seconds() - server_before
    # with more than one process, each /metrics is one process's own: no whole count
    server_p99 = bucket_p99_ms(buckets_before, batch_buckets(api.url)) if processes == 1 else None
    p99 = summary.p99_ms
    return Level(
        processes=processes,
        users=users,
        held=summary.errors == 0 and p99 is not None and p99 <= p99_limit_ms,
        p50_ms=summary.p50_ms,
        p95_ms=summary.p95_ms,
        p99_ms=p99,
        errors=summary.errors,
        batches=summary.batches,
        steps=summary.steps,
        duration_s=summary.duration_s,
        steps_per_s=summary.steps / summary.duration_s if summary.duration_s > 0 else 0.0,
        server_cpu_s=server_cpu,
        server_cpu_us_per_step=1e6 * server_cpu / summary.steps if summary.steps else None,
        client_cpu_s=time.process_time() - client_before,
        mean_error_m=summary.mean_error_m,
        first_error=summary.error_messages[0] if summary.error_messages else None,
        server_p99_ms=server_p99,
    )


async def _provision(url: str, key: str, seed: int) -> str:
    world = synthesize_world(seed)
    async with httpx.AsyncClient(base_url=url, timeout=httpx.Timeout(300.0)) as http:
        api = ApiClient(http, key)
        site = await provision_site(
            api, world.building, seed, world=world, name=f"bench load seed {seed}"
        )
    return site.site_id


async def _ceiling(database_url: str, walk: _Walk) -> float:
    """Engine steps per second of engine time, in this process (module docstring, step 5)."""
    settings = Settings(database_url=database_url, redis_url=None)
    async with open_runtime(settings) as rt, rt.transaction() as s:
        maps = await site_maps(s, rt.maps, walk.site_id)
    world = synthesize_world(walk.seed)
    params = walker_params()
    walks = []
    t0_ms = int(time.time() * 1000)  # a phone's clock: the wire takes times of 2000-2099
    for i in range(CEILING_WALKERS):
        walker = simulated_walker(world, walk.seed, i, t0_ms, params)
        batches = step_batches(walker.events(), walk.batch_steps)
        walks.append(
            [
                to_events(
                    BatchIn.model_validate(
                        {"seq": 1, "events": [item.event for item in next(batches)[1]]}
                    ).events
                )
                for _ in range(CEILING_BATCHES)
            ]
        )
    spec = get_engine(walk.engine)
    engine_params = spec.params()
    states = [spec.start(engine_params) for _ in walks]
    elapsed = 0.0
    steps = 0
    for k in range(CEILING_BATCHES):  # round robin, as interleaved sessions are served
        for i, events in enumerate(walks):
            rng = np.random.default_rng(np.random.SeedSequence(i, spawn_key=(k + 1,)))
            t0 = time.perf_counter()
            states[i], _ = spec.step(states[i], events[k], maps, engine_params, rng)
            elapsed += time.perf_counter() - t0
            steps += sum(isinstance(e, StepEvent) for e in events[k])
    return steps / elapsed


def _best(levels: list[Level]) -> Level | None:
    held = [level for level in levels if level.held]
    return max(held, key=lambda level: level.users) if held else None


def _best_users(levels: list[Level]) -> int | None:
    best = _best(levels)
    return best.users if best else None


def _particles(engine: str) -> int | None:
    params = get_engine(engine).params()
    particles = getattr(params, "particles", None)
    n = getattr(particles, "n", None)
    return int(n) if n is not None else None


def _machine() -> dict[str, Any]:
    model = ""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    return {
        "cpu": model or platform.processor(),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "system": f"{platform.system()} {platform.release()} {platform.machine()}",
    }
