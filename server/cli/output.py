"""What the commands print: the console, progress bars, tables of figures."""

from __future__ import annotations

import re
from typing import NoReturn

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeRemainingColumn
from rich.table import Table

console = Console()
_PASSWORD_PARAM = re.compile(r"([?&]password=)[^&]*", re.IGNORECASE)
_MASK = r"\1***"


def progress_bar(counter: str = "{task.completed}/{task.total}") -> Progress:
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn(counter),
        TimeRemainingColumn(),
        console=console,
    )


class StageProgress:
    """``progress(stage, done, total)`` callbacks shown as one bar per stage."""

    def __init__(self, bar: Progress) -> None:
        self.bar = bar
        self.tasks: dict[str, TaskID] = {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        if stage not in self.tasks:
            self.tasks[stage] = self.bar.add_task(stage, total=total)
        self.bar.update(self.tasks[stage], completed=done, total=total)


def print_report(title: str, result: dict[str, object]) -> None:
    table = Table(title=title)
    table.add_column("measure")
    table.add_column("value", justify="right")
    for name, value in result.items():
        text = f"{value:.3f}" if isinstance(value, float) else str(value)
        table.add_row(name, text)
    console.print(table)


def masked_url(url: str) -> str:
    """``url`` with its password, in the user part or a ``password=`` query parameter,
    replaced by ``***`` (for showing an operator which database a command used)."""
    scheme, sep, rest = url.partition("://")
    if not sep:
        return url
    end = min((i for i in (rest.find("/"), rest.find("?")) if i >= 0), default=len(rest))
    authority, tail = rest[:end], rest[end:]
    userinfo, at, hostport = authority.rpartition("@")
    if at and ":" in userinfo:
        authority = f"{userinfo.split(':', 1)[0]}:***@{hostport}"
    return f"{scheme}://{authority}{_PASSWORD_PARAM.sub(_MASK, tail)}"


def fail(message: str) -> NoReturn:
    """One line on stderr (never wrapped, no traceback) and exit status 1."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(1)
