"""The ``indoorpos`` command: serve, migrate, keys, demo."""

from __future__ import annotations

import asyncio
import contextlib
import json
import lzma
import socket
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, Literal

import typer
import uvicorn
from rich.console import Console
from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeRemainingColumn
from rich.table import Table

from server.app import create_app
from server.config import Settings, get_settings
from server.positioning.engines.base import SiteMaps
from server.positioning.events import Event, Fix
from server.services import auth
from server.services.errors import ServiceError
from server.services.runtime import open_runtime
from server.storage import db

app = typer.Typer(help="indoorpos: an indoor positioning service.", no_args_is_help=True)
keys_app = typer.Typer(help="Admin API keys.", no_args_is_help=True)
app.add_typer(keys_app, name="keys")
evaluate_app = typer.Typer(
    help="Measure engines and methods on recorded datasets.", no_args_is_help=True
)
app.add_typer(evaluate_app, name="evaluate")
console = Console()


def _progress_bar(counter: str = "{task.completed}/{task.total}") -> Progress:
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn(counter),
        TimeRemainingColumn(),
        console=console,
    )


class _StageProgress:
    """``progress(stage, done, total)`` callbacks shown as one bar per stage."""

    def __init__(self, bar: Progress) -> None:
        self.bar = bar
        self.tasks: dict[str, TaskID] = {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        if stage not in self.tasks:
            self.tasks[stage] = self.bar.add_task(stage, total=total)
        self.bar.update(self.tasks[stage], completed=done, total=total)


def _print_report(title: str, result: dict[str, object]) -> None:
    table = Table(title=title)
    table.add_column("measure")
    table.add_column("value", justify="right")
    for name, value in result.items():
        text = f"{value:.3f}" if isinstance(value, float) else str(value)
        table.add_row(name, text)
    console.print(table)


def _report_walk(title: str, result: dict[str, Any], json_path: Path | None) -> dict[str, Any]:
    """Show a simulator run's summary (table, p99 by minute, errors), write it as JSON
    when asked, and give it back."""
    _print_report(title, {k: v for k, v in result.items() if not isinstance(v, list | dict)})
    if len(result["p99_ms_by_minute"]) > 1:
        by_minute = ", ".join(f"{v:.1f}" for v in result["p99_ms_by_minute"])
        console.print(f"p99 ms by minute: {by_minute}")
    for message in result["error_messages"]:
        console.print(f"[red]error:[/] {message}")
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
        console.print(f"summary written to {json_path}")
    return result


@app.command()
def serve(
    host: Annotated[str, typer.Option(help="interface to listen on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="TCP port")] = 8000,
    workers: Annotated[int, typer.Option(help="uvicorn worker processes")] = 1,
    access_log: Annotated[bool, typer.Option(help="log every request")] = True,
) -> None:
    """Run the API server (logs: INDOORPOS_LOG_FORMAT=json|text, INDOORPOS_LOG_LEVEL)."""
    from server import logs

    settings = get_settings()
    logs.configure(settings.log_format, settings.log_level)
    if workers > 1 and settings.redis_url is None:
        raise typer.BadParameter(
            "several workers need a shared session store: set INDOORPOS_REDIS_URL",
            param_hint="--workers",
        )
    if settings.resolved_database_url.startswith("sqlite"):
        db.migrate(settings.resolved_database_url)  # once, before any worker starts
    uvicorn.run(
        "server.app:create_app",
        factory=True,
        host=host,
        port=port,
        workers=workers,
        # uvicorn applies this in every worker process instead of its own logging setup
        log_config=logs.dict_config(settings.log_format, settings.log_level),
        log_level=settings.log_level.lower(),
        access_log=access_log,
        ws_max_size=settings.json_max_bytes,  # a live-socket message: a batch at most
    )


@app.command()
def worker() -> None:
    """Run an upload worker: fold crowdsourced uploads into new map versions (needs
    INDOORPOS_REDIS_URL; without Redis the api process runs the worker itself)."""
    from server import logs
    from server import worker as upload_worker

    settings = get_settings()
    if settings.redis_url is None:
        raise typer.BadParameter(
            "a separate worker needs the shared queue: set INDOORPOS_REDIS_URL "
            "(embedded, `indoorpos serve` runs the worker in-process)"
        )
    logs.configure(settings.log_format, settings.log_level)

    async def main() -> None:
        async with open_runtime(settings) as rt:
            await upload_worker.run(rt, upload_worker.consumer_name())

    asyncio.run(main())


@app.command()
def migrate() -> None:
    """Bring the database schema up to date (alembic upgrade head)."""
    url = get_settings().resolved_database_url
    db.migrate(url)
    console.print(f"[green]schema up to date[/] on {url.split('@')[-1]}")


def _database() -> str:
    """The database the key commands act on, without credentials, for the operator."""
    settings = get_settings()
    url = settings.resolved_database_url
    where = url.split("@")[-1]
    if settings.database_url is None:
        return f"the embedded SQLite database {where} (set INDOORPOS_DATABASE_URL for another)"
    return where


async def _in_transaction(work: Any) -> Any:
    async with open_runtime(get_settings()) as rt, rt.transaction() as s:
        return await work(s)


def _run_keys(work: Any) -> Any:
    db.migrate(get_settings().resolved_database_url)
    try:
        return asyncio.run(_in_transaction(work))
    except ServiceError as exc:
        console.print(f"[red]{exc.field or 'key'}: {exc.message}[/]")
        raise typer.Exit(1) from None


@keys_app.command("create")
def keys_create(
    name: Annotated[str | None, typer.Option(help="what the key is for")] = None,
    scope: Annotated[
        list[str] | None,
        typer.Option(help=f"repeatable; one of {', '.join(auth.SCOPES)} (default admin)"),
    ] = None,
    site: Annotated[str | None, typer.Option(help="the one site id the key is for")] = None,
) -> None:
    """Create an API key; it is printed once and only its digest is stored."""
    scopes = scope or ["admin"]
    label = name or f"{' '.join(scopes)} key"
    row, key = _run_keys(lambda s: auth.create_key(s, label, scopes, site))
    console.print(
        f"key id {row.id} ({row.scopes}; {'site ' + row.site_id if row.site_id else 'all sites'})"
        f" in {_database()}; keep this key, it is not shown again:"
    )
    typer.echo(key)


@keys_app.command("list")
def keys_list(
    revoked: Annotated[bool, typer.Option(help="revoked keys too")] = False,
) -> None:
    """List the keys (never their secrets)."""
    rows = _run_keys(lambda s: auth.list_keys(s, revoked))
    table = Table(title=_database())
    table.add_column("id", no_wrap=True)
    for column in ("name", "scopes", "site", "created", "revoked"):
        table.add_column(column)
    for row in rows:
        revoked_at = row.revoked_at.isoformat(timespec="seconds") if row.revoked_at else ""
        created_at = row.created_at.isoformat(timespec="seconds")
        table.add_row(row.id, row.name, row.scopes, row.site_id or "all", created_at, revoked_at)
    console.print(table)


@keys_app.command("revoke")
def keys_revoke(key_id: Annotated[str, typer.Argument(help="the key's id")]) -> None:
    """Revoke a key: it stops working at once."""
    _run_keys(lambda s: auth.revoke_key(s, key_id))
    console.print(f"key {key_id} revoked in {_database()}")


@keys_app.command("rotate")
def keys_rotate(key_id: Annotated[str, typer.Argument(help="the key's id")]) -> None:
    """Give a key a new secret (printed once); the old one stops working."""
    _, key = _run_keys(lambda s: auth.rotate_key(s, key_id))
    console.print(f"key {key_id} rotated in {_database()}; its new secret, shown once:")
    typer.echo(key)


def _free_port(preferred: int) -> int:
    with socket.socket() as sock:
        try:
            sock.bind(("127.0.0.1", preferred))
        except OSError:
            sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class _ServerThread:
    """uvicorn in a background thread with its own event loop."""

    def __init__(self, port: int, settings: Settings | None = None) -> None:
        config = uvicorn.Config(
            create_app(settings), host="127.0.0.1", port=port, log_level="warning"
        )
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def start(self, timeout_s: float = 60.0) -> None:
        self.thread.start()
        deadline = time.monotonic() + timeout_s
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise typer.Exit(code=1)
            time.sleep(0.05)

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=10)


@app.command()
def demo(
    walkers: Annotated[int, typer.Option(min=1, max=2000, help="simulated users")] = 10,
    duration: Annotated[float, typer.Option(min=1, help="seconds of walking")] = 30.0,
    port: Annotated[int, typer.Option(help="port to serve on (a free one if taken)")] = 8000,
    seed: Annotated[int, typer.Option(help="seed of the synthetic building and walkers")] = 0,
    json_path: Annotated[Path | None, typer.Option("--json", help="write the summary here")] = None,
    exit_after: Annotated[
        bool, typer.Option("--exit", help="stop the server when the walk ends")
    ] = False,
) -> None:
    """Serve, build a synthetic site through the API, and walk simulated users through it."""
    from client_sim.run import run_walkers

    # an admin key builds the site; the simulator makes itself a device key with it
    _, key = _run_keys(lambda s: auth.create_key(s, "demo"))
    port = _free_port(port)
    # the walkers all come from this machine: the per-address limits are not for them
    server = _ServerThread(port, get_settings().model_copy(update={"rate_limits": False}))
    server.start()
    base_url = f"http://127.0.0.1:{port}"
    console.print(f"serving on {base_url} (docs at {base_url}/docs)")
    with _progress_bar("{task.completed:.0f}/{task.total:.0f} s") as progress:
        task = progress.add_task(f"{walkers} walkers", total=duration)
        summary = asyncio.run(
            run_walkers(
                base_url,
                key,
                walkers=walkers,
                duration_s=duration,
                seed=seed,
                batch_steps=2,
                on_progress=lambda elapsed: progress.update(task, completed=min(elapsed, duration)),
            )
        )
    result = _report_walk("demo summary", summary.to_json_dict(), json_path)
    if not exit_after:
        console.print(f"still serving on {base_url}; Ctrl-C to stop")
        with contextlib.suppress(KeyboardInterrupt):
            while server.thread.is_alive():
                time.sleep(0.5)
    server.stop()
    if result["errors"]:
        raise typer.Exit(code=1)


@app.command()
def openapi(
    out: Annotated[Path, typer.Option(help="where to write the document")] = Path(
        "openapi/openapi.json"
    ),
) -> None:
    """Write the OpenAPI document generated from the app."""
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(create_app().openapi(), indent=2, sort_keys=True) + "\n")
    console.print(f"wrote {out}")


def _http_replayer(
    base_url: str,
    admin_key: str,
    progress: Callable[[str, int, int], None],
    crowd_reports: list[dict[str, Any]] | None = None,
) -> Callable[..., list[list[Fix]]]:
    """Replay through a running service: training scans go up as a survey (with the floor
    plans and the magnetometer samples when the engine reads them), each test trace
    becomes one session's batches. With ``crowd_reports`` the training traces go up as
    crowd uploads instead (every waypoint dropped but the first and last) and the service
    builds the maps from them; the uploads' final states are appended to the list."""
    from client_sim.replay import keep_end_anchors, replay_over_http
    from server.api.convert import fix_from_wire, to_wire
    from server.lab.replay import batches
    from server.lab.training_maps import LabelledScans, TrainingSurvey

    def run(
        engine: str, maps: SiteMaps, training: TrainingSurvey, traces: list[list[Event]]
    ) -> list[list[Fix]]:
        levels = [f.level for f in maps.floors]
        uploads = []
        if crowd_reports is not None:
            for floor_index, path in training.traces:
                opener = lzma.open if path.suffix == ".xz" else open
                with opener(path, "rt", encoding="utf-8", errors="replace") as f:
                    text = keep_end_anchors(f.read())
                uploads.append((levels[floor_index], text.encode()))
            training = TrainingSurvey(LabelledScans(), plans=training.plans)
        labelled = training.scans
        survey = []
        for (x_m, y_m), floor, event in zip(
            labelled.xy_m, labelled.floor, labelled.events, strict=True
        ):
            wire = to_wire(event)
            key = "wifi" if wire["type"] == "wifi" else "ble"
            survey.append(
                {
                    "x_m": x_m,
                    "y_m": y_m,
                    "floor": maps.floors[floor].level,
                    "t": event.t_ms,
                    key: wire["readings"],
                }
            )
        plans = {levels[i]: plan for i, plan in enumerate(training.plans) if plan}
        magnetic: dict[int, list[dict[str, float]]] = {}
        if training.field is not None:
            for i, xy in training.field.xy_m.items():
                strengths = training.field.magnitude_ut[i]
                magnetic[levels[i]] = [
                    {"x_m": x, "y_m": y, "magnitude_ut": b}
                    for part, values in zip(xy, strengths, strict=True)
                    for (x, y), b in zip(part.tolist(), values.tolist(), strict=True)
                ]
        fixes = asyncio.run(
            replay_over_http(
                base_url,
                admin_key,
                site_name=f"evaluation {maps.floors[0].building_id}",
                levels=levels,
                survey_points=survey,
                engine=engine,
                traces=[[[to_wire(e) for e in b] for b in batches(t)] for t in traces],
                plans=plans,
                magnetic_points=magnetic,
                uploads=uploads,
                on_progress=progress,
                upload_reports=crowd_reports,
            )
        )
        index = {level: i for i, level in enumerate(levels)}
        return [[fix_from_wire(f, index) for f in path] for path in fixes]

    return run


class MapSource(StrEnum):
    survey = "survey"
    crowd = "crowd"


@contextlib.contextmanager
def _embedded_service() -> Iterator[tuple[str, str]]:
    """A throw-away embedded service (SQLite in a temporary directory, in-process worker)
    on a free loopback port; yields its URL and admin key."""
    import secrets
    import tempfile

    from pydantic import SecretStr

    from server.config import Settings

    key = secrets.token_urlsafe(24)
    with tempfile.TemporaryDirectory(prefix="indoorpos-crowd-") as data_dir:
        settings = Settings(
            data_dir=Path(data_dir),
            database_url=None,
            redis_url=None,
            admin_key=SecretStr(key),
            rate_limits=False,  # one local client opening many sessions on purpose
        )
        db.migrate(settings.resolved_database_url)
        port = _free_port(0)
        server = _ServerThread(port, settings)
        server.start()
        try:
            yield f"http://127.0.0.1:{port}", key
        finally:
            server.stop()


def _summarise_crowd(summary: dict[str, Any], reports: list[dict[str, Any]]) -> None:
    """What became of the crowd uploads, in the run's summary (the reference points and the
    per-floor magnetic coverage there describe the survey maps, so they are dropped)."""
    summary["map_source"] = "crowd"
    summary.pop("reference_points", None)  # of the survey maps, which this run did not use
    statuses: dict[str, int] = {}
    reasons: dict[str, int] = {}
    for r in reports:
        statuses[r["status"]] = statuses.get(r["status"], 0) + 1
        reason = (r.get("report") or {}).get("reason")
        if reason:
            # numbers differ from walk to walk; the wording says what happened
            key = " ".join(w for w in reason.split() if not any(c.isdigit() for c in w))
            reasons[key] = reasons.get(key, 0) + 1
    summary["uploads"] = {"status": statuses, "reasons": reasons}
    for floor in summary.get("per_floor", {}).values():
        floor.pop("magnetic_coverage", None)
        floor.pop("magnetic_at_waypoints", None)


def _write_points(json_path: Path, runs: Sequence[Any]) -> None:
    """The per-point errors of each run beside the summary: ``out.points.csv`` (one
    engine) or ``out.<engine>.points.csv``."""
    from server.lab.scoring import write_points

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
    from server.lab.engine_params import engine_params
    from server.lab.ilc_evaluation import evaluate_ilc
    from server.lab.replay import in_process_replayer

    if via_http and not admin_key:
        raise typer.BadParameter("--via-http needs --admin-key (or INDOORPOS_ADMIN_KEY)")
    if via_http and param:
        raise typer.BadParameter("sessions run engines on their defaults", param_hint="--param")
    overrides = dict(p.partition("=")[::2] for p in param or [])
    chosen = {}
    for name in engine:
        try:
            chosen[name] = engine_params(name, overrides) if overrides else None
        except (KeyError, ValueError) as e:
            raise typer.BadParameter(str(e.args[0]), param_hint="--param") from None

    if map_source is MapSource.crowd and param:
        raise typer.BadParameter("crowd maps are replayed through sessions", param_hint="--param")
    runs = []
    crowd_reports: list[list[dict[str, Any]]] = []
    with contextlib.ExitStack() as stack, _progress_bar() as bar:
        progress = _StageProgress(bar)
        service = (via_http, admin_key or "") if via_http else None
        if map_source is MapSource.crowd and service is None:
            service = stack.enter_context(_embedded_service())

        for name in engine:
            progress.tasks.clear()
            reports: list[dict[str, Any]] | None = None
            if map_source is MapSource.crowd:
                reports = []
                crowd_reports.append(reports)
            replayer = (
                _http_replayer(service[0], service[1], progress, reports)
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
                )
            )

    def cell(value: object, pattern: str = "{:.2f}") -> str:
        return "–" if value is None else pattern.format(value)

    per_run: list[list[dict[str, Any]] | None] = [*crowd_reports] or [None] * len(runs)
    for run, reports in zip(runs, per_run, strict=True):
        if overrides:
            run.summary["params"] = overrides
        if reports is not None:
            _summarise_crowd(run.summary, reports)
        title = f"ILC {run.site.name} · {run.summary['engine']}"
        per_floor: dict[str, dict[str, object]] = run.summary.get("per_floor", {})
        _print_report(title, {k: v for k, v in run.summary.items() if k != "per_floor"})
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
        payload = runs[0].summary if len(runs) == 1 else {"runs": [r.summary for r in runs]}
        json_path.write_text(json.dumps(payload, indent=2) + "\n")
        console.print(f"metrics written to {json_path}")
        _write_points(json_path, runs)
    if plots is not None:
        from server.lab.plots import write_ilc_plots

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
            help="read only repetitions 01 and 02 of every trial (maps and scoring), "
            "for choosing parameters",
        ),
    ] = False,
    param: Annotated[
        list[str] | None,
        typer.Option(help="NAME=VALUE: an engine parameter other than its default (repeatable)"),
    ] = None,
) -> None:
    """Replay IPIN 2023 Track 3 logs through engines, leaving one trial out of the maps."""
    from server.lab import ipin_evaluation
    from server.lab.engine_params import engine_params

    overrides = dict(p.partition("=")[::2] for p in param or [])
    for name in engine:
        try:
            engine_params(name, overrides)
        except (KeyError, ValueError) as e:
            raise typer.BadParameter(str(e.args[0]), param_hint="--param") from None
    runs = []
    with _progress_bar() as bar:
        progress = _StageProgress(bar)
        for name in engine:
            progress.tasks.clear()
            runs.append(
                ipin_evaluation.evaluate_ipin(
                    venue_dir,
                    name,
                    validation=validation,
                    progress=progress,
                    params=overrides or None,
                )
            )
    for run in runs:
        summary = run.summary
        title = f"IPIN {run.venue.name} · {summary['engine']}"
        _print_report(title, {k: v for k, v in summary.items() if not isinstance(v, dict)})
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
        payload = runs[0].summary if len(runs) == 1 else {"runs": [r.summary for r in runs]}
        json_path.write_text(json.dumps(payload, indent=2) + "\n")
        console.print(f"metrics written to {json_path}")
        _write_points(json_path, runs)


class StepDetector(StrEnum):
    mansour = "mansour"
    cui = "cui"


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
    from server.lab import pdr_evaluation
    from server.positioning.step_tracker import TrackerParams

    params = pdr_evaluation.with_detector(
        TrackerParams(heading=heading.value), detector.value, length_model.value
    )
    with _progress_bar() as bar:
        progress = _StageProgress(bar)

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
    _print_report(f"PDR on {site_dir.name}", flat)
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
    from server.datasets.uji import read_ujiindoorloc
    from server.lab.uji_evaluation import evaluate_uji

    with console.status("reading fingerprints"):
        train = read_ujiindoorloc(train_csv)
        test = read_ujiindoorloc(test_csv)
    with _progress_bar() as bar:
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
    _print_report(
        f"{method} on {test_csv.name}", {n: v for n, v in result.items() if n != "device_offsets"}
    )
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
        console.print(f"metrics written to {json_path}")


bench_app = typer.Typer(
    help="Time the positioning core (bench/performance.md).", no_args_is_help=True
)
app.add_typer(bench_app, name="bench")


@bench_app.command("particle")
def bench_particle(
    particles: Annotated[int, typer.Option(min=1, help="particle count N")] = 3000,
    window: Annotated[int, typer.Option(min=1, help="window W in steps")] = 3,
    repeat: Annotated[int, typer.Option(min=1, help="timed runs; medians are reported")] = 15,
    seed: Annotated[int, typer.Option(help="seed of the synthetic walk")] = 0,
    json_path: Annotated[Path | None, typer.Option("--json", help="write the figures here")] = None,
) -> None:
    """Mass-centered against DTW weight update on the same inputs, and the state codec."""
    from server.lab.particle_bench import particle_bench

    # no spinner: its refresh thread would take the GIL in the middle of the timings
    console.print(f"timing {particles} particles, {repeat} runs per measure ...")
    result = particle_bench(particles, window=window, repeat=repeat, seed=seed)
    _print_report(f"particle filter, N = {particles}, W = {window}", result)
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
        console.print(f"figures written to {json_path}")


@app.command()
def simulate(
    url: Annotated[
        str | None,
        typer.Option(help="the service to load (default: a throw-away embedded one in-process)"),
    ] = None,
    users: Annotated[int, typer.Option(min=1, max=20_000, help="simulated walking users")] = 10,
    duration: Annotated[
        float, typer.Option(min=1, max=24 * 3600, help="seconds of walking")
    ] = 30.0,
    engine: Annotated[str, typer.Option(help="fusion engine of every session")] = "pf_magnetic",
    batch_steps: Annotated[
        int, typer.Option(min=1, max=100, help="steps per batch (a step every 0.67 s)")
    ] = 1,
    ws: Annotated[bool, typer.Option("--ws", help="post batches over the live WebSocket")] = False,
    live: Annotated[
        bool, typer.Option(help="HTTP walkers also hold the live socket open for their fixes")
    ] = False,
    admin_key: Annotated[
        str | None,
        typer.Option(envvar="INDOORPOS_ADMIN_KEY", help="admin key of --url (to set up the site)"),
    ] = None,
    site_id: Annotated[
        str | None, typer.Option(help="reuse this site, set up before with the same --seed")
    ] = None,
    seed: Annotated[int, typer.Option(help="seed of the synthetic building and walkers")] = 0,
    json_path: Annotated[Path | None, typer.Option("--json", help="write the summary here")] = None,
) -> None:
    """Walk simulated users through a synthetic site over HTTP (or the WebSocket), each
    stepping every 0.67 s and posting every --batch-steps steps; latency and accuracy."""
    from client_sim.run import run_walkers

    with contextlib.ExitStack() as stack:
        if url is None:
            url, admin_key = stack.enter_context(_embedded_service())
            console.print(f"embedded service on {url}")
        elif not admin_key:
            raise typer.BadParameter(
                "the admin key of --url is needed to set up (or look up) the site",
                param_hint="--admin-key / INDOORPOS_ADMIN_KEY",
            )
        transport: Literal["http", "ws"] = "ws" if ws else "http"
        with _progress_bar("{task.completed:.0f}/{task.total:.0f} s") as progress:
            task = progress.add_task(f"{users} users over {transport}", total=duration)
            summary = asyncio.run(
                run_walkers(
                    url,
                    admin_key,
                    walkers=users,
                    duration_s=duration,
                    seed=seed,
                    engine=engine,
                    batch_steps=batch_steps,
                    transport=transport,
                    live_socket=live,
                    site_id=site_id,
                    on_progress=lambda elapsed: progress.update(task, completed=elapsed),
                )
            )
    title = f"simulate: {users} users, {engine}, {batch_steps} step(s) per batch over {transport}"
    result = _report_walk(title, summary.to_json_dict(), json_path)
    if result["errors"]:
        raise typer.Exit(code=1)


@bench_app.command("load")
def bench_load(
    users_max: Annotated[int, typer.Option(min=1, max=20_000, help="most users to try")] = 3000,
    users_start: Annotated[int, typer.Option(min=1, help="users of the first level")] = 50,
    hold: Annotated[float, typer.Option(min=10, help="seconds each level walks")] = 30.0,
    batch_steps: Annotated[int, typer.Option(min=1, max=100, help="steps per batch")] = 1,
    engine: Annotated[str, typer.Option(help="fusion engine of every session")] = "pf_magnetic",
    p99_limit_ms: Annotated[
        float, typer.Option(help="a level is held while p99 batch latency stays under this")
    ] = 50.0,
    two_processes: Annotated[
        bool, typer.Option(help="also measure two api processes (scale-out ratio)")
    ] = True,
    ws: Annotated[bool, typer.Option("--ws", help="post batches over the live WebSocket")] = False,
    database_url: Annotated[
        str, typer.Option(help="PostgreSQL of the service under test")
    ] = "postgresql://postgres@127.0.0.1:5432/test",
    redis_url: Annotated[
        str, typer.Option(help="Redis of the service under test")
    ] = "redis://127.0.0.1:6379/13",
    seed: Annotated[int, typer.Option(help="seed of the synthetic building and walkers")] = 0,
    json_path: Annotated[Path | None, typer.Option("--json", help="write the figures here")] = None,
) -> None:
    """Walking users per core through HTTP + Redis, the in-process ceiling, and two
    api processes against one (bench/performance.md)."""
    from server.lab.load_bench import Level, run_load_bench

    def show(level: Level) -> None:
        mark = "[green]held[/]" if level.held else "[red]not held[/]"
        cpu = level.server_cpu_us_per_step
        console.print(
            f"  {level.processes} process(es), {level.users:5d} users: {mark}  "
            f"p50 {level.p50_ms or 0:6.1f} ms  p99 {level.p99_ms or 0:6.1f} ms  "
            f"errors {level.errors}  {level.steps_per_s:7.1f} steps/s  "
            f"server {cpu or 0:7.0f} µs/step  simulator CPU {level.client_cpu_s:5.1f} s"
            + (f"  ({level.first_error})" if level.first_error else "")
        )

    with console.status("starting") as status:
        result = run_load_bench(
            users_max=users_max,
            users_start=users_start,
            hold_s=hold,
            batch_steps=batch_steps,
            engine=engine,
            p99_limit_ms=p99_limit_ms,
            two_processes=two_processes,
            transport="ws" if ws else "http",
            database_url=database_url,
            redis_url=redis_url,
            seed=seed,
            on_level=show,
            on_stage=lambda text: status.update(text),
        )
    _print_report(
        f"bench load: {engine}, {batch_steps} step(s) per batch over {'ws' if ws else 'http'}",
        {k: v for k, v in result.items() if not isinstance(v, list | dict)},
    )
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
        console.print(f"figures written to {json_path}")
