"""``indoorpos evaluate``: engines and methods measured on recorded datasets."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Sequence
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from lab.cli.embedded import embedded_service
from lab.cli.reports import StageProgress, print_report, progress_bar
from server.cli.output import console

evaluate_app = typer.Typer(
    help="Measure engines and methods on recorded datasets.", no_args_is_help=True
)


class MapSource(StrEnum):
    survey = "survey"
    crowd = "crowd"


def _write_json(json_path: Path, runs: Sequence[Any]) -> None:
    """The runs' summaries (one, or ``{"runs": [...]}``) and every scored point."""
    payload = runs[0].summary if len(runs) == 1 else {"runs": [r.summary for r in runs]}
    json_path.write_text(json.dumps(payload, indent=2) + "\n")
    console.print(f"metrics written to {json_path}")
    _write_points(json_path, runs)


def _write_points(json_path: Path, runs: Sequence[Any]) -> None:
    """The per-point errors of each run beside the summary: ``out.points.csv`` (one
    engine) or ``out.<engine>.points.csv``."""
    from lab.scoring import write_points

    for run in runs:
        middle = f".{run.summary['engine']}" if len(runs) > 1 else ""
        points = json_path.with_name(f"{json_path.stem}{middle}.points.csv")
        write_points(run.paths, points)
        console.print(f"per-point errors written to {points}")


@evaluate_app.command("ilc")
def evaluate_ilc(
    site_dir: Annotated[
        Path, typer.Argument(exists=True, file_okay=False, help="site or floor directory")
    ],
    engine: Annotated[list[str], typer.Option(help="engine to replay (repeat to compare)")],
    json_path: Annotated[Path | None, typer.Option("--json", help="write the metrics here")] = None,
    split_seed: Annotated[int, typer.Option(help="seed of the per-floor path split")] = 0,
    train_fraction: Annotated[float, typer.Option(min=0.05, max=0.95)] = 0.8,
    plots: Annotated[Path | None, typer.Option(help="write figures into this directory")] = None,
    via_http: Annotated[
        str | None, typer.Option(help="replay through the service at this URL instead")
    ] = None,
    admin_key: Annotated[
        str | None, typer.Option(envvar="INDOORPOS_ADMIN_KEY", help="admin key for --via-http")
    ] = None,
    map_source: Annotated[
        MapSource,
        typer.Option(
            help="survey: maps from the training traces' waypoints (in process); crowd: the "
            "training traces go through the upload API keeping only their first and last "
            "waypoint, and the service's worker builds the maps"
        ),
    ] = MapSource.survey,
    validation: Annotated[
        bool,
        typer.Option(
            "--validation",
            help="score on a split inside the training traces (for choosing parameters); "
            "the test traces are not read",
        ),
    ] = False,
    param: Annotated[
        list[str] | None,
        typer.Option(
            help="NAME=VALUE: an engine parameter other than its default (repeatable; "
            "in-process replay only)"
        ),
    ] = None,
) -> None:
    """Replay ILC 2.0 test traces through engines, with maps built from training traces."""
    from lab.engine_params import engine_params
    from lab.ilc_evaluation import evaluate_ilc
    from lab.replay import in_process_replayer
    from lab.service_replay import http_replayer, summarise_crowd
    from server.positioning.model.params import assignments as nested

    if via_http and not admin_key:
        raise typer.BadParameter("--via-http needs --admin-key (or INDOORPOS_ADMIN_KEY)")
    overrides = dict(p.partition("=")[::2] for p in param or [])
    chosen = {}
    for name in engine:
        try:
            chosen[name] = engine_params(name, overrides) if overrides else None
        except (KeyError, ValueError) as e:
            raise typer.BadParameter(str(e.args[0]), param_hint="--param") from None

    from lab.ilc_evaluation import prepare_ilc

    runs = []
    crowd_reports: list[list[dict[str, Any]]] = []
    with contextlib.ExitStack() as stack, progress_bar() as bar:
        progress = StageProgress(bar)
        service = (via_http, admin_key or "") if via_http else None
        if map_source is MapSource.crowd and service is None:
            service = stack.enter_context(embedded_service())
        sites: dict[int, str] = {}  # the service's site of the training set, shared
        # the maps every engine reads, built once for all of them
        setup = prepare_ilc(
            site_dir,
            engine,
            split_seed=split_seed,
            train_fraction=train_fraction,
            progress=progress,
            validation=validation,
        )

        for name in engine:
            progress.tasks.clear()
            reports: list[dict[str, Any]] | None = None
            if map_source is MapSource.crowd:
                reports = []
                crowd_reports.append(reports)
            replayer = (
                http_replayer(
                    service[0],
                    service[1],
                    progress,
                    reports,
                    nested(param or []),
                    sites,
                    seed=split_seed,  # the in-process replay's random stream
                )
                if service is not None
                else in_process_replayer(split_seed, progress, chosen[name])
            )
            runs.append(
                evaluate_ilc(
                    site_dir,
                    name,
                    split_seed=split_seed,
                    train_fraction=train_fraction,
                    progress=progress,
                    replayer=replayer,
                    validation=validation,
                    setup=setup,
                )
            )

    def cell(value: object, pattern: str = "{:.2f}") -> str:
        return "–" if value is None else pattern.format(value)

    per_run: list[list[dict[str, Any]] | None] = [*crowd_reports] or [None] * len(runs)
    for run, reports in zip(runs, per_run, strict=True):
        if overrides:
            run.summary["params"] = overrides
        if reports is not None:
            summarise_crowd(run.summary, reports)
        if reports is not None:  # the crowd maps' radio error is the service's own
            run.summary.pop("radio_error_68_m", None)
        title = f"ILC {run.site.name} · {run.summary['engine']}"
        per_floor: dict[str, dict[str, object]] = run.summary.get("per_floor", {})
        print_report(title, {k: v for k, v in run.summary.items() if k != "per_floor"})
        if not per_floor:
            continue
        magnetic = any("magnetic_coverage" in f for f in per_floor.values())
        table = Table(title=f"{title} · per floor")
        for column in ("floor", "paths", "n", "mean (m)", "P50 (m)", "P90 (m)", "floor hit"):
            table.add_column(column, justify="left" if column == "floor" else "right")
        if magnetic:
            table.add_column("field known: cells", justify="right")
            table.add_column("at waypoints", justify="right")
        for name, f in per_floor.items():
            row = [name, str(f["test_paths"]), str(f["n_points"])]
            row += [cell(f[k]) for k in ("mean_m", "p50_m", "p90_m")]
            row.append(cell(f["floor_hit_rate"], "{:.1%}"))
            if magnetic:
                row.append(cell(f.get("magnetic_coverage"), "{:.1%}"))
                row.append(cell(f.get("magnetic_at_waypoints"), "{:.1%}"))
            table.add_row(*row)
        console.print(table)
    if json_path is not None:
        _write_json(json_path, runs)
    if plots is not None:
        from lab.evaluation_plots import write_ilc_plots

        written = write_ilc_plots(runs, plots)
        console.print(f"{len(written)} figures written to {plots}")


@evaluate_app.command("ipin")
def evaluate_ipin(
    venue_dir: Annotated[
        Path,
        typer.Argument(
            exists=True,
            file_okay=False,
            help="venue folder: logs/, BLE_Locations.csv, references.csv",
        ),
    ],
    engine: Annotated[list[str], typer.Option(help="engine to replay (repeat to compare)")],
    json_path: Annotated[Path | None, typer.Option("--json", help="write the metrics here")] = None,
    validation: Annotated[
        bool,
        typer.Option(
            "--validation",
            help="read only repetitions 01 and 03 of every trial (one per phone; maps and "
            "scoring), for choosing parameters",
        ),
    ] = False,
    param: Annotated[
        list[str] | None,
        typer.Option(help="NAME=VALUE: an engine parameter other than its default (repeatable)"),
    ] = None,
    via_http: Annotated[
        str | None,
        typer.Option(
            help="replay through the service at this URL instead: each fold's training logs "
            "go up as a survey, each left-out log is one session"
        ),
    ] = None,
    admin_key: Annotated[
        str | None, typer.Option(envvar="INDOORPOS_ADMIN_KEY", help="admin key for --via-http")
    ] = None,
) -> None:
    """Replay IPIN 2023 Track 3 logs through engines, leaving one trial out of the maps."""
    from lab import ipin_evaluation
    from lab.engine_params import engine_params
    from lab.service_replay import http_replayer
    from server.positioning.model.params import assignments as nested

    if via_http and not admin_key:
        raise typer.BadParameter("--via-http needs --admin-key (or INDOORPOS_ADMIN_KEY)")
    overrides = dict(p.partition("=")[::2] for p in param or [])
    for name in engine:
        try:
            engine_params(name, overrides)
        except (KeyError, ValueError) as e:
            raise typer.BadParameter(str(e.args[0]), param_hint="--param") from None
    runs = []
    with progress_bar() as bar:
        progress = StageProgress(bar)
        sites: dict[int, str] = {}  # the service's site of each fold, shared by the engines
        # the logs read and each fold's maps built once for every engine
        setup = ipin_evaluation.prepare_ipin(
            venue_dir, engine, validation=validation, progress=progress
        )
        for name in engine:
            progress.tasks.clear()
            replayer = (
                http_replayer(
                    via_http,
                    admin_key or "",
                    progress,
                    params=nested(param or []),
                    sites=sites,
                    seed=0,  # evaluate_ipin's in-process seed
                )
                if via_http
                else None
            )
            runs.append(
                ipin_evaluation.evaluate_ipin(
                    venue_dir,
                    name,
                    validation=validation,
                    progress=progress,
                    params=overrides or None,
                    setup=setup,
                    replayer=replayer,
                )
            )
    for run in runs:
        summary = run.summary
        title = f"IPIN {run.venue.name} · {summary['engine']}"
        print_report(title, {k: v for k, v in summary.items() if not isinstance(v, dict)})
        table = Table(title=f"{title} · per log")
        for column in ("trial", "rep", "phone", "n", "IPIN score (m)", "mean (m)", "floor hit"):
            table.add_column(column, justify="left" if column == "phone" else "right")
        for f in summary["per_log"].values():
            score, mean = f["ipin_score_m"], f["mean_m"]
            table.add_row(
                str(f["trial"]),
                str(f["repetition"]),
                f["phone"],
                str(f["n_points"]),
                "–" if score is None else f"{score:.2f}",
                "–" if mean is None else f"{mean:.2f}",
                "–" if f["floor_hit_rate"] is None else f"{f['floor_hit_rate']:.1%}",
            )
        console.print(table)
    if json_path is not None:
        _write_json(json_path, runs)


class StepDetector(StrEnum):
    mansour = "mansour"
    cui = "cui"
    wang = "wang"


class StepLength(StrEnum):
    mansour = "mansour"
    weinberg = "weinberg"


class HeadingChoice(StrEnum):
    fused = "fused"
    rotation = "rotation"
    attitude = "attitude"


@evaluate_app.command("pdr")
def evaluate_pdr(
    site_dir: Annotated[
        Path, typer.Argument(exists=True, file_okay=False, help="ILC site or floor directory")
    ],
    detector: Annotated[StepDetector, typer.Option(help="step detector")] = StepDetector.mansour,
    length_model: Annotated[
        StepLength, typer.Option(help="step-length model")
    ] = StepLength.mansour,
    heading: Annotated[
        HeadingChoice, typer.Option(help="heading source of the tracker")
    ] = HeadingChoice.fused,
    json_path: Annotated[Path | None, typer.Option("--json", help="write the metrics here")] = None,
    split_seed: Annotated[int, typer.Option(help="seed of the per-floor path split")] = 0,
    train_fraction: Annotated[float, typer.Option(min=0.05, max=0.95)] = 0.8,
) -> None:
    """PDR alone on ILC 2.0 traces: walked-distance error of step detection against the
    waypoints, and dead-reckoning drift from the first waypoint."""
    from lab import pdr_evaluation
    from server.positioning.motion.step_tracker import TrackerParams

    params = pdr_evaluation.with_detector(
        TrackerParams(heading=heading.value), detector.value, length_model.value
    )
    with progress_bar() as bar:
        progress = StageProgress(bar)

        result = pdr_evaluation.evaluate_pdr(
            site_dir,
            params,
            split_seed=split_seed,
            train_fraction=train_fraction,
            progress=progress,
        )
    flat = {k: v for k, v in result.items() if not isinstance(v, dict | list)}
    for part in (
        "distance_paper",
        "distance_trained",
        "dead_reckoning",
        "dead_reckoning_straightened",
    ):
        flat.update({f"{part}.{k}": v for k, v in result[part].items()})
    print_report(f"PDR on {site_dir.name}", flat)
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
        console.print(f"metrics written to {json_path}")


@evaluate_app.command("uji")
def evaluate_uji(
    train_csv: Annotated[Path, typer.Argument(exists=True, dir_okay=False)],
    test_csv: Annotated[Path, typer.Argument(exists=True, dir_okay=False)],
    method: Annotated[str, typer.Option(help="fingerprint method")] = "wknn",
    k: Annotated[int, typer.Option(min=1, help="neighbours")] = 4,
    device_offsets: Annotated[
        bool,
        typer.Option(
            "--device-offsets",
            help="estimate per-phone RSS offsets on the training set and take them off "
            "training and test readings (phones unknown to training: not corrected)",
        ),
    ] = False,
    json_path: Annotated[Path | None, typer.Option("--json", help="write the metrics here")] = None,
) -> None:
    """Fingerprint methods on UJIIndoorLoc-style CSV files (EvAAL score included)."""
    from lab.datasets.uji import read_ujiindoorloc
    from lab.uji_evaluation import evaluate_uji

    with console.status("reading fingerprints"):
        train = read_ujiindoorloc(train_csv)
        test = read_ujiindoorloc(test_csv)
    with progress_bar() as bar:
        task = bar.add_task(method, total=test.rssi_dbm.shape[0])
        result = evaluate_uji(
            train,
            test,
            method,
            k=k,
            progress=lambda _stage, done, total: bar.update(task, completed=done, total=total),
            device_offsets=device_offsets,
        )
    result["dataset"] = f"uji:{test_csv.name}"
    offsets = result.get("device_offsets", {})
    if offsets:
        table = Table(title="per-phone RSS offsets (training set)")
        for column in ("phone id", "offset dB", "pairs", "std dB"):
            table.add_column(column, justify="right")
        for phone, o in offsets.items():
            table.add_row(phone, f"{o['offset_db']:+.2f}", str(o["n_pairs"]), f"{o['std_db']:.2f}")
        console.print(table)
    print_report(
        f"{method} on {test_csv.name}", {n: v for n, v in result.items() if n != "device_offsets"}
    )
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
        console.print(f"metrics written to {json_path}")
