"""``indoorpos plan-survey``: where to put reference points on a floor (Wang et al.'s
placement theory, ``mapping.survey_plan``), for a floor of the service or of an ILC
site, as GeoJSON and, with ``--plots``, drawn on the floor plan."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from server.cli.output import console
from server.config import get_settings
from server.services.errors import ServiceError
from server.services.runtime import open_runtime
from server.services.survey_plans import FloorSurveyPlan, floor_survey_plan, plan_floor
from server.storage import db

plan_survey_app = typer.Typer(
    help="Where to survey a floor: reference points a noise distance apart.",
    no_args_is_help=True,
)

NoiseOption = Annotated[
    float | None,
    typer.Option(min=0.01, help="a constant noise distance (m) instead of the map's own"),
]
JsonOption = Annotated[Path | None, typer.Option("--json", help="write the GeoJSON here")]
PlotsOption = Annotated[Path | None, typer.Option(help="draw the plan into this directory")]


def _report(
    found: FloorSurveyPlan,
    plan: dict[str, Any] | None,
    name: str,
    json_path: Path | None,
    plots: Path | None,
) -> None:
    summary = found.geojson()["properties"]
    table = Table(title=f"survey plan of {name}")
    for key in (
        "n_points",
        "n_surveyed",
        "grid_m",
        "noise_db",
        "noise_source",
        "n_access_points",
        "expected_error_m",
        "expected_error_p90_m",
    ):
        value = summary[key]
        table.add_row(key, f"{value:.2f}" if isinstance(value, float) else str(value))
    console.print(table)
    if json_path is not None:
        json_path.write_text(json.dumps(found.geojson()))
        console.print(f"GeoJSON written to {json_path}")
    if plots is not None:
        from lab.floor_plots import plot_survey_plan

        out = plot_survey_plan(
            plots / f"survey_plan_{name}.png",
            title=f"{name}: {summary['n_points']} planned points, "
            f"{summary['expected_error_m']:.1f} m expected",
            plan=plan,
            points_xy_m=found.plan.points,
            from_aps=found.plan.from_aps,
            surveyed=found.surveyed,
            rp_xy_m=found.rp_xy,
            ap_xy_m=[a.xy for a in found.plan.aps],
        )
        console.print(f"figure written to {out}")


@plan_survey_app.command("floor")
def plan_floor_of_service(
    floor_id: Annotated[str, typer.Argument(help="a floor of the service's database")],
    noise_distance_m: NoiseOption = None,
    json_path: JsonOption = None,
    plots: PlotsOption = None,
) -> None:
    """Plan a floor of the service from its stored plan and its building's radio map."""
    settings = get_settings()
    db.migrate(settings.resolved_database_url)

    async def work() -> tuple[FloorSurveyPlan, dict[str, Any] | None]:
        from server.storage.repositories import sites as site_repo

        async with open_runtime(settings) as rt, rt.transaction() as s:
            found = await floor_survey_plan(s, floor_id, noise_distance_m)
            floor = await site_repo.get_floor(s, floor_id)
            return found, floor.plan_geojson if floor else None

    try:
        found, plan = asyncio.run(work())
    except ServiceError as exc:
        console.print(f"[red]{exc.field or 'floor'}: {exc.message}[/]")
        raise typer.Exit(1) from None
    _report(found, plan, floor_id, json_path, plots)


@plan_survey_app.command("ilc")
def plan_floor_of_ilc(
    site_dir: Annotated[
        Path, typer.Argument(exists=True, file_okay=False, help="ILC site directory")
    ],
    floor: Annotated[str, typer.Option(help="floor name, e.g. F1")],
    noise_distance_m: NoiseOption = None,
    json_path: JsonOption = None,
    plots: PlotsOption = None,
) -> None:
    """Plan a floor of an ILC site from its plan and a radio map of all its traces."""
    from lab.datasets.ilc import read_site
    from lab.training_maps import build_site_maps

    site = read_site(site_dir)
    names = [f.name for f in site.floors]
    if floor not in names:
        raise typer.BadParameter(
            f"no floor {floor!r}; the site has {', '.join(names)}", param_hint="--floor"
        )
    index = names.index(floor)
    traces = [(index, path) for path in site.floors[index].trace_files]
    maps, _, _ = build_site_maps(site, traces, parts=())
    plan = site.floors[index].plan
    try:
        found = plan_floor(floor, plan, maps.radio, index, noise_distance_m)
    except ServiceError as exc:
        console.print(f"[red]{exc.field or 'floor'}: {exc.message}[/]")
        raise typer.Exit(1) from None
    _report(found, plan, floor, json_path, plots)
