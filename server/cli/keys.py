"""``indoorpos keys``: admin API keys, created, listed, revoked and rotated in the database."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from server.cli.output import console, masked_url
from server.cli.service import checked_settings, migrate_or_exit
from server.config import get_settings
from server.services import auth, revocations
from server.services.errors import ServiceError
from server.services.runtime import open_runtime

keys_app = typer.Typer(help="Admin API keys.", no_args_is_help=True)


def _database(*, for_a_new_key: bool = False) -> str:
    """The database the key commands act on, its URL with the password masked. The
    embedded one is named as such, with its file's full path, so that an operator who
    forgot INDOORPOS_DATABASE_URL sees where a new key went."""
    settings = get_settings()
    if settings.database_url is not None:
        return f"the database {masked_url(settings.database_url)}"
    path = Path(settings.resolved_database_url.removeprefix("sqlite:///")).resolve()
    where = f"the embedded SQLite database sqlite:///{path.as_posix()}"
    if for_a_new_key:
        where += (
            " (INDOORPOS_DATABASE_URL is not set: a server using another database will not "
            "know this key)"
        )
    return where


async def _in_runtime(work: Any, whole_runtime: bool) -> Any:
    async with open_runtime(get_settings()) as rt:
        if whole_runtime:
            return await work(rt)
        async with rt.transaction() as s:
            return await work(s)


def run_keys(work: Any, *, whole_runtime: bool = False) -> Any:
    """``work(session)`` in one transaction on the migrated database (``work(runtime)``
    with ``whole_runtime``, for what also tells the running servers); a service's refusal
    is printed and ends the command with status 1."""
    migrate_or_exit(checked_settings().resolved_database_url)
    try:
        return asyncio.run(_in_runtime(work, whole_runtime))
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
    row, key = run_keys(lambda s: auth.create_key(s, label, scopes, site))
    console.print(
        f"key id {row.id} ({row.scopes}; {'site ' + row.site_id if row.site_id else 'all sites'})"
        f" in {_database(for_a_new_key=True)}; keep this key, it is not shown again:"
    )
    typer.echo(key)


@keys_app.command("list")
def keys_list(
    revoked: Annotated[bool, typer.Option(help="revoked keys too")] = False,
) -> None:
    """List the keys (never their secrets)."""
    rows = run_keys(lambda s: auth.list_keys(s, revoked))
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
    """Revoke a key: it stops working at once (the servers sharing its session store close
    its live sockets)."""
    run_keys(lambda rt: revocations.revoke_key(rt, key_id), whole_runtime=True)
    console.print(f"key {key_id} revoked in {_database()}")


@keys_app.command("rotate")
def keys_rotate(key_id: Annotated[str, typer.Argument(help="the key's id")]) -> None:
    """Give a key a new secret (printed once); the old one stops working."""
    _, key = run_keys(lambda rt: revocations.rotate_key(rt, key_id), whole_runtime=True)
    console.print(
        f"key {key_id} rotated in {_database(for_a_new_key=True)}; its new secret, shown once:"
    )
    typer.echo(key)
