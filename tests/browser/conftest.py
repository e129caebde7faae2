"""The console in a real browser: a real ``indoorpos serve`` (a subprocess on the embedded
defaults) with a site the client simulator provisions, and Debian's chromium driven by
Playwright.

Playwright cannot download its own browsers here, so it launches the system's chromium
(``.ci/run`` installs it); without one the tests are skipped, saying so. Each test leaves
screenshots under ``test-artifacts/console/`` for review (``tests.support.console_browser``).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import secrets
import shutil
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.async_api import Browser, Route, async_playwright

from client_sim.api import ApiClient, ApiError, Session
from client_sim.run import simulated_walker, step_batches, walker_params
from client_sim.site import provision_site
from client_sim.world import SyntheticWorld, synthesize_world
from tests.support.console_browser import WALK_LEVEL_INDEX, Server, SimulatedSite, Tab
from tests.support.live_server import free_port

DEBIAN_CHROMIUM = Path("/usr/bin/chromium")
SEED = 0
START_TIMEOUT_S = 60.0


def _indoorpos() -> str:
    """The ``indoorpos`` script of the environment running the tests."""
    beside = Path(sys.executable).with_name("indoorpos")
    found = str(beside) if beside.exists() else shutil.which("indoorpos")
    if found is None:
        pytest.fail("no indoorpos command: pip install -e '.[dev]'")
    return found


@pytest.fixture(scope="session")
def chromium() -> Path:
    found = DEBIAN_CHROMIUM if DEBIAN_CHROMIUM.exists() else None
    if found is None and (which := shutil.which("chromium")):
        found = Path(which)
    if found is None:
        pytest.skip("no chromium to drive: apt-get install -y chromium (.ci/run installs it)")
    return found


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """``indoorpos serve`` on a free loopback port, embedded (SQLite, in-process session
    store and worker), whatever mode the rest of the suite runs in."""
    if os.environ.get("INDOORPOS_DATABASE_URL"):
        # the server is embedded in either pass, so the second pass would repeat the first
        pytest.skip("the browser tests run in the embedded pass of `make test`")
    data_dir = tmp_path_factory.mktemp("console-server")
    admin_key = secrets.token_urlsafe(24)
    env = {k: v for k, v in os.environ.items() if not k.startswith("INDOORPOS_")}
    env |= {
        "INDOORPOS_DATA_DIR": str(data_dir),
        "INDOORPOS_ADMIN_KEY": admin_key,
        "INDOORPOS_LOG_LEVEL": "WARNING",
    }
    port = free_port()
    log = data_dir / "server.log"
    with log.open("wb") as out:
        process = subprocess.Popen(
            [_indoorpos(), "serve", "--port", str(port), "--no-access-log"],
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if process.poll() is not None:
                pytest.fail(f"indoorpos serve exited with {process.returncode}:\n{log.read_text()}")
            with contextlib.suppress(httpx.TransportError):
                if httpx.get(f"{url}/healthz", timeout=2).status_code == 200:
                    break
            if time.monotonic() > deadline:
                pytest.fail(f"indoorpos serve did not answer in {START_TIMEOUT_S:.0f} s")
            time.sleep(0.2)
        yield Server(url=url, admin_key=admin_key, log=log)
    finally:
        process.terminate()
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def _with_beacons(world: SyntheticWorld, level: int) -> dict[str, Any]:
    """The level's plan with a point where each of its BLE beacons hangs (a kind the
    positioning ignores, drawn by the console)."""
    plan = world.building.floor(level).plan_geojson()
    ble = world.radio.ble
    for beacon_id, (x, y), at in zip(ble.ids, ble.xy.tolist(), ble.level.tolist(), strict=True):
        if at == level:
            plan["features"].append(
                {
                    "type": "Feature",
                    "geometry": {"type": "Point", "coordinates": [x, y]},
                    "properties": {"kind": "beacon", "id": beacon_id},
                }
            )
    return plan


def _walk_upload(world: SyntheticWorld, steps: int = 20) -> dict[str, Any]:
    """A short walk as a JSON upload: the phone's events and where it started and ended."""
    walker = simulated_walker(world, SEED, 1, int(time.time() * 1000), walker_params())
    events, truths, counted = [], [], 0
    for item in walker.events():
        events.append(item.event)
        truths.append(item.truth)
        counted += item.event["type"] == "step"
        if counted == steps:
            break
    anchors = [{"t": t.t, "x_m": t.x_m, "y_m": t.y_m} for t in (truths[0], truths[-1])]
    return {"events": events, "anchors": anchors}


@pytest.fixture(scope="session")
async def simulated_site(server: Server) -> SimulatedSite:
    """The simulator's synthetic building (plans and a survey of every floor), a viewer
    key for it and one upload of a walk."""
    world = synthesize_world(SEED)
    async with httpx.AsyncClient(base_url=server.url, timeout=60) as http:
        api = ApiClient(http, server.admin_key)
        site = await provision_site(api, world.building, SEED, world=world, name="console site")
        admin = {"Authorization": f"Bearer {server.admin_key}"}
        body = {"name": "console viewer", "scopes": ["viewer"], "site_id": site.site_id}
        r = await http.post("/v1/keys", json=body, headers=admin)
        assert r.status_code == 201, r.text
        viewer_key = r.json()["key"]
        level = world.building.levels[WALK_LEVEL_INDEX]
        r = await http.put(
            f"/v1/floors/{site.floor_ids[level]}/plan",
            json=_with_beacons(world, level),
            headers=admin,
        )
        assert r.status_code == 200, r.text
        r = await http.post(
            "/v1/uploads",
            params={"site_id": site.site_id, "floor": world.building.levels[0]},
            json=_walk_upload(world),
            headers=admin,
        )
        assert r.status_code == 202, r.text
    return SimulatedSite(site, world, viewer_key, r.json()["id"])


@pytest.fixture
async def walker(server: Server, simulated_site: SimulatedSite) -> AsyncIterator[Session]:
    """A simulated phone walking the lowest level: a session posting a batch per step in
    real time (about 1.5 a second) until the test ends."""
    async with httpx.AsyncClient(base_url=server.url, timeout=30) as http:
        api = ApiClient(http, server.admin_key)
        session = await api.create_session(simulated_site.site.site_id, "step_ekf")
        walk = simulated_walker(
            simulated_site.world, SEED, WALK_LEVEL_INDEX, int(time.time() * 1000), walker_params()
        )

        async def post() -> None:
            loop = asyncio.get_running_loop()
            start = loop.time()
            for seq, (due_s, batch) in enumerate(step_batches(walk.events(), 1), start=1):
                await asyncio.sleep(max(0.0, start + due_s - loop.time()))
                await api.post_batch(session, seq, [item.event for item in batch])

        task = asyncio.create_task(post())
        try:
            yield session
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
            with contextlib.suppress(ApiError, httpx.HTTPError):
                await api.delete_session(session)


@pytest.fixture(scope="session")
async def browser(chromium: Path) -> AsyncIterator[Browser]:
    async with async_playwright() as playwright:
        launched = await playwright.chromium.launch(executable_path=str(chromium))
        yield launched
        await launched.close()


@pytest.fixture
async def tab(browser: Browser, server: Server) -> AsyncIterator[Tab]:
    context = await browser.new_context(viewport={"width": 1366, "height": 860})
    page = await context.new_page()
    found = Tab(page, server.url)

    async def guard(route: Route) -> None:
        if route.request.url.startswith(server.url):
            await route.continue_()
        else:
            found.offsite.append(route.request.url)
            await route.abort()

    await page.route("**/*", guard)
    page.on("pageerror", lambda error: found.errors.append(str(error)))
    yield found
    await context.close()
