"""``indoorpos bench``: timing the positioning core and the service under load."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from lab.cli.reports import print_report
from server.cli.output import console

ILC_SITE2 = Path(__file__).resolve().parents[2].parent / "shared/data/ilc20-sample/site2"
"""The largest site of the shared data (floors B1..F8; B1 about 17,000 m² walkable)."""

bench_app = typer.Typer(
    help="Time the positioning core (bench/performance.md).", no_args_is_help=True
)


@bench_app.command("particle")
def bench_particle(
    particles: Annotated[int, typer.Option(min=1, help="particle count N")] = 3000,
    window: Annotated[int, typer.Option(min=1, help="window W in steps")] = 3,
    repeat: Annotated[int, typer.Option(min=1, help="timed runs; medians are reported")] = 15,
    seed: Annotated[int, typer.Option(help="seed of the synthetic walk")] = 0,
    dtw_samples_per_step: Annotated[
        int | None,
        typer.Option(min=1, max=100, help="the DTW baseline's samples per step [default: 34]"),
    ] = None,
    json_path: Annotated[Path | None, typer.Option("--json", help="write the figures here")] = None,
) -> None:
    """Mass-centered against DTW weight update on the same inputs, the compiled filter step
    against its numpy reference, and the state codec."""
    from lab.particle_bench import particle_bench

    # no spinner: its refresh thread would take the GIL in the middle of the timings
    console.print(f"timing {particles} particles, {repeat} runs per measure ...")
    result = particle_bench(
        particles,
        window=window,
        repeat=repeat,
        seed=seed,
        dtw_samples_per_step=dtw_samples_per_step,
    )
    print_report(f"particle filter, N = {particles}, W = {window}", result)
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
        console.print(f"figures written to {json_path}")


@bench_app.command("map-build")
def bench_map_build(
    site_dir: Annotated[
        Path, typer.Argument(exists=True, file_okay=False, help="ILC site or floor directory")
    ],
    split_seed: Annotated[int, typer.Option(help="seed of the per-floor path split")] = 0,
    json_path: Annotated[Path | None, typer.Option("--json", help="write the figures here")] = None,
) -> None:
    """The worker's build of a site's maps (fix-error table, FAI maps, floor graphs) from
    its training traces surveyed into a throw-away embedded service: time and peak memory."""
    from lab.cli.reports import StageProgress, progress_bar
    from lab.map_build_bench import map_build_bench

    with progress_bar() as bar:
        result = map_build_bench(site_dir, split_seed=split_seed, progress=StageProgress(bar))
    print_report(f"map build, {site_dir.name}", result)
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
        console.print(f"figures written to {json_path}")


@bench_app.command("routes")
def bench_routes(
    site_dir: Annotated[
        Path,
        typer.Argument(exists=True, file_okay=False, help="ILC site or floor directory"),
    ] = ILC_SITE2,
    queries: Annotated[int, typer.Option(min=1, help="timed route queries")] = 500,
    cross_share: Annotated[
        float, typer.Option(min=0.0, max=1.0, help="share of the queries between two floors")
    ] = 0.2,
    seed: Annotated[int, typer.Option(help="seed of the query pairs")] = 0,
    json_path: Annotated[Path | None, typer.Option("--json", help="write the figures here")] = None,
) -> None:
    """The site's routing graph: its build (time, size, memory) and route queries on it
    (point ends and the route, p50-p99 latency), against the 20 ms p95 target."""
    from lab.datasets.ilc import read_site
    from lab.route_bench import route_bench

    # no spinner: its refresh thread would take the GIL in the middle of the timings
    console.print(f"building the routing graph of {site_dir.name}, then {queries} queries ...")
    result = route_bench(read_site(site_dir), queries=queries, cross_share=cross_share, seed=seed)
    print_report(
        f"routing graph per floor, {result['site']}",
        {
            f["floor"]: f"{f['vertices']:,} vertices, {f['edges']:,} edges, "
            f"{f['graph_mb']:.1f} MB, plan {f['plan_s']:.2f} s, graph {f['build_s']:.2f} s"
            for f in result["floors"]
        },
    )
    print_report(f"routes, {result['site']}", {k: v for k, v in result.items() if k != "floors"})
    p95, target = result["same_floor_p95_ms"], result["target_p95_ms"]
    where = f"route query on {result['largest_floor']} within {target:g} ms p95"
    if result["target_met"] is None:
        console.print(f"[yellow]no verdict[/]: {where} (no route found on that floor)")
    elif result["target_met"]:
        console.print(f"[green]pass[/]: {where} (p95 {p95:.1f} ms)")
    else:
        console.print(f"[red]fail[/]: {where} (p95 {p95:.1f} ms)")
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
        console.print(f"figures written to {json_path}")


@bench_app.command("navigation")
def bench_navigation(
    sessions: Annotated[
        int, typer.Option(min=2, help="sessions per engine, half of them navigating at a time")
    ] = 50,
    batches: Annotated[int, typer.Option(min=1, help="batches per session in a block")] = 20,
    blocks: Annotated[
        int, typer.Option(min=2, help="timed blocks, an even number (the groups swap roles)")
    ] = 6,
    engine: Annotated[
        list[str] | None,
        typer.Option(help="engine of the sessions, repeat for several (default: auto and wknn)"),
    ] = None,
    geo: Annotated[
        bool, typer.Option(help="geo-reference the building (every point on the wire in WGS84)")
    ] = True,
    seed: Annotated[int, typer.Option(help="seed of the building, survey and walkers")] = 0,
    json_path: Annotated[Path | None, typer.Option("--json", help="write the figures here")] = None,
) -> None:
    """What navigation adds to a batch's CPU (the whole batch path of an embedded service,
    in this process) and to the bytes the session store keeps, against the 5 % target;
    navigation's part alone, per fix, and where its time goes."""
    from lab.navigation_bench import navigation_bench

    if blocks % 2:
        raise typer.BadParameter("an even number (the groups swap roles)", param_hint="--blocks")
    engines = engine or ["auto", "wknn"]
    # no spinner: its refresh thread would take the GIL in the middle of the timings
    console.print(
        f"{sessions} sessions per engine ({', '.join(engines)}), {blocks} blocks of "
        f"{batches} batches each, {'geo-referenced' if geo else 'local'} building ..."
    )
    result = navigation_bench(
        sessions=sessions, batches=batches, blocks=blocks, engines=engines, geo=geo, seed=seed
    )
    target = result["target_pct"]
    for figures in result["engines"]:
        name = figures["engine"]
        print_report(
            f"navigation, {name}",
            {k: v for k, v in figures.items() if not isinstance(v, list | dict)},
        )
        print_report(
            f"where navigation's time goes, {name} (cProfile, µs per fix, inside each)",
            {
                row["function"]: row["cumulative_us_per_fix"]
                for row in figures["profile_cumulative"]
            },
        )
        pct, us = figures["overhead_pct"], figures["overhead_us"]
        where = f"navigation adds at most {target:g} % to a batch's CPU ({name})"
        if figures["target_met"]:
            console.print(f"[green]pass[/]: {where} ({pct:.1f} %, {us:.0f} µs)")
        else:
            console.print(f"[red]fail[/]: {where} ({pct:.1f} %, {us:.0f} µs)")
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
        console.print(f"figures written to {json_path}")


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
    rate_limits: Annotated[
        bool,
        typer.Option(
            help="rate limits on, as deployed (one address's allowances raised for the "
            "load generator); --no-rate-limits measures without them"
        ),
    ] = True,
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
    from lab.load_bench import Level, run_load_bench

    def show(level: Level) -> None:
        mark = "[green]held[/]" if level.held else "[red]not held[/]"
        cpu = level.server_cpu_us_per_step
        console.print(
            f"  {level.processes} process(es), {level.users:5d} users: {mark}  "
            f"p50 {level.p50_ms or 0:6.1f} ms  p99 {level.p99_ms or 0:6.1f} ms "
            f"(server ≤ {level.server_p99_ms or 0:.0f} ms)  "
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
            rate_limits=rate_limits,
            database_url=database_url,
            redis_url=redis_url,
            seed=seed,
            on_level=show,
            on_stage=lambda text: status.update(text),
        )
    print_report(
        f"bench load: {engine}, {batch_steps} step(s) per batch over {'ws' if ws else 'http'}, "
        f"rate limits {'on' if rate_limits else 'off'}",
        {k: v for k, v in result.items() if not isinstance(v, list | dict)},
    )
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
        console.print(f"figures written to {json_path}")
