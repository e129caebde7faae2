"""A followed session's history on the floor page: its fixes loaded, and the time slider
moving the session's dot back to its first fix and forward again."""

from __future__ import annotations

import pytest

from client_sim.api import Session
from tests.support.console_browser import SimulatedSite, Tab

pytestmark = pytest.mark.slow

LIVE_TIMEOUT_MS = 20_000
MIN_FIXES = 5


async def test_the_history_slider_moves_the_dot_back_in_time(
    tab: Tab, simulated_site: SimulatedSite, walker: Session
) -> None:
    page = tab.page
    await tab.login(simulated_site.viewer_key)
    await tab.open(f"#/floors/{simulated_site.walk_floor_id}", "floorPage")
    await page.fill("input[name=session]", walker.id)
    await page.click("form.follow button[type=submit]")
    group = f'.layer-live g.session[data-session="{walker.id}"]'
    dot = f"{group} circle.fix-dot"
    await page.wait_for_selector(f"{group}:not(.hidden)", state="attached", timeout=LIVE_TIMEOUT_MS)
    # a few fixes into the walk
    await page.wait_for_function(
        """([selector, n]) => {
            const points = document.querySelector(selector)?.getAttribute("points") ?? "";
            return points.trim().split(/\\s+/).length >= n;
        }""",
        arg=[f'.layer-tracks polyline[data-session="{walker.id}"]', MIN_FIXES],
        timeout=LIVE_TIMEOUT_MS,
    )
    await page.click(f'ul.sessions li[data-session="{walker.id}"] button.history-open')
    slider = page.locator(".history input[type=range][name=history]")
    await slider.wait_for()
    newest = int(await slider.get_attribute("max") or 0)
    assert newest + 1 >= MIN_FIXES
    live_t = int(await page.get_attribute(group, "data-t") or 0)
    live_xy = (await page.get_attribute(dot, "cx"), await page.get_attribute(dot, "cy"))

    await slider.fill("0")  # back to the session's first fix
    first_t = int(await page.get_attribute(group, "data-t") or 0)
    assert first_t < live_t
    assert int(await page.get_attribute(".history", "data-t") or 0) == first_t
    assert (await page.get_attribute(dot, "cx"), await page.get_attribute(dot, "cy")) != live_xy
    # live fixes leave the dot where the slider put it: one comes (the row's last fix
    # moves on), the dot stays
    row = f'ul.sessions li[data-session="{walker.id}"]'
    row_t = int(await page.get_attribute(row, "data-t") or 0)
    await page.wait_for_function(
        "([selector, t]) => Number(document.querySelector(selector)?.dataset.t ?? 0) > t",
        arg=[row, row_t],
        timeout=LIVE_TIMEOUT_MS,
    )
    assert int(await page.get_attribute(group, "data-t") or 0) == first_t
    await tab.screenshot("floor-history")

    await slider.fill(str(newest // 2))  # forward again, halfway
    halfway_t = int(await page.get_attribute(group, "data-t") or 0)
    assert first_t <= halfway_t <= live_t
    assert tab.errors == [], tab.errors
    assert tab.offsite == [], f"asked other hosts for {tab.offsite}"
