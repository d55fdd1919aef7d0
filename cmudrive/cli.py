"""The ``cmudrive`` command line."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any

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
routes_app = typer.Typer(
    help="Route files: generate multi-CAV routes, import Bench2Drive routes.", no_args_is_help=True
)
app.add_typer(routes_app, name="routes")
data_app = typer.Typer(
    help="The driving dataset: collect expert rollouts into shards, summarise them, draw samples.",
    no_args_is_help=True,
)
app.add_typer(data_app, name="data")
console = Console()
err_console = Console(stderr=True)
LOG_WIDTH = 200  # [columns] of tables written to a file or a pipe (rich's default there: 80)


@app.callback()
def _log_width() -> None:
    """Tables as wide as a log needs when the output is not a terminal (cluster jobs write to files)."""
    for c in (console, err_console):
        if not c.is_terminal:
            c.width = LOG_WIDTH


MAX_WORKERS = 4  # default route workers at most (each holds a SUMO world, ~300 MB)


def default_workers() -> int:
    return max(1, min(os.cpu_count() or 1, MAX_WORKERS))


def _fail(exc: Exception) -> None:
    from rich.markup import escape

    # the message as it is: no markup read in it, only its own line breaks
    err_console.print(f"[bold red]error:[/] {escape(str(exc))}", soft_wrap=True)
    raise typer.Exit(code=1)


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
    sensors: Annotated[
        bool,
        typer.Option(help="show the followed CAV's camera, own and merged occupancy beside the BEV view"),
    ] = False,
) -> None:
    """CAVs on a lane-following autopilot among background traffic, rendered in BEV."""
    from cmudrive.viz.demo import run_demo

    if follow is not None and not 0 <= follow < cavs:
        _fail(ValueError(f"--follow {follow}: there are only CAVs 0-{cavs - 1}"))
    try:
        stats = run_demo(town, cavs, seconds, seed, output, pixels_per_meter, follow, window, sensors)
    except MapError as exc:
        _fail(exc)
    console.print(
        f"{stats.ticks} ticks; CAVs drove {stats.cav_distance.sum():.0f} m in total; up to "
        f"{stats.max_background_vehicles} background vehicles and {stats.max_pedestrians} pedestrians; "
        f"{len(stats.collisions)} collision events ({stats.sumo_collisions} seen by SUMO's own check)"
    )
    for t, a, b in stats.collisions[:10]:
        console.print(f"  t={t:.2f} s: {a} - {b}")
    if output is not None:
        console.print(f"wrote {output}")


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
        _fail(exc)
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
        checks = check_route_file(_routes_path(source), [str(d.resolve()) for d in town_dir or ()])
    except (OSError, ValueError) as exc:
        _fail(exc)
    if not checks:
        _fail(ValueError(f"{source}: no route in the file"))
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
        st = set_stats(read_routes(_routes_path(source)))
    except (OSError, ValueError) as exc:
        _fail(exc)
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
        _fail(exc)
    for route_id, reason in result.skipped:
        err_console.print(f"[yellow]skipped route {route_id}:[/] {reason}")
    if not result.routes:
        _fail(ValueError(f"no route of {source} could be imported"))
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
        specs = read_routes(_routes_path(file), min_cavs=1)
        spec = next((s for s in specs if s.id == route_id), None)
        if spec is None:
            known = ", ".join(s.id for s in specs[:10]) + (", ..." if len(specs) > 10 else "")
            raise ValueError(f"{file} has no route {route_id!r} (routes: {known})")
        path = save_route_figure(spec, output)
    except (OSError, ValueError, MapError, ScenarioError) as exc:
        _fail(exc)
    console.print(f"wrote {path}")


def _routes_path(name_or_path: str) -> Path:
    """The route file a ``--routes`` value names (``cmudrive.bench.route_sets``: set names win)."""
    from cmudrive.bench.route_sets import RouteSelectionError, resolve_routes

    try:
        return resolve_routes(name_or_path)
    except RouteSelectionError as exc:
        _fail(exc)
        raise  # unreachable: _fail exits


def _read_specs(
    routes: str,
    town_dir: list[Path] | None,
    limit: int | None = None,
    refuse_invalid: bool = False,
    subset: str | None = None,
) -> tuple[Path, list[Any]]:
    """The valid routes of a route file or set (invalid ones reported and skipped), only those ``subset``
    picks (``--routes-subset``), then at most ``limit``, with the extra town folders; exits naming the file
    when none is left, or, with ``refuse_invalid``, when any picked route cannot be read (every one
    listed)."""
    from cmudrive.bench.route_sets import select_subset
    from cmudrive.bench.routes import read_routes, route_ids

    path = _routes_path(routes)
    try:
        specs, invalid = read_routes(path, strict=False)
        if subset is not None:
            picked = set(select_subset(route_ids(path), subset, str(path)))
            specs = [s for s in specs if s.id in picked]
            invalid = [(route_id, message) for route_id, message in invalid if route_id in picked]
    except (OSError, ValueError) as exc:  # RouteSelectionError too
        _fail(exc)
    if invalid and refuse_invalid:
        lines = "".join(f"\n  route {route_id}: {message}" for route_id, message in invalid)
        _fail(
            ValueError(f"{path}: {len(invalid)} routes cannot be read (fix them, or --skip-invalid):{lines}")
        )
    for route_id, message in invalid:
        err_console.print(f"[yellow]skipping route {route_id}:[/] {message}")
    specs = specs[:limit] if limit is not None else specs
    if not specs:
        _fail(ValueError(f"{path}: no route to run" + (" (every route is invalid)" if invalid else "")))
    extra_dirs = tuple(str(d.resolve()) for d in town_dir or ())
    return path, [dataclasses.replace(s, town_dirs=s.town_dirs + extra_dirs) for s in specs]


def _agent_options(pairs: list[str] | None, checkpoint: Path | None) -> dict[str, Any]:
    """``--agent-option KEY=VALUE`` pairs (VALUE as JSON when it parses) and ``--checkpoint``."""
    options: dict[str, Any] = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip().isidentifier():
            _fail(ValueError(f"--agent-option {pair!r}: expected KEY=VALUE with KEY a Python identifier"))
        try:
            options[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            options[key.strip()] = value
    if checkpoint is not None:
        options["checkpoint"] = str(checkpoint.resolve())
    return options


def _leaderboard_agent(agent: str, config: Any) -> tuple[str, Any]:
    """``--agent leaderboard:FILE.py`` is the bundled ``leaderboard`` agent with the option
    ``agent=FILE.py`` (an absolute path: route workers may run elsewhere); other agents pass unchanged."""
    prefix, sep, file = agent.partition(":")
    if prefix != "leaderboard" or not sep:
        return agent, config
    if not file or "agent" in config.agent_options:
        _fail(ValueError("--agent leaderboard:FILE.py names the agent file once (no --agent-option agent=)"))
    options = {**config.agent_options, "agent": str(Path(file).resolve())}
    return "leaderboard", dataclasses.replace(config, agent_options=options)


def _route_executor(executor: str, workers: int | None, ray_address: str | None) -> Any:
    """The executor named on the command line (``local`` with ``workers``, or ``ray``)."""
    from cmudrive.bench.runner import LocalExecutor, RayExecutor

    if executor == "ray":
        return RayExecutor(ray_address)
    if executor != "local":
        _fail(ValueError(f"--executor {executor!r}: use 'local' or 'ray'"))
    return LocalExecutor(workers or default_workers())


@contextlib.contextmanager
def _warnings_to_stderr() -> Iterator[None]:
    """Python warnings raised inside (a resume of a folder written by other code: ResumeWarning, shown
    every time) printed on stderr as ``warning: ...`` lines."""
    from rich.markup import escape

    from cmudrive.bench.manifest import ResumeWarning

    def show(message: Warning | str, *args: Any, **kwargs: Any) -> None:
        err_console.print(f"[bold yellow]warning:[/] {escape(str(message))}", highlight=False)

    with warnings.catch_warnings():
        warnings.simplefilter("always", ResumeWarning)
        warnings.showwarning = show
        yield


@contextlib.contextmanager
def _route_progress(path: Path, total: int, tick_cap: int) -> Iterator[tuple[Any, Any]]:
    """Progress of a run, yielding (on_progress(route_id, tick), done(route_id, ticks)); call ``done``
    after printing a route's line. In a terminal: bars, one over the routes (with elapsed time, ETA and
    simulated seconds per wall second) and one per running route over its ticks. Elsewhere (a log file):
    no bars, one plain line after each finished route with the same numbers (``RunProgress``)."""
    import time

    from rich.markup import escape
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        ProgressColumn,
        Task,
        TaskID,
        TextColumn,
    )
    from rich.text import Text

    from cmudrive.bench.progress import RunProgress

    state = RunProgress(total)
    if not console.is_terminal:

        def done_plain(route_id: str, ticks: int) -> None:
            state.finish(route_id, ticks)
            console.print(f"progress: {state.describe(time.monotonic())}", soft_wrap=True, highlight=False)

        yield state.tick, done_plain
        return

    class RunColumn(ProgressColumn):
        """Elapsed time, ETA and simulated-time ratio of the run, on the overall bar, at each refresh."""

        def render(self, task: Task) -> Text:
            shown = (
                state.describe(time.monotonic()).partition(" routes, ")[2] if task.fields.get("run") else ""
            )
            return Text(shown)

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), RunColumn())
    with Progress(*columns, console=console) as progress:
        overall = progress.add_task(escape(f"{total} routes from {path.name}"), total=total, run=True)
        ticks: dict[str, TaskID] = {}

        def on_progress(route_id: str, tick: int) -> None:
            state.tick(route_id, tick)
            if route_id not in ticks:
                ticks[route_id] = progress.add_task(escape(f"  route {route_id} [ticks]"), total=tick_cap)
            progress.update(ticks[route_id], completed=tick)

        def done(route_id: str, ticks_run: int) -> None:
            state.finish(route_id, ticks_run)
            progress.advance(overall)
            if route_id in ticks:
                progress.remove_task(ticks.pop(route_id))

        yield on_progress, done


# --routes-subset of eval and data collect (bench.route_sets.select_subset)
RoutesSubset = Annotated[
    str | None,
    typer.Option(
        help="only these routes of the file: ids, 0-based indices and inclusive index ranges, "
        "comma-separated (Accident_0,HighwayCutIn_2 or 0-5 or 3,7,12; an exact id wins)"
    ),
]


@app.command("eval")
def evaluate(
    routes: Annotated[
        str,
        typer.Option(
            help="route file (.xml) or a committed route set: cmudrive44, cmudrive220, smoke, training"
        ),
    ] = "cmudrive44",
    routes_subset: RoutesSubset = None,
    agent: Annotated[
        str,
        typer.Option(
            help="agent class as package.module:Class, or a bundled one: expert, autopilot, pid, "
            "v2v-vla, v2v-vla-baseline; leaderboard:FILE.py runs a CARLA leaderboard agent file on every "
            "CAV (--agent-option conf=... is what its setup() gets)"
        ),
    ] = "expert",
    checkpoint: Annotated[
        Path | None,
        typer.Option(
            help="model checkpoint directory, passed to the agent's constructor as checkpoint=PATH "
            "(v2v-vla: default the committed cmudrive/assets/models/v2v-vla-tiny-no-speed)"
        ),
    ] = None,
    agent_option: Annotated[
        list[str] | None,
        typer.Option(
            help="KEY=VALUE passed to the agent's constructor, repeatable; VALUE is read as JSON when it "
            'parses (5, false, "own"), else as a string (v2v-vla: --agent-option partner_requests=false)'
        ),
    ] = None,
    out: Annotated[Path, typer.Option(help="output folder")] = Path("out/eval"),
    workers: Annotated[
        int | None,
        typer.Option(
            min=1, help=f"routes run in parallel (local executor); default: CPUs, at most {MAX_WORKERS}"
        ),
    ] = None,
    resume: Annotated[
        bool, typer.Option(help="skip routes already finished in OUT, re-run crashed ones")
    ] = False,
    skip_invalid: Annotated[
        bool,
        typer.Option(
            help="run the valid routes when some cannot run (bad town, waypoints or scenario parameters): "
            "those get 'Failed - Invalid route', counted apart and left out of DS/SR; without it the run "
            "is refused"
        ),
    ] = False,
    executor: Annotated[str, typer.Option(help="local or ray")] = "local",
    ray_address: Annotated[str | None, typer.Option(help="address of an existing Ray cluster")] = None,
    record: Annotated[bool, typer.Option(help="save a replayable log per route in OUT/logs")] = False,
    tick_cap: Annotated[int, typer.Option(min=1, help="ticks per route at most (20 per second)")] = 4000,
    seed: Annotated[
        int,
        typer.Option(
            min=0,
            help="evaluation seed, added to every route's seed (0: the route file's own); another seed "
            "draws other background traffic and pedestrians on the same routes",
        ),
    ] = 0,
    step_timeout: Annotated[
        float, typer.Option(help="seconds an agent may take per step (> 0); a hung worker is killed")
    ] = 10.0,
    max_memory: Annotated[
        float | None,
        typer.Option(help="GiB of address space per route's worker (exceeding it: Agent crashed)"),
    ] = None,
    town_dir: Annotated[
        list[Path] | None,
        typer.Option(help="folder of <town>.net.xml networks, searched after the route file's own folder"),
    ] = None,
    v2v_range: Annotated[
        float | None, typer.Option(help="V2V link: messages between CAVs farther apart (metres) are lost")
    ] = None,
    v2v_latency: Annotated[int, typer.Option(help="V2V link: latency in ticks of 0.05 s")] = 0,
    v2v_pose_noise: Annotated[
        tuple[float, float],
        typer.Option(help="V2V link: sigma of the partner's received position (metres) and yaw (degrees)"),
    ] = (0.0, 0.0),
    v2v_drop: Annotated[float, typer.Option(help="V2V link: probability that a message is lost")] = 0.0,
    detection_noise: Annotated[
        tuple[float, float],
        typer.Option(
            help="occupancy: miss probability and position sigma (metres) of an object at the weather's range"
        ),
    ] = (0.0, 0.0),
) -> None:
    """Evaluate an agent on a route file; one JSON record per route as it finishes, merged results.json."""
    from rich.markup import escape

    from cmudrive.bench.evaluator import EvalConfig
    from cmudrive.bench.observe import SensorConfig
    from cmudrive.bench.records import RouteResult
    from cmudrive.bench.runner import run_evaluation
    from cmudrive.sensors import DetectionNoise
    from cmudrive.v2v import LinkConfig

    path, specs = _read_specs(routes, town_dir, refuse_invalid=not skip_invalid, subset=routes_subset)
    try:
        sensors = SensorConfig(
            noise=DetectionNoise(*detection_noise),
            link=LinkConfig(v2v_range, v2v_latency, v2v_pose_noise[0], v2v_pose_noise[1], v2v_drop),
        )
    except ValueError as exc:
        _fail(ValueError(f"--v2v-* / --detection-noise: {exc}"))
    try:
        config = EvalConfig(
            tick_cap=tick_cap,
            step_timeout=step_timeout,
            record_dir=out / "logs" if record else None,
            sensors=sensors,
            agent_options=_agent_options(agent_option, checkpoint),
        )
    except ValueError as exc:
        _fail(ValueError(f"--step-timeout / --tick-cap: {exc}"))
    agent, config = _leaderboard_agent(agent, config)
    if agent in ("v2v-vla", "v2v-vla-baseline"):  # a missing checkpoint fails here, not once per route
        from cmudrive.model.agent import resolve_checkpoint

        try:
            resolve_checkpoint(checkpoint, cooperative=agent == "v2v-vla")
        except FileNotFoundError as exc:
            _fail(exc)
    runner = _route_executor(executor, workers, ray_address)
    with _route_progress(path, len(specs), tick_cap) as (on_progress, done):

        def on_result(result: RouteResult) -> None:
            console.print(
                f"route {escape(result.route_id)}: {result.status}, DS {result.driving_score:.1f} "
                f"(RC {result.route_completion:.1f}, IS {result.infraction_score:.2f}), "
                f"{result.ticks} ticks, {result.wall_time:.0f} s",
                soft_wrap=True,
            )
            if result.error:  # why it crashed, in one line: the error's last line
                last = result.error.strip().splitlines()[-1] if result.error.strip() else ""
                err_console.print(f"  [red]{escape(last)}[/]", highlight=False, soft_wrap=True)
            done(result.route_id, result.ticks)

        try:
            with _warnings_to_stderr():
                merged = run_evaluation(
                    specs,
                    agent,
                    out,
                    runner,
                    config,
                    resume,
                    on_result,
                    on_progress,
                    max_memory=max_memory,
                    skip_invalid=skip_invalid,
                    seed=seed,
                    routes_file=path,
                )
        except KeyboardInterrupt:
            err_console.print(f"interrupted: finished routes are in {out / 'routes'}; continue with --resume")
            raise typer.Exit(code=130) from None
        except ValueError as exc:
            _fail(exc)
    _print_results(merged)
    console.print(f"results: {out / 'results.json'}")


@data_app.command("collect")
def data_collect(
    routes: Annotated[
        str, typer.Option(help="route file (.xml) or a committed route set (training; never the benchmark's)")
    ] = "training",
    routes_subset: RoutesSubset = None,
    out: Annotated[Path, typer.Option(help="dataset folder: one <route>.parquet shard per route")] = Path(
        "data/train"
    ),
    workers: Annotated[
        int | None,
        typer.Option(
            min=1, help=f"routes run in parallel (local executor); default: CPUs, at most {MAX_WORKERS}"
        ),
    ] = None,
    executor: Annotated[str, typer.Option(help="local or ray")] = "local",
    ray_address: Annotated[str | None, typer.Option(help="address of an existing Ray cluster")] = None,
    resume: Annotated[
        bool, typer.Option(help="collect only the routes without a complete shard in OUT")
    ] = False,
    limit_routes: Annotated[
        int | None, typer.Option(min=1, help="only the first K routes of the file")
    ] = None,
    tick_cap: Annotated[int, typer.Option(min=1, help="ticks per route at most (20 per second)")] = 4000,
    step_timeout: Annotated[
        float, typer.Option(help="seconds the expert and sensors may take per step; a hung worker is killed")
    ] = 10.0,
    allow_benchmark_routes: Annotated[
        bool, typer.Option(help="collect on routes of cmudrive220/cmudrive44 too (never for training data)")
    ] = False,
    town_dir: Annotated[
        list[Path] | None,
        typer.Option(help="folder of <town>.net.xml networks, searched after the route file's own folder"),
    ] = None,
) -> None:
    """Run the expert on the routes and save one sample per active CAV every 5th tick (docs/data.md)."""
    from rich.markup import escape

    from cmudrive.bench.evaluator import EvalConfig
    from cmudrive.bench.records import RouteResult
    from cmudrive.data import collect, shard_path
    from cmudrive.data.shards import shard_rows

    path, specs = _read_specs(routes, town_dir, limit_routes, subset=routes_subset)
    try:
        config = EvalConfig(tick_cap=tick_cap, step_timeout=step_timeout)
    except ValueError as exc:
        _fail(ValueError(f"--step-timeout / --tick-cap: {exc}"))
    runner = _route_executor(executor, workers, ray_address)
    samples = 0
    with _route_progress(path, len(specs), tick_cap) as (on_progress, done):

        def on_result(result: RouteResult, written: bool) -> None:
            nonlocal samples
            if written:
                rows = shard_rows(shard_path(out, result.route_id))
                samples += rows
                console.print(
                    f"route {escape(result.route_id)}: {rows} samples, {result.ticks} ticks, "
                    f"{result.wall_time:.0f} s",
                    soft_wrap=True,
                )
            else:
                last = (result.error or "").strip().splitlines()[-1:] or [result.status]
                err_console.print(
                    f"[red]route {escape(result.route_id)} failed, no shard:[/] {escape(last[0])}",
                    soft_wrap=True,
                )
            done(result.route_id, result.ticks)

        try:
            with _warnings_to_stderr():
                summary = collect(
                    specs,
                    out,
                    runner,
                    config,
                    resume=resume,
                    allow_benchmark=allow_benchmark_routes,
                    on_result=on_result,
                    on_progress=on_progress,
                    routes_file=path,
                )
        except KeyboardInterrupt:
            err_console.print(f"interrupted: finished shards are in {out}; continue with --resume")
            raise typer.Exit(code=130) from None
        except (ValueError, FileExistsError) as exc:
            _fail(exc)
    console.print(
        f"{len(summary.written)} shards written ({samples} samples), {len(summary.skipped)} already there, "
        f"{len(summary.failed)} routes failed; dataset: {out}"
    )
    if summary.failed:
        raise typer.Exit(code=1)


@data_app.command("stats")
def data_stats(
    folder: Annotated[Path, typer.Argument(help="dataset folder")],
    as_json: Annotated[bool, typer.Option("--json", help="print the statistics as JSON")] = False,
) -> None:
    """Samples per scenario type, weather, CAV count and town; label histograms; waypoint ranges; size."""
    import json

    from rich.markup import escape

    from cmudrive.data.stats import dataset_stats

    try:
        stats = dataset_stats(folder)
    except (OSError, ValueError) as exc:
        _fail(exc)
    if as_json:
        console.print_json(json.dumps(stats))
        return
    console.print(
        f"{stats['samples']} samples from {stats['routes']} routes ({stats['shards']} shards), "
        f"{stats['bytes'] / 2**20:.1f} MiB on disk, {stats['bytes_per_sample']:.0f} bytes per sample; "
        f"communication sentence in {100 * stats['communication_share']:.1f} % of samples, "
        f"a V2V partner in {100 * stats['partner_share']:.1f} %"
    )
    n = max(stats["samples"], 1)
    for name, counts in stats["counts"].items():
        table = Table(title=f"samples per {name}")
        table.add_column(name)
        table.add_column("samples", justify="right")
        table.add_column("%", justify="right")
        for key, value in counts.items():
            table.add_row(escape(str(key)) if key != "" else "(none)", str(value), f"{100 * value / n:.1f}")
        console.print(table)
    table = Table(title="ranges")
    for col in ("quantity", "min", "p5", "median", "p95", "max"):
        table.add_column(col, justify="right" if col != "quantity" else "left")
    for name, r in stats["ranges"].items():
        if r:
            table.add_row(escape(name), *(f"{r[k]:.2f}" for k in ("min", "p5", "median", "p95", "max")))
    console.print(table)


@data_app.command("show")
def data_show(
    folder: Annotated[Path, typer.Argument(help="dataset folder")],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG to write")] = Path("grid.png"),
    types: Annotated[
        list[str] | None,
        typer.Option("--types", help="scenario types to show (comma-separated, or repeat the option)"),
    ] = None,
    count: Annotated[int, typer.Option(min=1, help="samples to draw")] = 8,
    seed: Annotated[int, typer.Option(help="which samples (random draw)")] = 0,
) -> None:
    """A grid of samples: camera with the path, merged BEV with path and speed waypoints, sentences."""
    from cmudrive.data.show import save_grid

    try:
        names = [t for arg in types or () for t in arg.split(",") if t]
        path = save_grid(folder, output, count=count, types=names or None, seed=seed)
    except (OSError, ValueError) as exc:
        _fail(exc)
    console.print(f"wrote {path}")


PER_ROUTE_TABLE_MAX = 12  # routes; larger runs print one row per scenario type
# infraction keys a failure status already says (and minimum speed, which is recorded without penalty)
_IMPLIED_BY_STATUS = frozenset({"min_speed_infractions", "vehicle_blocked", "route_dev", "route_timeout"})


def _failures(route: dict[str, Any]) -> str:
    """Why a route is not a success, per CAV: its status (when not completed) and its infractions."""
    parts = []
    for cav in route.get("cavs", []):
        status = str(cav["status"])
        why = [status.removeprefix("Failed - Agent ").removeprefix("Failed - ")] if "Failed" in status else []
        why += sorted(k for k, v in cav["infractions"].items() if v and k not in _IMPLIED_BY_STATUS)
        if why:
            parts.append(f"{cav['cav_id']}: {', '.join(why)}")
    if route.get("error") and not parts:
        parts.append(str(route["status"]))
    return "; ".join(parts)


def _route_line(r: dict[str, Any]) -> str:
    """One route's results on one line, every field, the whole failure reason (logs)."""
    why = _failures(r)
    return (
        f"route {r['route_id']} ({r.get('scenario_type') or 'no scenario'}): {r['town']}, {r['weather']}, "
        f"{r['num_cavs']} CAVs, {r['status']}, RC {r['route_completion']:.1f}, "
        f"IS {r['infraction_score']:.3f}, DS {r['driving_score']:.1f}" + (f"; why: {why}" if why else "")
    )


def _results_table(merged: dict[str, Any]) -> Table:
    """A row per route (up to ``PER_ROUTE_TABLE_MAX`` routes) or per scenario type, with why routes failed."""
    routes = merged["routes"]
    if len(routes) <= PER_ROUTE_TABLE_MAX:
        table = Table(title="CMU-Drive results")
        for col in ("route", "town", "weather", "CAVs", "status", "RC", "IS", "DS", "why not a success"):
            table.add_column(col)
        for r in routes:
            table.add_row(
                str(r["route_id"]),
                r["town"],
                r["weather"],
                str(r["num_cavs"]),
                r["status"],
                f"{r['route_completion']:.1f}",
                f"{r['infraction_score']:.3f}",
                f"{r['driving_score']:.1f}",
                _failures(r),
            )
    else:
        table = Table(title="CMU-Drive results by scenario type")
        for col in (
            "scenario type",
            "routes",
            "DS",
            "SR %",
            "why not a success (route: CAV: why)",
        ):
            table.add_column(col)
        by_type: dict[str, list[dict[str, Any]]] = {}
        for r in routes:
            by_type.setdefault(str(r.get("scenario_type") or "-"), []).append(r)
        for name, group in by_type.items():
            scores = merged["summary"]["by_scenario_type"].get(name)
            ds = f"{scores['driving_score']:.1f}" if scores else "-"
            sr = f"{scores['success_rate']:.0f}" if scores else "-"
            why = " | ".join(f"{r['route_id']}: {_failures(r)}" for r in group if not r["success"])
            table.add_row(name, str(len(group)), ds, sr, why)
    return table


def _print_results(merged: dict[str, Any]) -> None:
    """The results of a run: a table in a terminal; where stdout is not one (a log file), plain lines that
    no width cuts: one per route with every field and why it failed, then one per scenario type."""
    routes = merged["routes"]
    if console.is_terminal:
        console.print(_results_table(merged))
    else:
        for r in routes:
            console.print(_route_line(r), soft_wrap=True, highlight=False, markup=False)
        if len(routes) > PER_ROUTE_TABLE_MAX:
            by_type = merged["summary"]["by_scenario_type"]
            for name in dict.fromkeys(str(r.get("scenario_type") or "-") for r in routes):
                if name in by_type:
                    ds, sr = by_type[name]["driving_score"], by_type[name]["success_rate"]
                    console.print(f"scenario type {name}: DS {ds:.1f}, SR {sr:.0f} %", soft_wrap=True)
    s = merged["summary"]
    invalid = s.get("num_invalid", 0)
    console.print(
        f"driving score {s['driving_score']:.2f}, success rate {s['success_rate']:.2f} %, "
        f"{s['num_routes']} routes" + (f" ({invalid} invalid routes skipped, not scored)" if invalid else "")
    )


@app.command("train")
def train_model(
    data: Annotated[Path, typer.Option(help="dataset folder of <route>.parquet shards (data collect)")],
    out: Annotated[Path, typer.Option(help="run folder: checkpoints, metrics.jsonl, tensorboard/, model/")],
    config: Annotated[str, typer.Option(help="model configuration: tiny, small, internvl2-1b")] = "tiny",
    baseline: Annotated[
        bool, typer.Option(help="train the non-cooperative baseline (same data, size and budget)")
    ] = False,
    pretrained_path: Annotated[
        Path | None, typer.Option(help="local InternVL checkpoint directory (internvl2-1b)")
    ] = None,
    resume: Annotated[bool, typer.Option(help="continue from OUT's last checkpoint")] = False,
    epochs: Annotated[int, typer.Option(min=1, help="passes over the training routes")] = 1,
    max_steps: Annotated[
        int | None, typer.Option(min=1, help="optimizer steps (instead of --epochs)")
    ] = None,
    batch_size: Annotated[int, typer.Option(min=1, help="rows per step and process")] = 8,
    lr: Annotated[
        float | None, typer.Option(help="peak learning rate (default: tiny 1e-3, internvl2-1b 3e-5)")
    ] = None,
    save_every: Annotated[int, typer.Option(min=1, help="checkpoint every N steps (and at the end)")] = 500,
    log_every: Annotated[int, typer.Option(min=1, help="a metrics line every N steps")] = 10,
    val_fraction: Annotated[float, typer.Option(help="share of the routes held out for validation")] = 0.1,
    standing_keep: Annotated[
        float,
        typer.Option(
            help="share of the standing rows kept (below 0.1 m/s and still there 2.5 s later; 47 % of "
            "the collection); fewer teach a model fed its speed to start again"
        ),
    ] = 1.0,
    communication_repeat: Annotated[
        int,
        typer.Option(
            min=1,
            help="times each row with a communication sentence (1.2 % of the collection) is seen per epoch",
        ),
    ] = 1,
    speed_input: Annotated[
        bool, typer.Option(help="the prompt states the CAV's speed (SimLingo); --no-speed-input: never")
    ] = True,
    speed_dropout: Annotated[
        float, typer.Option(help="share of training rows whose prompt leaves the speed out")
    ] = 0.0,
    bucket_power: Annotated[
        float | None,
        typer.Option(
            help="bucketed sampling: bucket shares (starts, stands, stops, turns, follows, slows, cruises) "
            "proportional to count ** P; 1 samples as collected, 0 equal shares (default: no buckets)"
        ),
    ] = None,
    threads: Annotated[
        int | None,
        typer.Option(
            min=1, help="torch threads of this process (default: torch's choice; 1 per process on a CPU)"
        ),
    ] = None,
    num_workers: Annotated[int, typer.Option(min=0, help="DataLoader worker processes")] = 0,
    mixed_precision: Annotated[
        str, typer.Option(help="auto (bf16/fp16 on GPUs, none on CPU), no, fp16, bf16")
    ] = "auto",
    augment_prob: Annotated[
        float, typer.Option(help="share of training rows rotated by up to +-20 deg (0: off)")
    ] = 0.5,
    seed: Annotated[int, typer.Option(help="model initialisation, data order, augmentation, split")] = 0,
) -> None:
    """Train V2V-VLA (or --baseline) on a dataset folder; the same command on a CPU, one GPU or several
    (accelerate launch -m cmudrive.cli train ...)."""
    try:
        import torch

        from cmudrive.model.augment import YawAugment
        from cmudrive.model.train import TrainConfig, train
    except ImportError as exc:
        _fail(ImportError(f"training needs the model extra (pip install -e '.[model]'): {exc}"))
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        cfg = TrainConfig(
            data=str(data),
            out=str(out),
            model=config,
            cooperative=not baseline,
            pretrained_path=str(pretrained_path) if pretrained_path else None,
            epochs=epochs,
            max_steps=max_steps,
            batch_size=batch_size,
            lr=lr,
            save_every=save_every,
            log_every=log_every,
            val_fraction=val_fraction,
            standing_keep=standing_keep,
            communication_repeat=communication_repeat,
            speed_input=speed_input,
            speed_dropout=speed_dropout,
            bucket_power=bucket_power,
            num_workers=num_workers,
            mixed_precision=mixed_precision,
            augment=YawAugment(prob=augment_prob),
            seed=seed,
        )
        metrics = train(cfg, resume=resume)
    except (OSError, ValueError) as exc:
        _fail(exc)
    shown = ", ".join(f"{k} {v:.3f}" for k, v in metrics.items())
    console.print(f"model: {out / 'model'}" + (f"; validation: {shown}" if shown else ""))


@app.command("report")
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
    from cmudrive.bench.compare_report import write_comparison

    try:
        paths = write_comparison(runs, output)
    except (OSError, ValueError, MapError) as exc:
        _fail(exc)
    for p in paths:
        console.print(f"wrote {p}")


@app.command("export")
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
        _fail(ValueError(f"--format must be one of {', '.join(FORMATS)}, got {format!r}"))
    try:
        done = export_leaderboard(run, output, per=per, routes_file=routes, metric_info_required=metric_info)
    except (OSError, ValueError) as exc:
        _fail(exc)
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


@app.command("replay")
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
        _fail(exc)
    console.print(f"wrote {path}")


def main() -> None:
    app()


if __name__ == "__main__":
    main()
