"""``cmudrive sim``: the embedded simulator."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cmudrive.cli.common import (
    console,
    fail,
)
from cmudrive.maps.errors import MapError

sim_app = typer.Typer(help="The embedded simulator.", no_args_is_help=True)


@sim_app.command("demo")
def sim_demo(
    town: Annotated[str, typer.Option(help="town name or path to a .net.xml")] = "downtown",
    cavs: Annotated[int, typer.Option(min=1, max=16, help="number of CAVs")] = 8,
    seconds: Annotated[float, typer.Option(min=0.05, help="simulated time [s]")] = 30.0,
    seed: Annotated[int, typer.Option(help="seed of routes, traffic and SUMO")] = 0,
    output: Annotated[Path | None, typer.Option("-o", "--output", help=".mp4 or .gif to write")] = None,
    pixels_per_meter: Annotated[float | None, typer.Option(help="video resolution [px/m]")] = None,
    follow: Annotated[int | None, typer.Option(help="follow this CAV instead of showing all")] = None,
    window: Annotated[float, typer.Option(help="size of the follow view [m]")] = 100.0,
    sensors: Annotated[
        bool,
        typer.Option(help="show the followed CAV's camera, own and merged occupancy beside the BEV view"),
    ] = False,
) -> None:
    """CAVs on a lane-following autopilot among background traffic, rendered in BEV."""
    from cmudrive.viz.demo import run_demo

    if follow is not None and not 0 <= follow < cavs:
        fail(ValueError(f"--follow {follow}: there are only CAVs 0-{cavs - 1}"))
    try:
        stats = run_demo(town, cavs, seconds, seed, output, pixels_per_meter, follow, window, sensors)
    except MapError as exc:
        fail(exc)
    console.print(
        f"{stats.ticks} ticks; CAVs drove {stats.cav_distance.sum():.0f} m in total; up to "
        f"{stats.max_background_vehicles} background vehicles and {stats.max_pedestrians} pedestrians; "
        f"{len(stats.collisions)} collision events ({stats.sumo_collisions} seen by SUMO's own check)"
    )
    for t, a, b in stats.collisions[:10]:
        console.print(f"  t={t:.2f} s: {a} - {b}")
    if output is not None:
        console.print(f"wrote {output}")
