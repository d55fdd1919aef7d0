"""Collect a dataset: an agent drives many routes, the expert labels, one Parquet shard per route
(``cmudrive data collect``).

Routes run through the benchmark's own runner (``cmudrive.bench.runner``: a fresh worker process per route
with the watchdog, or Ray tasks); in each worker a :class:`ShardJob` runs the ordinary route loop with the
driving agent (the expert by default; ``--driver v2v-vla --checkpoint DIR`` for closed-loop data) and a
:class:`~cmudrive.data.collector.RowCollector` callback, which renames the route's shard into place when
the route has run to its end. A route that crashes (the simulation, the driver or the expert raised, the
worker died) leaves no shard, only its record in ``DIR/.routes/`` with the error, and the other routes go
on; ``resume`` runs exactly the routes without a complete shard. A driver's collision or time-out is no
crash: the route has run, and its rows are kept.

Training data must not come from the benchmark: :func:`check_not_benchmark` refuses routes whose id or
scenario place is one of ``cmudrive220``'s (``cmudrive44`` is a subset of it) unless told otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import pyarrow as pa

from cmudrive.agents.base import BUNDLED_AGENTS, Agent
from cmudrive.agents.expert import ExpertAgent
from cmudrive.bench.evaluator import EvalConfig, RouteHooks, evaluate_route
from cmudrive.bench.manifest import run_setup, start_run
from cmudrive.bench.observe import SensorConfig
from cmudrive.bench.records import STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED, RouteResult, record_stem
from cmudrive.bench.routes import RouteSpec, read_routes, route_sha256
from cmudrive.bench.runner import (
    Executor,
    ProgressCallback,
    RouteTask,
    check_routes,
    load_records,
    write_json_atomic,
)
from cmudrive.data.collector import SAMPLE_EVERY, RouteInfo, RowCollector
from cmudrive.data.recovery import RecoveryViews
from cmudrive.data.schema import EXPERT_DRIVER, features
from cmudrive.data.shards import MANIFEST, RECORDS_DIR, ShardWriter, shard_complete, shard_path

EXPERT = BUNDLED_AGENTS["expert"]
BUNDLED = {path: name for name, path in BUNDLED_AGENTS.items()}  # class path -> short name
BENCHMARK_SETS = ("cmudrive220",)  # cmudrive44's routes are cmudrive220 routes
SAME_PLACE = 30.0  # [m] scenario triggers of one type closer than this are one place (the generator's rule)
CRASHED = (STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED)


class BenchmarkRouteError(ValueError):
    """A route to collect on is one of the benchmark's (by id or by scenario place)."""


@dataclass(frozen=True)
class ShardJob:
    """Runs one route with the row collector in a worker and writes its shard (a ``RouteJob``)."""

    out: str
    schema: pa.Schema  # features(sensors.occupancy).arrow_schema, built where datasets is imported
    sample_every: int = SAMPLE_EVERY
    sensors: SensorConfig = field(default_factory=SensorConfig)
    recovery: RecoveryViews = field(default_factory=RecoveryViews)
    driver: str = EXPERT  # the driving agent's class path (the task's agent); not the expert: it labels

    def __call__(
        self,
        spec: RouteSpec,
        make_agent: Callable[[], Agent],
        config: EvalConfig,
        hooks: RouteHooks,
    ) -> RouteResult:
        info = RouteInfo(
            route_id=spec.id,
            scenario_type=spec.scenarios[0].type if spec.scenarios else "",
            weather=spec.weather,
            town=spec.town,
            num_cavs=len(spec.cavs),
        )
        writer = ShardWriter(Path(self.out), spec.id, self.schema)
        closed_loop = self.driver != EXPERT
        collector = RowCollector(
            info,
            writer,
            self.sample_every,
            self.sensors,
            spec.seed,
            self.recovery,
            labeller=ExpertAgent() if closed_loop else None,
            driver=BUNDLED.get(self.driver, self.driver) if closed_loop else EXPERT_DRIVER,
        )
        try:
            return evaluate_route(spec, make_agent, config, hooks=hooks, callbacks=[collector])
        except BaseException:
            writer.abort()
            raise


def check_not_benchmark(specs: Sequence[RouteSpec], benchmark: Sequence[RouteSpec] | None = None) -> None:
    """Raise :class:`BenchmarkRouteError` naming every route of ``specs`` whose id is a benchmark route's,
    or whose scenario lies within SAME_PLACE of a benchmark scenario of the same type in the same town."""
    if benchmark is None:
        bench_dir = Path(__file__).resolve().parents[1] / "assets" / "routes"
        benchmark = [s for name in BENCHMARK_SETS for s in read_routes(bench_dir / f"{name}.xml")]
    ids = {s.id for s in benchmark}
    places: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for s in benchmark:
        for sc in s.scenarios:
            x, y, _ = sc.map_trigger()
            places.setdefault((s.town, sc.type), []).append((x, y))
    bad = []
    for s in specs:
        if s.id in ids:
            bad.append(f"{s.id} (a benchmark route id)")
            continue
        for sc in s.scenarios:
            x, y, _ = sc.map_trigger()
            near = [
                p for p in places.get((s.town, sc.type), []) if math.hypot(x - p[0], y - p[1]) < SAME_PLACE
            ]
            if near:
                bad.append(f"{s.id} ({sc.type} at a benchmark place in {s.town})")
                break
    if bad:
        shown = ", ".join(bad[:10]) + (f" and {len(bad) - 10} more" if len(bad) > 10 else "")
        raise BenchmarkRouteError(
            f"{len(bad)} route(s) are benchmark routes, never training data: {shown} "
            "(--allow-benchmark-routes overrides this)"
        )


@dataclass
class CollectSummary:
    written: list[str] = field(default_factory=list)  # route ids whose shard was written by this run
    skipped: list[str] = field(default_factory=list)  # complete shards found (resume)
    failed: dict[str, str] = field(default_factory=dict)  # route id -> the error's last line


def collect(
    routes: Sequence[RouteSpec],
    out: Path,
    executor: Executor,
    config: EvalConfig | None = None,
    resume: bool = False,
    allow_benchmark: bool = False,
    sample_every: int = SAMPLE_EVERY,
    on_result: Callable[[RouteResult, bool], None] | None = None,
    on_progress: ProgressCallback | None = None,
    routes_file: Path | None = None,
    recovery: RecoveryViews | None = None,
    driver: str = "expert",
) -> CollectSummary:
    """Collect shards for ``routes`` into ``out`` (module docstring). ``on_result(record, shard_written)``
    hears of every route as it finishes. Without ``resume``, ``out`` must hold no shard yet; with it, the
    setup must be the one that wrote them (``OUT/.run.json``, ``bench/manifest.py``); ``routes_file``,
    where the routes came from, is recorded there. ``driver``: the agent that drives (a bundled name or
    ``package.module:Class``, its constructor's keywords in ``config.agent_options``); other than the
    expert, the expert labels the states it reaches (closed-loop data, docs/data.md)."""
    check_routes(routes)
    driver = BUNDLED_AGENTS.get(driver, driver)
    ids = [spec.id for spec in routes]
    if not allow_benchmark:
        check_not_benchmark(routes)
    out = Path(out)
    done = {s.id for s in routes if shard_complete(shard_path(out, s.id))}
    if done and not resume:
        raise FileExistsError(
            f"{out} already holds {len(done)} shard(s) of these routes: continue with --resume, "
            "or write to another folder"
        )
    config = config or EvalConfig()
    recovery = recovery or RecoveryViews()
    job_settings: dict[str, object] = {"sample_every": sample_every}
    if recovery.prob > 0.0:  # a run without views keeps the setup (and resumability) of older runs
        job_settings["recovery_views"] = asdict(recovery)
    setup = run_setup("collect", driver, config, job=job_settings)
    hashes = {spec.id: route_sha256(spec) for spec in routes}
    kept = load_records(out / RECORDS_DIR, done)
    settings = {"executor": type(executor).__name__, "workers": getattr(executor, "workers", None)}
    run = start_run(out, setup, hashes, resume, kept, len(done), settings, routes_file, MANIFEST)
    schema = features(config.sensors.occupancy).arrow_schema
    job = ShardJob(str(out.resolve()), schema, sample_every, config.sensors, recovery, driver)
    tasks = [RouteTask(s, driver, config, job=job) for s in routes if s.id not in done]
    summary = CollectSummary(skipped=[i for i in ids if i in done])
    for result in executor.run(tasks, on_progress):
        result.provenance = run.stamp(hashes[result.route_id])
        write_json_atomic(out / RECORDS_DIR / f"{record_stem(result.route_id)}.json", result.to_json())
        written = shard_complete(shard_path(out, result.route_id))
        if written:
            summary.written.append(result.route_id)
        else:
            summary.failed[result.route_id] = _last_line(result.error) or result.status
        if on_result is not None:
            on_result(result, written)
    return summary


def _last_line(error: str | None) -> str:
    lines = (error or "").strip().splitlines()
    return lines[-1] if lines else ""


__all__ = [
    "BenchmarkRouteError",
    "CollectSummary",
    "ShardJob",
    "check_not_benchmark",
    "collect",
]
