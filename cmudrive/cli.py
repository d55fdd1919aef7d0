"""The ``cmudrive`` command line."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from cmudrive.maps.errors import MapError

app = typer.Typer(
    help="CMU-Drive: cooperative driving benchmark on an embedded SUMO world.", no_args_is_help=True
)
maps_app = typer.Typer(help="Road maps: list, draw, build, import, plan routes.", no_args_is_help=True)
app.add_typer(maps_app, name="maps")
sim_app = typer.Typer(help="The embedded simulator.", no_args_is_help=True)
app.add_typer(sim_app, name="sim")
console = Console()
err_console = Console(stderr=True)


def _fail(exc: Exception) -> None:
    err_console.print(f"[bold red]error:[/] {exc}")
    raise typer.Exit(code=1)


def _town_descriptions() -> dict[str, str]:
    try:
        from cmudrive.maps.towns import TOWNS
    except ImportError:
        return {}
    return {name: spec.description for name, spec in TOWNS.items()}


@maps_app.command("list")
def maps_list() -> None:
    """List the committed towns with their size and junction mix."""
    from cmudrive.maps import available_towns, load_map

    descriptions = _town_descriptions()
    table = Table(title="cmudrive towns")
    for col in ("town", "driving km", "junctions (tls/prio/allway/stop)", "crossings", "description"):
        table.add_column(col)
    for town in available_towns():
        s = load_map(town).summary()
        junctions = (
            f"{s['junctions_traffic_light']}/{s['junctions_priority']}/"
            f"{s['junctions_allway_stop']}/{s['junctions_priority_stop']}"
        )
        table.add_row(
            town, f"{s['driving_km']:.1f}", junctions, str(s["crossings"]), descriptions.get(town, "")
        )
    console.print(table)


@maps_app.command("show")
def maps_show(
    town: Annotated[str, typer.Argument(help="town name or path to a .net.xml")],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG to write")] = Path("town.png"),
    dpi: Annotated[int, typer.Option(help="resolution of the PNG")] = 200,
) -> None:
    """Draw a town's lanes, markings, junctions, crossings, traffic lights and stop signs."""
    from cmudrive.maps import load_map
    from cmudrive.viz import save_map_figure

    try:
        road_map = load_map(town)
    except MapError as exc:
        _fail(exc)
    path = save_map_figure(road_map, output, dpi=dpi)
    console.print(f"wrote {path}")


@maps_app.command("build")
def maps_build(
    names: Annotated[list[str] | None, typer.Argument(help="towns to build (default: all)")] = None,
    out_dir: Annotated[
        Path | None, typer.Option("--out", help="folder (default: the package's assets)")
    ] = None,
) -> None:
    """Rebuild procedural towns with netconvert (needs `pip install 'cmudrive[maps]'`)."""
    from cmudrive.maps.towns import TOWNS, assets_dir, build_town

    target = out_dir or assets_dir()
    try:
        for name in names or list(TOWNS):
            console.print(f"built {build_town(name, target)}")
    except MapError as exc:
        _fail(exc)


@maps_app.command("import")
def maps_import(
    source: Annotated[Path, typer.Argument(help="OpenDRIVE .xodr or OpenStreetMap .osm file")],
    output: Annotated[Path, typer.Option("-o", "--output", help="SUMO network to write (.net.xml)")],
) -> None:
    """Convert an OpenDRIVE or OpenStreetMap file into a SUMO network (keeps lights, stops, sidewalks)."""
    from cmudrive.maps.importer import import_map

    try:
        report = import_map(source, output)
    except MapError as exc:
        _fail(exc)
    console.print(report)


@maps_app.command("route")
def maps_route(
    town: Annotated[str, typer.Argument(help="town name or path to a .net.xml")],
    start: Annotated[tuple[float, float] | None, typer.Option(help="start x y [m], map frame")] = None,
    goal: Annotated[tuple[float, float] | None, typer.Option(help="goal x y [m], map frame")] = None,
    seed: Annotated[int, typer.Option(help="seed for picking start and goal when not given")] = 0,
    output: Annotated[Path | None, typer.Option("-o", "--output", help="PNG of the route on the map")] = None,
) -> None:
    """Plan a lane-level route (random far-apart start and goal unless given) and summarise it."""
    from cmudrive.maps import RoadOption, RoutePlanner, load_map
    from cmudrive.maps.routing import pick_far_apart

    try:
        road_map = load_map(town)
        planner = RoutePlanner(road_map)
        if start is None or goal is None:
            route = pick_far_apart(planner, np.random.default_rng(seed))
        else:
            route = planner.plan(np.array(start), np.array(goal))
    except MapError as exc:
        _fail(exc)
    options, counts = np.unique(route.option, return_counts=True)
    table = Table(title=f"route on {road_map.name}: {route.length:.0f} m, {len(route)} points")
    table.add_column("road option")
    table.add_column("points")
    for opt, cnt in zip(options.tolist(), counts.tolist(), strict=True):
        table.add_row(RoadOption(opt).name, str(cnt))
    (x0, y0), (x1, y1) = route.xy[0], route.xy[-1]
    console.print(f"start ({x0:.1f}, {y0:.1f})  goal ({x1:.1f}, {y1:.1f})")
    console.print(table)
    if output is not None:
        from cmudrive.viz import save_map_figure

        console.print(
            f"wrote {save_map_figure(road_map, output, route=route, title=f'{road_map.name}: route')}"
        )


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
) -> None:
    """CAVs on a lane-following autopilot among background traffic, rendered in BEV."""
    from cmudrive.sim.demo import run_demo

    if follow is not None and not 0 <= follow < cavs:
        _fail(ValueError(f"--follow {follow}: there are only CAVs 0-{cavs - 1}"))
    try:
        stats = run_demo(town, cavs, seconds, seed, output, pixels_per_meter, follow, window)
    except MapError as exc:
        _fail(exc)
    console.print(
        f"{stats.ticks} ticks; CAVs drove {stats.cav_distance.sum():.0f} m in total; up to "
        f"{stats.max_background_vehicles} background vehicles and {stats.max_pedestrians} pedestrians; "
        f"{len(stats.collisions)} collision events"
    )
    for t, a, b in stats.collisions[:10]:
        console.print(f"  t={t:.2f} s: {a} - {b}")
    if output is not None:
        console.print(f"wrote {output}")


def main() -> None:
    app()


if __name__ == "__main__":
    main()
