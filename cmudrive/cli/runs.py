"""Commands over finished runs: ``report`` (the comparison page), ``export`` (another benchmark's
format) and ``replay`` (a recorded route as a video)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cmudrive.cli.common import (
    console,
    err_console,
    fail,
)
from cmudrive.maps.errors import MapError


def report(
    runs: Annotated[
        list[Path], typer.Argument(help="run folders of cmudrive eval (or their results.json), one or more")
    ],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="folder for the page, tables and PNGs")
    ] = Path("report"),
) -> None:
    """An HTML page (OUTPUT/index.html, opens from disk) comparing runs: seeds of one setup as mean ± std,
    DS/SR/RC/IS overall and per ability, scenario type, CAV count and weather, infraction maps, replays.
    With one run also summary.md, CSV tables and the single-run charts. Runs must share a route set."""
    from cmudrive.viz.compare_report import write_comparison

    try:
        paths = write_comparison(runs, output)
    except (OSError, ValueError, MapError) as exc:
        fail(exc)
    for p in paths:
        console.print(f"wrote {p}")


def export_run(
    run: Annotated[Path, typer.Argument(help="output folder of cmudrive eval (holds results.json)")],
    format: Annotated[
        str, typer.Option("--format", help="leaderboard: CARLA Leaderboard 2.0 / Bench2Drive files")
    ] = "leaderboard",
    per: Annotated[
        str, typer.Option(help="cav: one leaderboard route per CAV; route: one per route (multi-agent score)")
    ] = "cav",
    output: Annotated[
        Path | None, typer.Option("-o", "--output", help="new or empty folder; default RUN/leaderboard-PER")
    ] = None,
    routes: Annotated[
        Path | None, typer.Option(help="the run's route file; default the one RUN/run.json names")
    ] = None,
    metric_info: Annotated[
        bool | None,
        typer.Option(
            "--metric-info/--no-metric-info",
            help="metric_info.json from the route logs (eval --record): --metric-info requires a log per "
            "route; default: where a log exists",
        ),
    ] = None,
) -> None:
    """Export a run's results in another benchmark's format: the leaderboard checkpoint JSON, a route XML
    with matching ids and metric_info.json per route (docs/formats.md, "Leaderboard export")."""
    from cmudrive.bench.export import FORMATS, export_leaderboard

    if format not in FORMATS:
        fail(ValueError(f"--format must be one of {', '.join(FORMATS)}, got {format!r}"))
    try:
        done = export_leaderboard(run, output, per=per, routes_file=routes, metric_info_required=metric_info)
    except (OSError, ValueError) as exc:
        fail(exc)
    console.print(f"wrote {done.checkpoint} ({done.records} records, per {per})")
    console.print(f"wrote {done.routes}")
    if done.metric_info:
        console.print(
            f"wrote {len(done.metric_info)} metric_info.json in {done.checkpoint.parent}/<save_name>/"
        )
    if done.without_log:
        shown = ", ".join(done.without_log[:5]) + (" ..." if len(done.without_log) > 5 else "")
        err_console.print(
            f"warning: no route log for {len(done.without_log)} routes ({shown}): no metric_info.json for "
            "them (Bench2Drive's efficiency_smoothness_benchmark.py needs one per record; eval --record)"
        )
    if done.invalid:
        err_console.print(f"note: {len(done.invalid)} routes recorded 'Failed - Invalid route' left out")


def replay_log(
    log: Annotated[Path, typer.Argument(help="route log (.npz) written by eval --record")],
    output: Annotated[Path, typer.Option("-o", "--output", help=".mp4 or .gif")] = Path("route.mp4"),
    follow: Annotated[int | None, typer.Option(help="follow this CAV")] = None,
) -> None:
    """Render a recorded route as a BEV video with each CAV's route and its infractions marked."""
    from cmudrive.viz.replay import replay

    try:
        path = replay(log, output, follow=follow)
    except (OSError, ValueError, MapError) as exc:
        fail(exc)
    console.print(f"wrote {path}")
