"""``cmudrive eval``: an agent on a route file, one record per route, merged results."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Any

import typer

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
from cmudrive.cli.results import print_results


def _leaderboard_agent(agent: str, config: Any) -> tuple[str, Any]:
    """``--agent leaderboard:FILE.py`` is the bundled ``leaderboard`` agent with the option
    ``agent=FILE.py`` (an absolute path: route workers may run elsewhere); other agents pass unchanged."""
    prefix, sep, file = agent.partition(":")
    if prefix != "leaderboard" or not sep:
        return agent, config
    if not file or "agent" in config.agent_options:
        fail(ValueError("--agent leaderboard:FILE.py names the agent file once (no --agent-option agent=)"))
    options = {**config.agent_options, "agent": str(Path(file).resolve())}
    return "leaderboard", dataclasses.replace(config, agent_options=options)


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
    checkpoint: Checkpoint = None,
    agent_option: AgentOptions = None,
    out: Annotated[Path, typer.Option(help="output folder")] = Path("out/eval"),
    workers: Workers = None,
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
    executor: Executor = "local",
    ray_address: RayAddress = None,
    record: Annotated[bool, typer.Option(help="save a replayable log per route in OUT/logs")] = False,
    tick_cap: TickCap = 4000,
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
    town_dir: TownDirs = None,
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

    path, specs = read_specs(routes, town_dir, refuse_invalid=not skip_invalid, subset=routes_subset)
    try:
        sensors = SensorConfig(
            noise=DetectionNoise(*detection_noise),
            link=LinkConfig(v2v_range, v2v_latency, v2v_pose_noise[0], v2v_pose_noise[1], v2v_drop),
        )
    except ValueError as exc:
        fail(ValueError(f"--v2v-* / --detection-noise: {exc}"))
    try:
        config = EvalConfig(
            tick_cap=tick_cap,
            step_timeout=step_timeout,
            record_dir=out / "logs" if record else None,
            sensors=sensors,
            agent_options=agent_options(agent_option, checkpoint),
        )
    except ValueError as exc:
        fail(ValueError(f"--step-timeout / --tick-cap: {exc}"))
    agent, config = _leaderboard_agent(agent, config)
    runner = route_executor(executor, workers, ray_address)
    with route_progress(path, len(specs), tick_cap) as (on_progress, done):

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
            with warnings_to_stderr():
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
            fail(exc)
    print_results(merged)
    console.print(f"results: {out / 'results.json'}")
