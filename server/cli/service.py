"""Running the service: ``serve``, ``worker``, ``migrate``, ``openapi``."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Annotated

import typer
import uvicorn
from pydantic import ValidationError

from server.app import create_app
from server.cli.http_protocol import http_protocol
from server.cli.output import console, fail, masked_url
from server.config import Settings, get_settings
from server.services.runtime import open_runtime
from server.storage import db


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
        http=http_protocol(settings),  # with a deadline for a request's headers
        **settings.proxy_options(),
    )


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


def checked_settings() -> Settings:
    """The settings, or one line naming each bad ``INDOORPOS_`` variable and exit 1."""
    try:
        return get_settings()
    except ValidationError as exc:
        fail(
            "; ".join(
                f"INDOORPOS_{'_'.join(str(part) for part in error['loc']).upper()}: {error['msg']}"
                for error in exc.errors()
            )
        )


def migrate_or_exit(url: str) -> None:
    """Bring the schema at ``url`` up to date, or say in one line on stderr why not (a
    server that does not answer, a database that does not exist, a refused login) and
    exit 1. At this edge the cause is nearly always the URL or the server, whichever
    library raised it, so it is one line and not a traceback."""
    try:
        db.migrate(url)
    except Exception as exc:
        detail = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        password = _password(url)
        if password:
            detail = detail.replace(password, "***")
        cause = f"{type(exc).__name__}: {detail}" if detail else type(exc).__name__
        fail(f"cannot migrate the database {masked_url(url)}: {cause}")


def _password(url: str) -> str:
    userinfo = url.partition("://")[2].split("/", 1)[0].rpartition("@")[0]
    return userinfo.partition(":")[2]


def migrate() -> None:
    """Bring the database schema up to date (alembic upgrade head)."""
    url = checked_settings().resolved_database_url
    migrate_or_exit(url)
    console.print(f"[green]schema up to date[/] on {masked_url(url)}")


def openapi(
    out: Annotated[Path, typer.Option(help="where to write the document")] = Path(
        "openapi/openapi.json"
    ),
) -> None:
    """Write the OpenAPI document generated from the app."""
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(create_app().openapi(), indent=2, sort_keys=True) + "\n")
    console.print(f"wrote {out}")
