"""``cmudrive routes``: generate, list, check, count, import and draw route files."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from cmudrive.cli.common import console, err_console, fail, routes_path
from cmudrive.maps.errors import MapError

routes_app = typer.Typer(
    help="Route files: generate multi-CAV routes, import Bench2Drive routes.", no_args_is_help=True
)


@routes_app.command("generate")
def routes_generate(
    output: Annotated[Path, typer.Option("-o", "--output", help="route file to write")],
    entries: Annotated[
        list[str] | None,
        typer.Argument(
            metavar="TOWN[:CAVS[:WEATHER]]",
            help="one scenario-free route per entry (not with --benchmark)",
        ),
    ] = None,
    benchmark: Annotated[
        str | None,
        typer.Option(
            "-b", "--benchmark", help="write a named benchmark set instead: cmudrive220, cmudrive44, training"
        ),
    ] = None,
    seed: Annotated[int, typer.Option("-s", "--seed", help="seed of the generated routes")] = 0,
    length: Annotated[
        tuple[float, float], typer.Option("-l", "--length", help="CAV 0's route length MIN MAX [m]")
    ] = (200.0, 400.0),
    id_prefix: Annotated[
        str, typer.Option("-p", "--id-prefix", help="route ids are PREFIX_00, PREFIX_01, ...")
    ] = "route",
    cavs: Annotated[int, typer.Option("-c", "--cavs", help="CAVs of entries that do not name a number")] = 4,
    weather: Annotated[
        str, typer.Option("-w", "--weather", help="weather of entries that do not name one")
    ] = "ClearNoon",
) -> None:
    """Multi-CAV routes: scenario-free ones (one per TOWN entry, e.g. downtown:4 suburb:3:ClearNight), or a
    benchmark set (-b NAME); the command is recorded in the file's header."""
    from cmudrive.bench.route_gen import main as generate_main

    argv = ["generate", *(entries or ()), "-o", str(output), "-s", str(seed), "-p", id_prefix]
    argv += ["-l", repr(length[0]), repr(length[1]), "-c", str(cavs), "-w", weather]
    argv += ["-b", benchmark] if benchmark is not None else []
    try:
        code = generate_main(argv)
    except (MapError, ValueError) as exc:
        fail(exc)
    raise typer.Exit(code=code)


@routes_app.command("list")
def routes_list() -> None:
    """The committed route sets: name, routes, CAVs per route and what each is for (--routes NAME)."""
    from cmudrive.bench.route_sets import ROUTE_SET_DIR, ROUTE_SET_PURPOSES, route_set_names
    from cmudrive.bench.routes import read_routes

    table = Table(title=f"committed route sets ({ROUTE_SET_DIR})")
    for col in ("name", "routes", "CAVs", "what for"):
        table.add_column(col, justify="right" if col in ("routes", "CAVs") else "left")
    for name in route_set_names():
        specs = read_routes(ROUTE_SET_DIR / f"{name}.xml")
        cavs = [len(s.cavs) for s in specs]
        table.add_row(name, str(len(specs)), f"{min(cavs)}-{max(cavs)}", ROUTE_SET_PURPOSES.get(name, ""))
    console.print(table)


@routes_app.command("check")
def routes_check(
    source: Annotated[str, typer.Argument(help="route file, or the name of a committed route set")],
    town_dir: Annotated[
        list[Path] | None, typer.Option(help="folder of <town>.net.xml networks (as for eval)")
    ] = None,
) -> None:
    """Validate a route file without running it: reading, towns, planning, bounds, trigger points."""
    from rich.markup import escape

    from cmudrive.bench.route_check import check_route_file

    try:
        checks = check_route_file(routes_path(source), [str(d.resolve()) for d in town_dir or ()])
    except (OSError, ValueError) as exc:
        fail(exc)
    if not checks:
        fail(ValueError(f"{source}: no route in the file"))
    bad = 0
    for c in checks:
        if c.problem is None:
            lengths = ", ".join(f"{v:.0f}" for v in c.lengths)
            console.print(f"[green]ok[/]    {escape(c.route_id)}: {c.num_cavs} CAVs, {lengths} m")
        else:
            bad += 1
            console.print(f"[red]error[/] {escape(c.route_id)}: {escape(c.problem)}", highlight=False)
    console.print(f"{len(checks) - bad} of {len(checks)} routes can run")
    if bad:
        raise typer.Exit(code=1)


@routes_app.command("stats")
def routes_stats(
    source: Annotated[str, typer.Argument(help="route file, or the name of a committed route set")],
) -> None:
    """Table 1's row of a route file (routes, min/max/avg CAVs) and its per-type, per-town and per-weather
    counts."""
    from rich.table import Table

    from cmudrive.bench.benchmark_gen import set_stats
    from cmudrive.bench.routes import read_routes

    try:
        st = set_stats(read_routes(routes_path(source)))
    except (OSError, ValueError) as exc:
        fail(exc)
    row = Table(title=f"{source}: CAVs per route (paper Table 1)")
    for col in ("routes", "min", "max", "avg"):
        row.add_column(col, justify="right")
    row.add_row(str(st["routes"]), str(st["min"]), str(st["max"]), f"{st['avg']:.2f}")
    console.print(row)
    for key, title in (("types", "scenario type"), ("towns", "town"), ("weathers", "weather")):
        counts = st[key]
        assert isinstance(counts, dict)
        table = Table(title=f"routes per {title}")
        table.add_column(title)
        table.add_column("routes", justify="right")
        for name, n in sorted(counts.items()):
            table.add_row(name, str(n))
        console.print(table)


@routes_app.command("import")
def routes_import(
    source: Annotated[Path, typer.Argument(help="Bench2Drive / Leaderboard-2.0 route file")],
    output: Annotated[Path, typer.Option("-o", "--output", help="our multi-CAV route file to write")],
    cavs: Annotated[
        int, typer.Option(min=1, max=16, help="CAVs per route (CAV 0 drives the original route)")
    ] = 2,
    town: Annotated[
        list[str] | None, typer.Option(help="extra town: name or .net.xml path (repeatable)")
    ] = None,
    seed: Annotated[int, typer.Option(help="seed of the added CAVs")] = 0,
) -> None:
    """Import single-ego leaderboard routes (routes on towns we have no map of are skipped, with why)."""
    from cmudrive.bench.bench2drive import import_leaderboard_routes
    from cmudrive.bench.routes import write_routes

    try:
        result = import_leaderboard_routes(source, towns=town, extra_cavs=cavs - 1, seed=seed)
    except (OSError, ValueError, MapError) as exc:
        fail(exc)
    for route_id, reason in result.skipped:
        err_console.print(f"[yellow]skipped route {route_id}:[/] {reason}")
    if not result.routes:
        fail(ValueError(f"no route of {source} could be imported"))
    write_routes(result.routes, output, min_cavs=min(cavs, 2))
    console.print(f"wrote {len(result.routes)} routes to {output} ({len(result.skipped)} skipped)")


@routes_app.command("show")
def routes_show(
    file: Annotated[str, typer.Argument(help="route file (.xml) or the name of a committed one")],
    route_id: Annotated[str, typer.Argument(help="id of the route to draw")],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG to write")] = Path("route.png"),
) -> None:
    """Draw one route: the map around it, each CAV's path, the trigger and the scenario's planned actors."""
    from cmudrive.bench.routes import read_routes
    from cmudrive.bench.scenarios import ScenarioError
    from cmudrive.viz.route_plot import save_route_figure

    try:
        specs = read_routes(routes_path(file), min_cavs=1)
        spec = next((s for s in specs if s.id == route_id), None)
        if spec is None:
            known = ", ".join(s.id for s in specs[:10]) + (", ..." if len(specs) > 10 else "")
            raise ValueError(f"{file} has no route {route_id!r} (routes: {known})")
        path = save_route_figure(spec, output)
    except (OSError, ValueError, MapError, ScenarioError) as exc:
        fail(exc)
    console.print(f"wrote {path}")
