"""The ``indoorpos`` command itself: the service's commands, then those other distributions
add through the ``indoorpos.commands`` entry point group (package docstring)."""

from __future__ import annotations

import sys
from importlib.metadata import entry_points

import typer

from server.cli import keys, service

app = typer.Typer(help="indoorpos: an indoor positioning service.", no_args_is_help=True)
# in this order in `indoorpos --help`: the commands, then the groups
app.command()(service.serve)
app.command()(service.worker)
app.command()(service.migrate)
app.command()(service.openapi)
app.add_typer(keys.keys_app, name="keys")
for _plugin in entry_points(group="indoorpos.commands"):
    try:
        _register = _plugin.load()
    except ImportError as exc:  # its distribution's metadata is there, its code is not
        print(f"indoorpos: commands of {_plugin.value} not loaded: {exc}", file=sys.stderr)
        continue
    _register(app)
