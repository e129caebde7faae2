"""How long the worker takes to build a site's maps, and how much memory it needs.

An ILC site's training traces (the evaluation's split) go into a throw-away embedded
service as an operator would survey them: each scan a survey point with its walk, the
floor plans on their floors, through the services the API calls. The worker's own build
(``worker.build_maps``: the version's points read from SQL, ``map_set.build_map_set``,
the artefacts stored) is then timed, and the process' peak resident memory during it is
read from ``/proc/self/status`` after the kernel's high-water mark was reset
(``/proc/self/clear_refs``), so it is the build's peak, not the survey's.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import anyio

from lab.datasets.ilc import read_site
from lab.progress import Progress
from lab.service_replay import survey_points
from lab.split import split_site
from lab.training_maps import build_site_maps
from server import worker
from server.config import Settings
from server.positioning.mapping.survey_points import SurveyPointData
from server.services import maps, sites
from server.services.runtime import open_runtime
from server.storage import db
from server.storage.repositories import maps as map_repo

CHUNK = 5000  # survey points per request, as the simulator sends them


def _rss_kib(field: str) -> int | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def _reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return False
    return True


def map_build_bench(
    site_dir: Path, *, split_seed: int = 0, progress: Progress | None = None
) -> dict[str, Any]:
    """Survey the site's training traces into an embedded service and time the worker's
    build of the resulting radio map version (module docstring)."""
    site = read_site(site_dir)
    split = split_site(site, split_seed, 0.8)
    _, survey, _ = build_site_maps(site, split.train, progress, parts=())
    levels = [f.level for f in site.floors]
    points = survey_points(survey.scans, levels)

    async def run(settings: Settings) -> dict[str, Any]:
        async with open_runtime(settings) as rt:
            async with rt.transaction() as s:
                created = await sites.create_site(s, f"bench {site.name}")
                building = await sites.create_building(s, created.id, name=site.name)
                for floor in site.floors:
                    made = await sites.create_floor(s, building.id, floor.level, floor.name)
                    if floor.plan:
                        await sites.put_floor_plan(s, made.id, floor.plan)
            for done, start in enumerate(range(0, len(points), CHUNK), start=1):
                chunk = [_point(p) for p in points[start : start + CHUNK]]
                async with rt.transaction() as s:
                    await maps.add_survey(s, building.id, chunk)
                if progress:
                    progress("survey", done, -(-len(points) // CHUNK))
            reset = _reset_peak()
            before = _rss_kib("VmRSS")
            started = time.perf_counter()
            built = await worker.build_maps(rt)
            wall_s = time.perf_counter() - started
            peak = _rss_kib("VmHWM") if reset else None
            async with rt.read() as s:
                row = await map_repo.latest_radio_map(s, building.id)
                assert row is not None
                return {
                    "site": site.name,
                    "floors": len(site.floors),
                    "survey_points": len(points),
                    "reference_points": row.n_reference_points,
                    "emitters": row.n_emitters,
                    "versions_built": built,
                    "build_status": row.build_status,
                    "build_s": row.build_seconds,
                    "wall_s": round(wall_s, 2),
                    "rss_before_mib": round(before / 1024, 1) if before else None,
                    "peak_rss_mib": round(peak / 1024, 1) if peak else None,
                }

    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(data_dir=Path(tmp), database_url=None, redis_url=None)
        db.migrate(settings.resolved_database_url)
        return anyio.run(run, settings)


def _point(body: dict[str, Any]) -> SurveyPointData:
    return SurveyPointData(
        x_m=body["x_m"],
        y_m=body["y_m"],
        floor_level=body["floor"],
        t_ms=body["t"],
        wifi=[(r["bssid"], r["rssi_dbm"]) for r in body.get("wifi", [])],
        ble=[(r["id"], r["rssi_dbm"]) for r in body.get("ble", [])],
        mag_ut=None,
        walk=body.get("walk"),
        route=body.get("route"),
        wifi_age_ms=[r.get("age_ms") for r in body.get("wifi", [])],
        ble_age_ms=[r.get("age_ms") for r in body.get("ble", [])],
    )
