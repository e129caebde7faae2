"""The ``indoorpos`` command itself: the service's commands, then those other distributions
add through the ``indoorpos.commands`` entry point group (package docstring)."""

from __future__ import annotations

import sys
from collections.abc import Iterable
from importlib.metadata import EntryPoint, entry_points

import typer

from server.cli import keys, service

app = typer.Typer(help="indoorpos: an indoor positioning service.", no_args_is_help=True)
# in this order in `indoorpos --help`: the commands, then the groups
app.command()(service.serve)
app.command()(service.worker)
app.command()(service.migrate)
app.command()(service.openapi)
app.add_typer(keys.keys_app, name="keys")


def add_plugins(target: typer.Typer, plugins: Iterable[EntryPoint]) -> list[str]:
    """Let each plugin add its commands to ``target``; what went wrong with the others, one
    line each (a plugin whose code is gone or fails must not take the service's own
    commands down with it)."""
    failed: list[str] = []
    for plugin in plugins:
        try:
            plugin.load()(target)
        except Exception as exc:  # any failure of foreign code: reported, then skipped
            failed.append(f"commands of {plugin.value} not loaded: {type(exc).__name__}: {exc}")
    return failed


for _problem in add_plugins(app, entry_points(group="indoorpos.commands")):
    print(f"indoorpos: {_problem}", file=sys.stderr)
