"""The ``cmudrive`` command line: one module per sub-command group (``maps``, ``sim``, ``routes``,
``data``) and per top-level command (``eval``, ``train``; ``report``, ``export`` and ``replay`` over
finished runs); ``common`` holds what they share, ``results`` the console summary of a run."""

from __future__ import annotations

import typer

from cmudrive.cli.common import LOG_WIDTH as LOG_WIDTH
from cmudrive.cli.common import console, err_console
from cmudrive.cli.data import data_app
from cmudrive.cli.evaluate import evaluate
from cmudrive.cli.maps import maps_app
from cmudrive.cli.routes import routes_app
from cmudrive.cli.runs import export_run, replay_log, report
from cmudrive.cli.sim import sim_app
from cmudrive.cli.train import train_model

app = typer.Typer(
    help="CMU-Drive: cooperative driving benchmark on an embedded SUMO world.", no_args_is_help=True
)
app.add_typer(maps_app, name="maps")
app.add_typer(sim_app, name="sim")
app.add_typer(routes_app, name="routes")
app.add_typer(data_app, name="data")
app.command("eval")(evaluate)
app.command("train")(train_model)
app.command("report")(report)
app.command("export")(export_run)
app.command("replay")(replay_log)


@app.callback()
def _log_width() -> None:
    """Tables as wide as a log needs when the output is not a terminal (cluster jobs write to files)."""
    for c in (console, err_console):
        if not c.is_terminal:
            c.width = LOG_WIDTH


def main() -> None:
    app()


__all__ = ["app", "main"]
