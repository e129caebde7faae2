"""The ``indoorpos`` command takes other distributions' commands as plugins, and a plugin
that fails does not take the service's own commands down."""

from __future__ import annotations

from importlib.metadata import EntryPoint

import typer
from typer.testing import CliRunner

from server.cli.main import add_plugins, app

GROUP = "indoorpos.commands"


def register_hello(target: typer.Typer) -> None:
    """A plugin of this module: one command."""

    @target.command()
    def hello() -> None:
        typer.echo("hello from a plugin")


def register_broken(target: typer.Typer) -> None:
    raise RuntimeError("the plugin's own bug")


def _fresh() -> typer.Typer:
    target = typer.Typer(no_args_is_help=True)

    @target.command()
    def serve() -> None:
        typer.echo("serving")

    return target


def test_a_plugin_adds_its_commands() -> None:
    target = _fresh()
    plugin = EntryPoint("hello", f"{__name__}:register_hello", GROUP)
    assert add_plugins(target, [plugin]) == []
    assert CliRunner().invoke(target, ["hello"]).output == "hello from a plugin\n"


def test_plugins_whose_code_is_gone_or_fails_are_reported_and_skipped() -> None:
    target = _fresh()
    plugins = [
        EntryPoint("gone", "not_installed_anywhere.cli:register", GROUP),
        EntryPoint("broken", f"{__name__}:register_broken", GROUP),
        EntryPoint("hello", f"{__name__}:register_hello", GROUP),
    ]
    failed = add_plugins(target, plugins)
    assert failed == [
        "commands of not_installed_anywhere.cli:register not loaded: "
        "ModuleNotFoundError: No module named 'not_installed_anywhere'",
        f"commands of {__name__}:register_broken not loaded: RuntimeError: the plugin's own bug",
    ]
    runner = CliRunner()
    assert runner.invoke(target, ["serve"]).output == "serving\n"
    assert runner.invoke(target, ["hello"]).output == "hello from a plugin\n"


def test_the_service_s_commands_are_there() -> None:
    output = CliRunner().invoke(app, ["--help"]).output
    for command in ("serve", "worker", "migrate", "openapi", "keys"):
        assert command in output
