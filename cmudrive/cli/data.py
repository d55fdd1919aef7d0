"""``cmudrive data``: collect the driving dataset, summarise it, draw samples."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from cmudrive.cli.common import (
    AgentOptions,
    Checkpoint,
    Executor,
    RayAddress,
    RoutesSubset,
    TickCap,
    TownDirs,
    Workers,
    agent_options,
    console,
    err_console,
    fail,
    read_specs,
    route_executor,
    route_progress,
    warnings_to_stderr,
)

data_app = typer.Typer(
    help="The driving dataset: collect expert rollouts into shards, summarise them, draw samples.",
    no_args_is_help=True,
)


@data_app.command("collect")
def data_collect(
    routes: Annotated[
        str, typer.Option(help="route file (.xml) or a committed route set (training; never the benchmark's)")
    ] = "training",
    routes_subset: RoutesSubset = None,
    out: Annotated[Path, typer.Option(help="dataset folder: one <route>.parquet shard per route")] = Path(
        "data/train"
    ),
    workers: Workers = None,
    executor: Executor = "local",
    ray_address: RayAddress = None,
    resume: Annotated[
        bool, typer.Option(help="collect only the routes without a complete shard in OUT")
    ] = False,
    limit_routes: Annotated[
        int | None, typer.Option(min=1, help="only the first K routes of the file")
    ] = None,
    tick_cap: TickCap = 4000,
    step_timeout: Annotated[
        float, typer.Option(help="seconds the driver may take per step; a hung worker is killed")
    ] = 10.0,
    allow_benchmark_routes: Annotated[
        bool, typer.Option(help="collect on routes of cmudrive220/cmudrive44 too (never for training data)")
    ] = False,
    recovery_views: Annotated[
        float,
        typer.Option(
            min=0.0,
            max=1.0,
            help="share of sampled rows that get a second row rendered from a pose beside the CAV, "
            "labelled back toward its path (docs/data.md, 'Recovery views')",
        ),
    ] = 0.0,
    driver: Annotated[
        str,
        typer.Option(
            help="the agent that drives: expert (default), a bundled one (v2v-vla, ...) or "
            "package.module:Class; another than the expert drives while the expert labels the states it "
            "reaches (closed-loop data, DAgger; docs/data.md)"
        ),
    ] = "expert",
    checkpoint: Checkpoint = None,
    agent_option: AgentOptions = None,
    town_dir: TownDirs = None,
) -> None:
    """Drive the routes (the expert, or --driver with the expert labelling) and save one sample per active
    CAV every 5th tick (docs/data.md)."""
    from rich.markup import escape

    from cmudrive.bench.evaluator import EvalConfig
    from cmudrive.bench.records import RouteResult
    from cmudrive.data import RecoveryViews, collect, shard_path
    from cmudrive.data.shards import shard_rows

    path, specs = read_specs(routes, town_dir, limit_routes, subset=routes_subset)
    try:
        config = EvalConfig(
            tick_cap=tick_cap,
            step_timeout=step_timeout,
            agent_options=agent_options(agent_option, checkpoint),
        )
    except ValueError as exc:
        fail(ValueError(f"--step-timeout / --tick-cap: {exc}"))
    runner = route_executor(executor, workers, ray_address)
    samples = 0
    with route_progress(path, len(specs), tick_cap) as (on_progress, done):

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
            with warnings_to_stderr():
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
                    recovery=RecoveryViews(prob=recovery_views),
                    driver=driver,
                )
        except KeyboardInterrupt:
            err_console.print(f"interrupted: finished shards are in {out}; continue with --resume")
            raise typer.Exit(code=130) from None
        except (ValueError, FileExistsError) as exc:
            fail(exc)
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

    from rich.markup import escape

    from cmudrive.data.stats import dataset_stats

    try:
        stats = dataset_stats(folder)
    except (OSError, ValueError) as exc:
        fail(exc)
    if as_json:
        console.print_json(json.dumps(stats))
        return
    console.print(
        f"{stats['samples']} samples from {stats['routes']} routes ({stats['shards']} shards; "
        f"{stats['recovery_views']} of them recovery views), {stats['bytes'] / 2**20:.1f} MiB on disk, "
        f"{stats['bytes_per_sample']:.0f} bytes per sample; "
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
        fail(exc)
    console.print(f"wrote {path}")
