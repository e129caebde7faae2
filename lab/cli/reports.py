"""What the harness's commands show: progress bars (one per stage of an evaluation) and
tables of figures."""

from __future__ import annotations

from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeRemainingColumn
from rich.table import Table

from server.cli.output import console


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
