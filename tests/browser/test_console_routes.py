"""Routes and navigation on the floor page, in chromium: a route between two points picked
on the floor (its origin on one level, its destination on the other), drawn leg by leg
and listed step by step, step-free on request, and a 404's reason when there is none;
and a followed session's navigation (the instruction, what is left, its route and the
fix snapped to it, re-routed after a walk the wrong way)."""

from __future__ import annotations

import re
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Any

import httpx
import pytest
from playwright.async_api import expect

from client_sim.building import Rect
from tests.support.console_browser import Server, SimulatedSite, Tab
from tests.support.sessions import scan
from tests.support.toy_site import ToySite, build_toy_site, linked_toy_plan, new_key

pytestmark = pytest.mark.slow

LIVE_TIMEOUT_MS = 20_000
T0 = 1_700_000_000_000


def _polyline_points(points: str | None) -> int:
    return len((points or "").split())


async def test_a_route_between_two_picked_points(tab: Tab, simulated_site: SimulatedSite) -> None:
    building = simulated_site.world.building
    low, high = building.levels[0], building.levels[-1]
    floor_ids = simulated_site.site.floor_ids

    def rooms(level: int) -> list[Rect]:
        return [r for r in building.floor(level).walkable if r.use == "room"]

    # from a room at the south-west of the lowest level to one at the north-east of the top one
    origin = min(rooms(low), key=lambda r: sum(r.centre)).centre
    destination = max(rooms(high), key=lambda r: sum(r.centre)).centre
    page = tab.page
    tool = page.locator(".route-tool")
    await tab.login(simulated_site.viewer_key)
    await tab.open(f"#/floors/{floor_ids[low]}", "floorPage")
    await page.wait_for_selector("button.route-pick:not([disabled])")

    # a destination outside the building: no route, and the reason
    await page.click("button.route-pick")
    await tab.click_floor(*origin)
    await page.wait_for_selector('.route-tool[data-state="destination"]')
    await tab.click_floor(-2.5, building.depth_m / 2)
    await page.wait_for_selector('.route-tool[data-state="failed"]')
    status = await tool.locator(".route-status").text_content() or ""
    assert status.startswith("No route: destination:"), status
    assert "outside walkable space" in status

    # the origin here, the destination on the level above (the level links keep picking)
    await page.click("button.route-pick")
    await tab.click_floor(*origin)
    await page.wait_for_selector('.route-tool[data-state="destination"]')
    await page.wait_for_selector(".layer-routes .route-origin circle", state="attached")
    await page.click(f'.levels a[href="#/floors/{floor_ids[high]}"]')
    await page.wait_for_selector(f'.levels a.current[href="#/floors/{floor_ids[high]}"]')
    await page.wait_for_selector('.route-tool[data-state="destination"]')
    await page.wait_for_selector(".layer-walkable path.walkable", state="attached")  # the plan
    await tab.click_floor(*destination)
    await page.wait_for_selector('.route-tool[data-state="route"]')

    line = page.locator('.layer-routes g[data-route="planned"] polyline.route-line')
    assert await line.count() == 1  # this floor's leg
    assert _polyline_points(await line.get_attribute("points")) >= 3
    assert await line.get_attribute("data-level") == str(high)
    came = page.locator('.layer-routes g[data-route="planned"] .route-label')
    assert (await came.text_content() or "").endswith(f"from level {low}")
    steps = tool.locator(".route-steps li.route-item")
    assert await steps.count() >= 4
    assert await steps.first.get_attribute("data-kind") == "start"
    assert await steps.last.get_attribute("data-kind") == "arrive"
    kinds = [await steps.nth(i).get_attribute("data-kind") for i in range(await steps.count())]
    assert any(k and k.endswith("_up") for k in kinds), kinds  # up to the destination's level
    total = await tool.locator(".route-total").text_content() or ""
    assert " m · about " in total, total
    await tab.screenshot("floor-route")

    # step-free: the lift instead of the stairs
    await page.check(".route-tool input[name=accessible]")
    await page.wait_for_selector('.route-steps li[data-kind="lift_up"]')
    assert "step-free" in (await tool.locator(".route-total").text_content() or "")

    # back on the origin's level: its own leg, to the way up
    await tool.locator(f'.route-legs a[href="#/floors/{floor_ids[low]}"]').click()
    await page.wait_for_selector(f'.levels a.current[href="#/floors/{floor_ids[low]}"]')
    leg = page.locator('.layer-routes g[data-route="planned"] polyline.route-line')
    await leg.wait_for(state="attached")
    assert await leg.get_attribute("data-level") == str(low)
    label = page.locator('.layer-routes g[data-route="planned"] .step-change .route-label')
    assert await label.text_content() == f"↑ to level {high}"
    await tab.screenshot("floor-route-other-level")
    assert tab.errors == [], tab.errors
    assert tab.offsite == [], f"asked other hosts for {tab.offsite}"


@dataclass(frozen=True)
class LinkedToySite:
    site: ToySite
    viewer_key: str


@pytest.fixture(scope="module")
async def linked_toy_site(server: Server) -> LinkedToySite:
    """The toy site with its stairs, lift and information desk on both floors, and a
    viewer key for it."""
    admin = {"Authorization": f"Bearer {server.admin_key}"}
    async with httpx.AsyncClient(base_url=server.url, timeout=60) as http:
        site = await build_toy_site(http, admin)
        for floor_id in site.floor_ids.values():
            r = await http.put(f"/v1/floors/{floor_id}/plan", json=linked_toy_plan(), headers=admin)
            assert r.status_code in (200, 201), r.text
        _, viewer_key = await new_key(http, admin, ("viewer",), site.site_id)
    return LinkedToySite(site, viewer_key)


class Walker:
    """A wknn session of the toy site: a scan a second makes a fix at the scan's place."""

    def __init__(self, http: httpx.AsyncClient, session_id: str, token: str) -> None:
        self.http, self.id, self.token = http, session_id, token
        self.auth = {"Authorization": f"Bearer {token}"}
        self.seq = 0

    async def at(self, x_m: float, y_m: float, level: int = 0) -> dict[str, Any]:
        self.seq += 1
        body = {"seq": self.seq, "events": [scan(T0 + 1000 * self.seq, x_m, y_m, level)]}
        r = await self.http.post(f"/v1/sessions/{self.id}/batches", json=body, headers=self.auth)
        assert r.status_code == 200, r.text
        fix: dict[str, Any] = r.json()["fixes"][-1]
        return fix


@pytest.fixture
async def toy_walker(server: Server, linked_toy_site: LinkedToySite) -> AsyncIterator[Walker]:
    site = linked_toy_site.site
    async with httpx.AsyncClient(base_url=server.url, timeout=30) as http:
        body = {"site_id": site.site_id, "engine": "wknn"}
        r = await http.post("/v1/sessions", json=body, headers=site.device)
        assert r.status_code == 201, r.text
        walker = Walker(http, r.json()["id"], r.json()["token"])
        yield walker
        await http.delete(f"/v1/sessions/{walker.id}", headers=walker.auth)


async def test_a_followed_sessions_navigation(
    tab: Tab, linked_toy_site: LinkedToySite, toy_walker: Walker
) -> None:
    floors = linked_toy_site.site.floor_ids
    await toy_walker.at(10.0, 2.0)
    # to the floor above, re-routed soon once off the route
    body = {
        "destination": {"floor_id": floors[1], "x_m": 12.0, "y_m": 8.0},
        "settings": {"off_route_m": 3.0, "reroute_after_s": 2.0},
    }
    url = f"/v1/sessions/{toy_walker.id}/navigation"
    r = await toy_walker.http.put(url, json=body, headers=toy_walker.auth)
    assert r.status_code == 200, r.text

    page = tab.page
    await tab.login(linked_toy_site.viewer_key)
    await tab.open(f"#/floors/{floors[0]}", "floorPage")
    await page.fill("input[name=session]", toy_walker.id)
    await page.click("form.follow button[type=submit]")
    row = f'ul.sessions li[data-session="{toy_walker.id}"]'
    await page.wait_for_selector(f"{row} .state-live", timeout=LIVE_TIMEOUT_MS)
    for x, y in ((11.0, 2.5), (12.0, 3.0)):  # along the route, east to the stairs
        fix = await toy_walker.at(x, y)
    progress = fix["navigation"]

    line = page.locator(f"{row} .nav-line")
    drawn = f'.layer-routes g.nav-route[data-session="{toy_walker.id}"]'
    await page.wait_for_selector(f"{drawn} polyline.route-line", state="attached")
    await page.wait_for_selector(f"{drawn} circle.nav-snapped", state="attached")
    await expect(line.locator(".nav-instruction")).to_have_text(progress["instruction"])
    left = re.compile(r"^\d+ m · \d+ s left to level 1 \(12, 8\)$")
    await expect(line.locator(".nav-remaining")).to_have_text(left)
    assert await line.locator(".nav-on").count() == 1
    label = page.locator(f"{drawn} .step-change .route-label")
    assert await label.text_content() == "↑ to level 1"
    assert await line.get_attribute("data-route-version") == "0"
    await tab.screenshot("floor-navigation")

    # west, the wrong way: off the route, then re-routed from where the walker went
    for x in (8.0, 6.0, 5.0):
        await toy_walker.at(x, 2.0)
    await page.wait_for_selector(f"{row} .nav-line .nav-off")
    await toy_walker.at(4.0, 2.0)
    await page.wait_for_selector(f'{row} .nav-line[data-route-version="1"]')
    await page.wait_for_selector(f"{row} .nav-event-rerouted")
    await page.wait_for_selector(f'{drawn}[data-route-version="1"] polyline.route-line')
    await tab.screenshot("floor-navigation-rerouted")

    # a viewer key may watch, not guide: the console says what it takes
    await page.click(f"{row} button.nav-action")
    refused = page.locator(f"{row} .nav-refused")
    await refused.wait_for()
    assert "admin key" in (await refused.text_content() or "")

    # followed again with the session's token, the console ends its navigation and starts
    # another
    await page.fill("input[name=session]", toy_walker.id)
    await page.fill("input[name=token]", toy_walker.token)
    await page.click("form.follow button[type=submit]")
    await page.wait_for_selector(f"{row} .state-live", timeout=LIVE_TIMEOUT_MS)
    await toy_walker.at(4.0, 2.5)
    await expect(page.locator(f"{row} button.nav-action")).to_have_text("End navigation")
    await page.click(f"{row} button.nav-action")
    await expect(page.locator(f"{row} button.nav-action")).to_have_text("Navigate…")
    assert await page.locator(f"{drawn} polyline").count() == 0
    await page.click(f"{row} button.nav-action")
    await page.wait_for_selector('.route-tool[data-state="picking-for"]')
    await tab.click_floor(10.0, 8.0)  # the information desk
    await expect(line.locator(".nav-remaining")).to_contain_text("left to level 0 (10, 8)")
    await page.wait_for_selector(f"{drawn} polyline.route-line", state="attached")
    r = await toy_walker.http.get(url, headers=toy_walker.auth)
    assert r.status_code == 200, r.text
    assert r.json()["route"]["destination"]["x_m"] == 10.0
    assert tab.errors == [], tab.errors
    assert tab.offsite == [], f"asked other hosts for {tab.offsite}"
