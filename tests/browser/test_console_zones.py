"""Zones on the floor page, in chromium: drawn over the plan with their names, listed, and
lit while a followed walker is in one."""

from __future__ import annotations

from typing import Any

import httpx
import pytest

from client_sim.api import Session
from tests.support.console_browser import Server, SimulatedSite, Tab

pytestmark = pytest.mark.slow

LIVE_TIMEOUT_MS = 30_000


def _rect(zone_id: str, name: str, x0: float, y0: float, x1: float, y1: float) -> dict[str, Any]:
    ring = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
    return {
        "type": "Feature",
        "id": zone_id,
        "feature_type": "geofence",
        "properties": {"name": name},
        "geometry": {"type": "Polygon", "coordinates": [ring]},
    }


async def test_zones_are_drawn_and_lit_while_a_walker_is_in_one(
    tab: Tab, server: Server, simulated_site: SimulatedSite, walker: Session
) -> None:
    building = simulated_site.world.building
    zones = {
        "type": "FeatureCollection",
        "features": [
            # the whole floor: the walker is in it once the dwell time has passed
            _rect("everywhere", "Whole floor", 0, 0, building.width_m, building.depth_m),
            _rect("corner", "Corner", 0, 0, 3, 3),
        ],
    }
    async with httpx.AsyncClient(base_url=server.url, timeout=30) as http:
        r = await http.put(
            f"/v1/floors/{simulated_site.walk_floor_id}/zones",
            json=zones,
            headers={"Authorization": f"Bearer {server.admin_key}"},
        )
    assert r.status_code == 200, r.text

    page = tab.page
    await tab.login(simulated_site.viewer_key)
    await tab.open(f"#/floors/{simulated_site.walk_floor_id}", "floorPage")
    await page.wait_for_selector(".layer-zones path.zone", state="attached")
    drawn = page.locator(".layer-zones path.zone")
    assert await drawn.count() == 2
    assert {await drawn.nth(i).get_attribute("data-zone") for i in range(2)} == {
        "everywhere",
        "corner",
    }
    labels = await page.locator(".layer-zones text.zone-label").all_text_contents()
    assert sorted(labels) == ["Corner", "Whole floor"]
    assert await page.locator(".zone-list li").count() == 2
    await page.uncheck("input[name=zones]")
    assert "hidden" in (await page.get_attribute(".layer-zones", "class") or "")
    await page.check("input[name=zones]")

    # the walker, followed (the site's active sessions are followed by themselves)
    lit = '.layer-zones path.zone.occupied[data-zone="everywhere"]'
    await page.wait_for_selector(lit, state="attached", timeout=LIVE_TIMEOUT_MS)
    count = page.locator('.zone-list li[data-zone="everywhere"] .zone-count')
    assert (await count.text_content() or "").endswith(" in")
    await tab.screenshot("floor-zones")
    assert tab.errors == [], tab.errors
    assert tab.offsite == [], tab.offsite
