"""The console against a running server, in chromium: sites to a floor, the plan drawn to
scale, the map-quality layers, a walker followed live, uploads, and the docs pages
working without any other host."""

from __future__ import annotations

import pytest

from client_sim.api import Session
from tests.support.console_browser import Server, SimulatedSite, Tab, beacons_on

pytestmark = pytest.mark.slow

LIVE_TIMEOUT_MS = 20_000


def _no_trouble(tab: Tab) -> None:
    assert tab.errors == [], tab.errors
    assert tab.offsite == [], f"asked other hosts for {tab.offsite}"


async def test_sites_buildings_floors_and_the_plan(tab: Tab, simulated_site: SimulatedSite) -> None:
    page = tab.page
    await tab.login(simulated_site.viewer_key)
    # a key of one site lists that site only
    assert await page.locator("main table tbody tr").count() == 1
    await tab.screenshot("sites")

    await page.click("text=console site")
    await page.wait_for_selector("main[data-page=sitePage]")
    await page.wait_for_selector("main .uploads, main .uploads-body p")
    await tab.screenshot("site")

    await page.click("text=synthetic building")
    await page.wait_for_selector("main[data-page=buildingPage]")
    levels = simulated_site.world.building.levels
    assert await page.locator("main section").first.locator("tbody tr").count() == len(levels)
    await tab.screenshot("building")

    await page.click(f"text=Level {levels[0]}")
    await page.wait_for_selector("main[data-page=floorPage]")
    plan = page.locator("svg#plan")
    assert await plan.locator(".walkable").count() > 0
    assert await plan.locator(".wall").count() > 0
    assert await plan.locator(".door").count() > 0
    beacons = beacons_on(simulated_site.world, levels[0])
    assert beacons > 0
    assert await plan.locator(".beacon").count() == beacons
    # to scale: the view box frames the building in metres (x, -y, width, height)
    box = [float(v) for v in (await plan.get_attribute("viewBox") or "").split()]
    width_m = simulated_site.world.building.width_m
    assert width_m <= box[2] <= 1.2 * width_m
    assert (await page.text_content(".scale-text") or "").endswith(" m")
    await tab.screenshot("floor")
    _no_trouble(tab)


async def test_map_quality_layers_show(tab: Tab, simulated_site: SimulatedSite) -> None:
    page = tab.page
    await tab.login(simulated_site.viewer_key)
    await tab.open(f"#/floors/{simulated_site.walk_floor_id}", "floorPage")
    await page.wait_for_selector(".quality[data-loaded=true]")
    coverage = page.locator(".layer-coverage path.coverage")
    assert await coverage.count() > 0
    assert await page.locator(".layer-coverage path.covered").get_attribute("d")
    assert await page.locator(".layer-emitters .emitter").count() > 0
    facts = await page.text_content(".quality") or ""
    assert "Radio coverage" in facts
    assert "Reference points" in facts

    # a layer goes when its box is unticked, and comes back
    await page.uncheck("input[name=coverage]")
    assert "hidden" in (await page.get_attribute(".layer-coverage", "class") or "")
    await page.check("input[name=magnetic]")
    assert await page.locator(".layer-magnetic rect.magnetic-grid").count() == 1
    await page.check("input[name=coverage]")
    await tab.screenshot("floor-quality")
    _no_trouble(tab)


async def test_a_walkers_dot_moves(
    tab: Tab, simulated_site: SimulatedSite, walker: Session
) -> None:
    page = tab.page
    await tab.login(simulated_site.viewer_key)
    await tab.open(f"#/floors/{simulated_site.walk_floor_id}", "floorPage")
    # followed with the viewer key (the session's token stays with the phone)
    await page.fill("input[name=session]", walker.id)
    await page.click("form.follow button[type=submit]")
    dot = f'.layer-live g.session[data-session="{walker.id}"]:not(.hidden) circle.fix-dot'
    await page.wait_for_selector(dot, state="attached", timeout=LIVE_TIMEOUT_MS)
    first = (await page.get_attribute(dot, "cx"), await page.get_attribute(dot, "cy"))
    await page.wait_for_function(
        """([selector, x, y]) => {
            const el = document.querySelector(selector);
            return el && (el.getAttribute("cx") !== x || el.getAttribute("cy") !== y);
        }""",
        arg=[dot, *first],
        timeout=LIVE_TIMEOUT_MS,
    )
    accuracy = page.locator(f'.layer-live g.session[data-session="{walker.id}"] circle.accuracy')
    assert float(await accuracy.get_attribute("r") or 0) > 0
    row = page.locator(f'ul.sessions li[data-session="{walker.id}"]')
    assert await row.locator(".state").text_content() == "live"
    track = page.locator(f'.layer-tracks polyline[data-session="{walker.id}"]')
    assert len((await track.get_attribute("points") or "").split()) >= 2
    await tab.screenshot("floor-live")
    _no_trouble(tab)


async def test_the_sites_active_sessions_are_followed_by_themselves(
    tab: Tab, simulated_site: SimulatedSite, walker: Session
) -> None:
    """With a session list on the server, the floor page follows the site's active
    sessions without being given their ids."""
    page = tab.page
    await tab.login(simulated_site.viewer_key)
    await tab.open(f"#/floors/{simulated_site.walk_floor_id}", "floorPage")
    dot = f'.layer-live g.session[data-session="{walker.id}"]:not(.hidden) circle.fix-dot'
    await page.wait_for_selector(dot, state="attached", timeout=LIVE_TIMEOUT_MS)
    _no_trouble(tab)


async def test_uploads_and_their_status(tab: Tab, simulated_site: SimulatedSite) -> None:
    page = tab.page
    await tab.login(simulated_site.viewer_key)
    await tab.open("#/uploads", "uploadsPage")
    await page.fill("input[name=upload]", simulated_site.upload_id)
    await page.click("form.inline button[type=submit]")
    status = page.locator(f'tr[data-upload="{simulated_site.upload_id}"] .status')
    await status.wait_for()
    assert await status.text_content() in {"queued", "processing", "done", "rejected", "failed"}
    await tab.screenshot("uploads")
    _no_trouble(tab)


async def test_the_floor_fits_a_phone(tab: Tab, simulated_site: SimulatedSite) -> None:
    page = tab.page
    await page.set_viewport_size({"width": 390, "height": 844})
    await tab.login(simulated_site.viewer_key)
    await tab.open(f"#/floors/{simulated_site.walk_floor_id}", "floorPage")
    await page.wait_for_selector(".quality[data-loaded=true]")
    overflow = await page.evaluate("document.scrollingElement.scrollWidth - window.innerWidth")
    assert overflow <= 0
    await tab.screenshot("floor-phone")
    _no_trouble(tab)


async def test_a_wrong_key_is_refused(tab: Tab) -> None:
    page = tab.page
    await page.goto(f"{tab.base_url}/console")
    assert page.url == f"{tab.base_url}/console/"
    await page.fill("input[name=key]", "not-a-key")
    await page.click("form.key-form button[type=submit]")
    await page.wait_for_selector("form.key-form .error:has-text('not a valid API key')")
    assert await page.evaluate("sessionStorage.length") == 0
    _no_trouble(tab)


@pytest.mark.parametrize(
    ("path", "title"),
    [("/docs", ".swagger-ui .info .title"), ("/redoc", ".api-info h1")],
)
async def test_docs_pages_need_no_other_host(
    tab: Tab, server: Server, path: str, title: str
) -> None:
    page = tab.page
    await page.goto(f"{server.url}{path}")
    heading = page.locator(title)
    await heading.wait_for()
    assert "indoorpos" in (await heading.text_content() or "")
    await tab.screenshot(path.strip("/"), full_page=False)  # the first screen: pages are long
    _no_trouble(tab)
