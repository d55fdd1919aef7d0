"""``cmudrive maps``: list, draw, build and import road maps, plan a route."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.table import Table

from cmudrive.cli.common import (
    console,
    fail,
)
from cmudrive.maps.errors import MapError

maps_app = typer.Typer(help="Road maps: list, draw, build, import, plan routes.", no_args_is_help=True)


def _town_descriptions() -> dict[str, str]:
    try:
        from cmudrive.maps.towns import TOWNS
    except ImportError:
        return {}
    from cmudrive.maps.importer import CARLA_TOWNS

    carla = {town: f"CARLA's {town}, imported from OpenDRIVE" for town in CARLA_TOWNS}
    return carla | {name: spec.description.split(":")[0] for name, spec in TOWNS.items()}


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
        fail(exc)
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
        fail(exc)


@maps_app.command("build-carla")
def maps_build_carla(
    source: Annotated[Path, typer.Argument(help="folder with CARLA's Town01.xodr .. Town07.xodr")],
    out_dir: Annotated[
        Path | None, typer.Option("--out", help="folder (default: the package's assets)")
    ] = None,
) -> None:
    """Re-import the committed CARLA towns (Town01 from SOURCE/with-signals/Town01.xodr when present)."""
    from cmudrive.maps.importer import CARLA_TOWNS, carla_town_source, import_map
    from cmudrive.maps.towns import assets_dir

    target = out_dir or assets_dir()
    try:
        for town in CARLA_TOWNS:
            report = import_map(carla_town_source(source, town), target / f"{town}.net.xml")
            console.print(f"built {report.dst} ({report.tls} traffic lights, {report.tls_source})")
    except MapError as exc:
        fail(exc)


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
        fail(exc)
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
        fail(exc)
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
