"""The ``indoorpos`` command: serve, migrate, keys, demo."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import threading
import time
from pathlib import Path
from typing import Annotated

import typer
import uvicorn
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from server.app import create_app
from server.config import get_settings
from server.services import auth
from server.services.runtime import open_runtime
from server.storage import db

app = typer.Typer(help="indoorpos: an indoor positioning service.", no_args_is_help=True)
keys_app = typer.Typer(help="Admin API keys.", no_args_is_help=True)
app.add_typer(keys_app, name="keys")
console = Console()


@app.command()
def serve(
    host: Annotated[str, typer.Option(help="interface to listen on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="TCP port")] = 8000,
    workers: Annotated[int, typer.Option(help="uvicorn worker processes")] = 1,
) -> None:
    """Run the API server."""
    uvicorn.run(
        "server.app:create_app",
        factory=True,
        host=host,
        port=port,
        workers=workers,
        log_level="info",
    )


@app.command()
def migrate() -> None:
    """Bring the database schema up to date (alembic upgrade head)."""
    url = get_settings().resolved_database_url
    db.migrate(url)
    console.print(f"[green]schema up to date[/] on {url.split('@')[-1]}")


async def _create_key(name: str) -> tuple[str, str]:
    async with open_runtime(get_settings()) as rt, rt.transaction() as s:
        return await auth.create_admin_key(s, name)


@keys_app.command("create")
def keys_create(
    name: Annotated[str, typer.Option(help="what the key is for")] = "admin",
) -> None:
    """Create an admin API key; it is printed once and only its digest is stored."""
    db.migrate(get_settings().resolved_database_url)
    key_id, key = asyncio.run(_create_key(name))
    console.print(f"key id {key_id}; keep this key, it is not shown again:")
    typer.echo(key)


def _free_port(preferred: int) -> int:
    with socket.socket() as sock:
        try:
            sock.bind(("127.0.0.1", preferred))
            return preferred
        except OSError:
            sock.bind(("127.0.0.1", 0))
            return int(sock.getsockname()[1])


class _ServerThread:
    """uvicorn in a background thread with its own event loop."""

    def __init__(self, port: int) -> None:
        config = uvicorn.Config(create_app(), host="127.0.0.1", port=port, log_level="warning")
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

    settings = get_settings()
    db.migrate(settings.resolved_database_url)
    _, key = asyncio.run(_create_key("demo"))
    port = _free_port(port)
    server = _ServerThread(port)
    server.start()
    base_url = f"http://127.0.0.1:{port}"
    console.print(f"serving on {base_url} (docs at {base_url}/docs)")
    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
        TimeRemainingColumn(),
        console=console,
    ) as progress:
        task = progress.add_task(f"{walkers} walkers", total=duration)
        summary = asyncio.run(
            run_walkers(
                base_url,
                key,
                walkers=walkers,
                duration_s=duration,
                seed=seed,
                on_progress=lambda elapsed: progress.update(task, completed=min(elapsed, duration)),
            )
        )
    result = summary.to_json_dict()
    table = Table(title="demo summary")
    table.add_column("measure")
    table.add_column("value", justify="right")
    for name, value in result.items():
        if isinstance(value, float):
            table.add_row(name, f"{value:.2f}")
        elif not isinstance(value, list | dict):
            table.add_row(name, str(value))
    console.print(table)
    for message in result.get("error_messages", []) or []:
        console.print(f"[red]error:[/] {message}")
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
        console.print(f"summary written to {json_path}")
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
