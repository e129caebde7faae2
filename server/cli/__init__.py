"""The ``indoorpos`` command: one module per command group, each command parsing its
arguments, calling the services or the lab and printing what they give back.

``service`` (serve, worker, migrate, openapi), ``simulate`` (demo, simulate), ``keys``,
``evaluate``, ``bench``, ``survey`` (plan-survey); ``output`` holds the console and the
progress bars they share,
``embedded`` the service some commands run in this process.
"""

from __future__ import annotations

import typer

from server.cli import bench, evaluate, keys, service, simulate, survey

app = typer.Typer(help="indoorpos: an indoor positioning service.", no_args_is_help=True)
# in this order in `indoorpos --help`: the commands, then the groups
app.command()(service.serve)
app.command()(service.worker)
app.command()(service.migrate)
app.command()(simulate.demo)
app.command()(service.openapi)
app.command()(simulate.simulate)
app.add_typer(keys.keys_app, name="keys")
app.add_typer(evaluate.evaluate_app, name="evaluate")
app.add_typer(bench.bench_app, name="bench")
app.add_typer(survey.plan_survey_app, name="plan-survey")
