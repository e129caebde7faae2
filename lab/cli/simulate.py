"""Simulated users: ``demo`` (serve and walk) and ``simulate`` (load and accuracy)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from pathlib import Path
from typing import Annotated, Any, Literal

import typer

from lab.cli.embedded import ServerThread, embedded_service, free_port
from lab.cli.reports import print_report, progress_bar
from server.cli.keys import run_keys
from server.cli.output import console
from server.config import get_settings
from server.services import auth


def report_walk(title: str, result: dict[str, Any], json_path: Path | None) -> dict[str, Any]:
    """Show a simulator run's summary (table, p99 by minute, errors), write it as JSON
    when asked, and give it back."""
    print_report(title, {k: v for k, v in result.items() if not isinstance(v, list | dict)})
    if len(result["p99_ms_by_minute"]) > 1:
        by_minute = ", ".join(f"{v:.1f}" for v in result["p99_ms_by_minute"])
        console.print(f"p99 ms by minute: {by_minute}")
    for message in result["error_messages"]:
        console.print(f"[red]error:[/] {message}")
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
        console.print(f"summary written to {json_path}")
    return result


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
    _, key = run_keys(lambda s: auth.create_key(s, "demo"))
    port = free_port(port)
    # the walkers all come from this machine: the per-address limits are not for them
    server = ServerThread(port, get_settings().model_copy(update={"rate_limits": False}))
    server.start()
    base_url = f"http://127.0.0.1:{port}"
    console.print(f"serving on {base_url} (docs at {base_url}/docs)")
    with progress_bar("{task.completed:.0f}/{task.total:.0f} s") as progress:
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
    result = report_walk("demo summary", summary.to_json_dict(), json_path)
    if not exit_after:
        console.print(f"still serving on {base_url}; Ctrl-C to stop")
        with contextlib.suppress(KeyboardInterrupt):
            while server.thread.is_alive():
                time.sleep(0.5)
    server.stop()
    if result["errors"]:
        raise typer.Exit(code=1)


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
            url, admin_key = stack.enter_context(embedded_service())
            console.print(f"embedded service on {url}")
        elif not admin_key:
            raise typer.BadParameter(
                "the admin key of --url is needed to set up (or look up) the site",
                param_hint="--admin-key / INDOORPOS_ADMIN_KEY",
            )
        transport: Literal["http", "ws"] = "ws" if ws else "http"
        with progress_bar("{task.completed:.0f}/{task.total:.0f} s") as progress:
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
    result = report_walk(title, summary.to_json_dict(), json_path)
    if result["errors"]:
        raise typer.Exit(code=1)
