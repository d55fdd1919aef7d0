"""``cmudrive routes``: generate, list, check, count, import and draw route files."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from cmudrive.cli.common import console, err_console, fail, routes_path
from cmudrive.maps.errors import MapError

if TYPE_CHECKING:
    from cmudrive.bench.routes import RouteSpec

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
    argv = ["generate", *(entries or ()), "-o", str(output), "-s", str(seed), "-p", id_prefix]
    argv += ["-l", repr(length[0]), repr(length[1]), "-c", str(cavs), "-w", weather]
    argv += ["-b", benchmark] if benchmark is not None else []
    try:
        code = generate_main(argv)
    except (MapError, ValueError) as exc:
        fail(exc)
    raise typer.Exit(code=code)


def _summary(specs: Sequence[RouteSpec]) -> list[str]:
    from cmudrive.maps import densify, load_map

    lines = []
    for spec in specs:
        m = load_map(spec.town_path())
        lengths = [densify(m, spec.map_waypoints(c.id)).length for c in spec.cavs]
        lines.append(
            f"{spec.id}: {spec.town}, {spec.weather}, seed {spec.seed}, {len(spec.cavs)} CAVs, "
            f"route lengths {', '.join(f'{v:.0f}' for v in lengths)} m"
        )
    return lines


# the generator's own argument parser behind `routes generate`: it writes the command into the file's header
def generate_main(argv: Sequence[str] | None = None) -> int:
    """``cmudrive routes generate -o FILE [-s SEED] [-l MIN MAX] [-p PREFIX] [-c CAVS]
    [-w WEATHER] TOWN[:CAVS[:WEATHER]] ...``: one generated route per entry, written to FILE with the
    command and a summary in its header comment; or ``cmudrive routes generate -b NAME -o FILE``: the
    named benchmark route set (``benchmark_gen.ROUTE_SETS``). Options are written single-dash in the
    header because an XML comment cannot hold ``--``."""
    from cmudrive.bench.authoring.route_gen import generate_route_set
    from cmudrive.bench.routes import write_routes

    parser = argparse.ArgumentParser(prog="cmudrive routes")
    sub = parser.add_subparsers(dest="command", required=True)
    gen = sub.add_parser("generate", help="generate multi-CAV routes: scenario-free ones, or a benchmark set")
    gen.add_argument("entries", nargs="*", metavar="TOWN[:CAVS[:WEATHER]]")
    gen.add_argument("-o", "--output", required=True, type=Path)
    gen.add_argument(
        "-b", "--benchmark", default=None, help="a named route set: cmudrive220, cmudrive44, training"
    )
    gen.add_argument("-s", "--seed", type=int, default=0)
    gen.add_argument("-l", "--length", type=float, nargs=2, default=(200.0, 400.0), metavar=("MIN", "MAX"))
    gen.add_argument("-p", "--id-prefix", default="route")
    gen.add_argument("-c", "--cavs", type=int, default=4, help="CAVs of entries that do not name a number")
    gen.add_argument("-w", "--weather", default="ClearNoon", help="weather of entries that do not name one")
    args = parser.parse_args(argv)
    if args.benchmark is not None:
        if args.entries:
            parser.error("give either -b NAME or TOWN entries, not both")
        return _main_benchmark(args.benchmark, args.output)
    if not args.entries:
        parser.error("give TOWN entries or -b NAME")
    entries = []
    for entry in args.entries:
        town, *rest = entry.split(":")
        entries.append(
            (town, int(rest[0]) if rest else args.cavs, rest[1] if len(rest) > 1 else args.weather)
        )
    length = (float(args.length[0]), float(args.length[1]))
    specs = generate_route_set(entries, args.seed, length, args.id_prefix)
    command = (
        f"cmudrive routes generate -o {args.output.as_posix()} -s {args.seed} "
        f"-l {length[0]:g} {length[1]:g} -p {args.id_prefix} "
        + " ".join(f"{t}:{c}:{w}" for t, c, w in entries)
    )
    summary = _summary(specs)
    write_routes(specs, args.output, comment="\n".join(["Generated by:", f"  {command}", "", *summary]))
    print("\n".join([f"wrote {len(specs)} routes to {args.output}", *summary]))
    return 0


def _main_benchmark(name: str, output: Path) -> int:
    from cmudrive.bench.authoring.benchmark_gen import ROUTE_SETS, generate_set, stats_lines
    from cmudrive.bench.routes import write_routes

    if name not in ROUTE_SETS:
        raise ValueError(f"unknown route set {name!r}; known: {', '.join(ROUTE_SETS)}")
    specs = generate_set(name, progress=lambda line: print(line, flush=True))
    lines = stats_lines(specs)
    command = f"cmudrive routes generate -b {name} -o {output.as_posix()}"
    write_routes(specs, output, comment="\n".join(["Generated by:", f"  {command}", "", *lines]))
    print("\n".join([f"wrote {len(specs)} routes to {output}", *lines]))
    return 0


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
            for v in c.rules:
                line = f"[yellow]rule[/]  {escape(c.route_id)}: {v.rule}: {escape(v.message)}"
                console.print(line, highlight=False)
        else:
            bad += 1
            console.print(f"[red]error[/] {escape(c.route_id)}: {escape(c.problem)}", highlight=False)
    console.print(f"{len(checks) - bad} of {len(checks)} routes can run")
    ruled = [c for c in checks if c.rules]
    if ruled:
        counts: dict[str, int] = {}
        for c in ruled:
            for name in {v.rule for v in c.rules}:
                counts[name] = counts.get(name, 0) + 1
        per_rule = ", ".join(f"{name} {n}" for name, n in sorted(counts.items()))
        console.print(f"{len(ruled)} of them break a placement rule ({per_rule}; docs/route_format.md)")
    if bad:
        raise typer.Exit(code=1)


@routes_app.command("stats")
def routes_stats(
    source: Annotated[str, typer.Argument(help="route file, or the name of a committed route set")],
) -> None:
    """Table 1's row of a route file (routes, min/max/avg CAVs) and its per-type, per-town and per-weather
    counts."""
    from rich.table import Table

    from cmudrive.bench.authoring.benchmark_gen import set_stats
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
    source: Annotated[
        Path,
        typer.Argument(
            help="Bench2Drive / Leaderboard-2.0 route file, or an InterDrive / MDrive scenario folder "
            "(or a folder of them)"
        ),
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="our multi-CAV route file to write")],
    cavs: Annotated[
        int,
        typer.Option(
            min=1, max=16, help="CAVs per route (CAV 0 drives the original route); route files only"
        ),
    ] = 2,
    town: Annotated[
        list[str] | None, typer.Option(help="extra town: name or .net.xml path (repeatable)")
    ] = None,
    seed: Annotated[int, typer.Option(help="seed of the added CAVs (route files), SUMO seed (folders)")] = 0,
    npc: Annotated[
        bool,
        typer.Option(
            "--npc/--no-npc",
            help="folders: InterDrive's NPC variant (50 background vehicles, 50 pedestrians), not none",
        ),
    ] = False,
) -> None:
    """Import single-ego leaderboard routes (routes on towns we have no map of are skipped, with why), or
    multi-vehicle scenario folders: one route per folder, its ego files as CAVs, its other actors kept."""
    from cmudrive.bench.authoring.bench2drive import ImportResult, import_leaderboard_routes
    from cmudrive.bench.authoring.interdrive import import_scenario_folders
    from cmudrive.bench.routes import write_routes

    try:
        result: ImportResult
        if source.is_dir():
            result = import_scenario_folders(source, npc=npc, seed=seed, towns=town)
        else:
            result = import_leaderboard_routes(source, towns=town, extra_cavs=cavs - 1, seed=seed)
    except (OSError, ValueError, MapError) as exc:
        fail(exc)
    for route_id, reason in result.skipped:
        err_console.print(f"[yellow]skipped route {route_id}:[/] {reason}", highlight=False)
    for route_id, note in result.notes:
        err_console.print(f"[cyan]changed {route_id}:[/] {note}", highlight=False)
    if not result.routes:
        fail(ValueError(f"no route of {source} could be imported"))
    least = min(len(r.cavs) for r in result.routes)
    write_routes(result.routes, output, min_cavs=min(least, 2))
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
