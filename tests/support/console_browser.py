"""What the console's browser tests hold on to (their fixtures: ``tests/browser/conftest.py``):
the ``indoorpos serve`` under test, the simulated site it serves, and a browser tab that
records what went wrong in it and leaves screenshots under ``test-artifacts/console/``."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from playwright.async_api import Page

from client_sim.site import ProvisionedSite
from client_sim.world import SyntheticWorld

ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts" / "console"
WALK_LEVEL_INDEX = 0  # walker 0 walks the building's lowest level


@dataclass(frozen=True)
class Server:
    url: str
    admin_key: str
    log: Path


@dataclass(frozen=True)
class SimulatedSite:
    site: ProvisionedSite
    world: SyntheticWorld
    viewer_key: str  # the viewer scope, for this site only: what the console logs in with
    upload_id: str

    @property
    def walk_floor_id(self) -> str:
        return self.site.floor_ids[self.world.building.levels[WALK_LEVEL_INDEX]]


def beacons_on(world: SyntheticWorld, level: int) -> int:
    """How many of the world's BLE beacons hang on ``level``."""
    return sum(at == level for at in world.radio.ble.level.tolist())


@dataclass
class Tab:
    """A page of the browser, with what went wrong in it: scripts that threw, and requests
    for anything not served by the server under test (aborted)."""

    page: Page
    base_url: str
    errors: list[str] = field(default_factory=list)
    offsite: list[str] = field(default_factory=list)

    async def login(self, key: str) -> None:
        await self.page.goto(f"{self.base_url}/console/")
        await self.page.fill("input[name=key]", key)
        await self.page.click("form.key-form button[type=submit]")
        await self.page.wait_for_selector("main[data-page=sitesPage]")

    async def open(self, fragment: str, page_name: str) -> None:
        """Go to a console page (``#/...``) and wait until it has drawn."""
        await self.page.evaluate("delete document.getElementById('main')?.dataset.page")
        await self.page.goto(f"{self.base_url}/console/{fragment}")
        await self.page.wait_for_selector(f"main[data-page={page_name}]")

    async def click_floor(self, x_m: float, y_m: float) -> None:
        """Click the floor map at (x, y) in floor metres (where the map draws it now)."""
        await self.page.locator("#plan").scroll_into_view_if_needed()
        x, y = await self.page.evaluate(
            """([x, y]) => {
                const p = new DOMPoint(x, y).matrixTransform(
                    document.querySelector("#plan .world").getScreenCTM());
                return [p.x, p.y];
            }""",
            [x_m, y_m],
        )
        await self.page.mouse.click(x, y)

    async def screenshot(self, name: str, *, full_page: bool = True) -> Path:
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        path = ARTIFACTS / f"{name}.png"
        await self.page.screenshot(path=str(path), full_page=full_page)
        return path
