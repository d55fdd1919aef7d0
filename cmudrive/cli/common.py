"""What the commands share: the consoles, the error exit, and reading, running and showing the progress of
routes (``eval`` and ``data collect``)."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

console = Console()
err_console = Console(stderr=True)

LOG_WIDTH = 200  # [columns] of tables written to a file or a pipe (rich's default there: 80)

MAX_WORKERS = 4  # default route workers at most (each holds a SUMO world, ~300 MB)


def default_workers() -> int:
    return max(1, min(os.cpu_count() or 1, MAX_WORKERS))


def fail(exc: Exception) -> None:
    from rich.markup import escape

    # the message as it is: no markup read in it, only its own line breaks
    err_console.print(f"[bold red]error:[/] {escape(str(exc))}", soft_wrap=True)
    raise typer.Exit(code=1)


def routes_path(name_or_path: str) -> Path:
    """The route file a ``--routes`` value names (``cmudrive.bench.route_sets``: set names win)."""
    from cmudrive.bench.route_sets import RouteSelectionError, resolve_routes

    try:
        return resolve_routes(name_or_path)
    except RouteSelectionError as exc:
        fail(exc)
        raise  # unreachable: fail exits


def read_specs(
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

    path = routes_path(routes)
    try:
        specs, invalid = read_routes(path, strict=False)
        if subset is not None:
            picked = set(select_subset(route_ids(path), subset, str(path)))
            specs = [s for s in specs if s.id in picked]
            invalid = [(route_id, message) for route_id, message in invalid if route_id in picked]
    except (OSError, ValueError) as exc:  # RouteSelectionError too
        fail(exc)
    if invalid and refuse_invalid:
        lines = "".join(f"\n  route {route_id}: {message}" for route_id, message in invalid)
        fail(
            ValueError(f"{path}: {len(invalid)} routes cannot be read (fix them, or --skip-invalid):{lines}")
        )
    for route_id, message in invalid:
        err_console.print(f"[yellow]skipping route {route_id}:[/] {message}")
    specs = specs[:limit] if limit is not None else specs
    if not specs:
        fail(ValueError(f"{path}: no route to run" + (" (every route is invalid)" if invalid else "")))
    extra_dirs = tuple(str(d.resolve()) for d in town_dir or ())
    return path, [dataclasses.replace(s, town_dirs=s.town_dirs + extra_dirs) for s in specs]


def agent_options(pairs: list[str] | None, checkpoint: Path | None) -> dict[str, Any]:
    """``--agent-option KEY=VALUE`` pairs (VALUE as JSON when it parses) and ``--checkpoint``."""
    options: dict[str, Any] = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip().isidentifier():
            fail(ValueError(f"--agent-option {pair!r}: expected KEY=VALUE with KEY a Python identifier"))
        try:
            options[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            options[key.strip()] = value
    if checkpoint is not None:
        options["checkpoint"] = str(checkpoint.resolve())
    return options


def route_executor(executor: str, workers: int | None, ray_address: str | None) -> Any:
    """The executor named on the command line (``local`` with ``workers``, or ``ray``)."""
    from cmudrive.bench.runner import LocalExecutor, RayExecutor

    if executor == "ray":
        return RayExecutor(ray_address)
    if executor != "local":
        fail(ValueError(f"--executor {executor!r}: use 'local' or 'ray'"))
    return LocalExecutor(workers or default_workers())


@contextlib.contextmanager
def warnings_to_stderr() -> Iterator[None]:
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
def route_progress(path: Path, total: int, tick_cap: int) -> Iterator[tuple[Any, Any]]:
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

# options of eval and data collect: which routes run where
Workers = Annotated[
    int | None,
    typer.Option(
        min=1, help=f"routes run in parallel (local executor); default: CPUs, at most {MAX_WORKERS}"
    ),
]
Executor = Annotated[str, typer.Option(help="local or ray")]
RayAddress = Annotated[str | None, typer.Option(help="address of an existing Ray cluster")]
TickCap = Annotated[int, typer.Option(min=1, help="ticks per route at most (20 per second)")]
TownDirs = Annotated[
    list[Path] | None,
    typer.Option(help="folder of <town>.net.xml networks, searched after the route file's own folder"),
]
Checkpoint = Annotated[
    Path | None,
    typer.Option(
        help="model checkpoint directory, passed to the agent's constructor as checkpoint=PATH "
        "(v2v-vla: default the committed cmudrive/assets/models/v2v-vla-tiny-no-speed)"
    ),
]
AgentOptions = Annotated[
    list[str] | None,
    typer.Option(
        help="KEY=VALUE passed to the agent's constructor, repeatable; VALUE is read as JSON when it "
        'parses (5, false, "own"), else as a string (v2v-vla: --agent-option partner_requests=false)'
    ),
]
