"""The coverage heatmap on the floor page, in chromium: the grid's cells drawn over the
plan, their legend, a switch of the figure they are coloured by, and the cell under the
pointer read out."""

from __future__ import annotations

import httpx
import pytest

from tests.support.console_browser import Server, SimulatedSite, Tab

pytestmark = pytest.mark.slow

LAYER = ".layer-heatmap"


async def drawn_cells(server: Server, site: SimulatedSite) -> int:
    """How many cells the console should draw: those of the walkable area and those
    outside it that hold readings or points."""
    async with httpx.AsyncClient(base_url=server.url, timeout=30) as http:
        r = await http.get(
            f"/v1/floors/{site.walk_floor_id}/maps/coverage",
            headers={"Authorization": f"Bearer {site.viewer_key}"},
        )
    assert r.status_code == 200, r.text
    cells = r.json()["cells"]
    return sum(
        area or readings > 0 or points > 0
        for row in zip(cells["in_area"], cells["readings"], cells["points"], strict=True)
        for area, readings, points in zip(*row, strict=True)
    )


async def colouring(tab: Tab) -> list[tuple[str | None, str | None]]:
    """The heatmap's paths as (fill, cells) pairs, in drawing order."""
    paths = tab.page.locator(f"{LAYER} path.heat")
    return [
        (await paths.nth(i).get_attribute("fill"), await paths.nth(i).get_attribute("data-cells"))
        for i in range(await paths.count())
    ]


async def test_the_heatmap_shows(tab: Tab, server: Server, simulated_site: SimulatedSite) -> None:
    page = tab.page
    await tab.login(simulated_site.viewer_key)
    await tab.open(f"#/floors/{simulated_site.walk_floor_id}", "floorPage")
    layer = page.locator(LAYER)
    await page.wait_for_selector(f"{LAYER} path.heat", state="attached")

    # every cell of the floor is drawn, surveyed or not, coloured by the expected error
    expected = await drawn_cells(server, simulated_site)
    assert expected > 0
    assert await layer.get_attribute("data-metric") == "expected_error_m"
    assert int(await layer.get_attribute("data-cells") or 0) == expected
    by_error = await colouring(tab)
    assert sum(int(n or 0) for _, n in by_error) == expected
    assert all(fill and fill.startswith("#") for fill, _ in by_error)
    assert await page.input_value("select[name=heatmap-metric]") == "expected_error_m"
    # a legend of the error classes (round steps over the floor's range) and "no data"
    legend = page.locator(".heat-legend li")
    assert await legend.count() >= 2 + 1
    assert (await legend.first.text_content() or "").startswith(" under ")
    assert await legend.last.get_attribute("data-class") == "none"
    summary = await page.text_content(".heat-summary") or ""
    assert "cells of 2 m hold readings" in summary
    await tab.screenshot("floor-heatmap")

    # another figure: other colours, another legend
    await page.select_option("select[name=heatmap-metric]", "readings")
    assert await layer.get_attribute("data-metric") == "readings"
    by_readings = await colouring(tab)
    assert by_readings != by_error
    assert sum(int(n or 0) for _, n in by_readings) == expected
    assert await legend.count() == 6 + 1
    assert "none" in (await legend.first.text_content() or "")
    await page.select_option("select[name=heatmap-metric]", "age_days")
    assert "days" in (await legend.first.text_content() or "")

    # the cell under the pointer is read out
    box = await page.locator(f"{LAYER} path.heat").first.bounding_box()
    assert box is not None
    await page.mouse.move(box["x"] + 2, box["y"] + 2)
    readout = page.locator(".heat-readout")
    await readout.filter(has_text="expected error").wait_for()
    assert "readings" in (await readout.text_content() or "")

    # a layer like the others: its box hides it
    await page.uncheck("input[name=heatmap]")
    assert "hidden" in (await layer.get_attribute("class") or "")
    await page.check("input[name=heatmap]")
    assert "hidden" not in (await layer.get_attribute("class") or "")
    await page.select_option("select[name=heatmap-metric]", "expected_error_m")
    await tab.screenshot("floor-heatmap-error")
    assert tab.errors == [], tab.errors
    assert tab.offsite == [], f"asked other hosts for {tab.offsite}"
