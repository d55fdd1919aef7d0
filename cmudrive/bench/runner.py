"""Run many routes: executors (local processes or Ray), per-route result files, resume, merge.

Layout of an output folder::

    OUT/routes/<route_id>.json   one RouteResult per finished route, written atomically as it finishes
    OUT/results.json             {"summary": {...}, "routes": [...]}, rewritten after every route
    OUT/logs/<route_id>.npz      replayable route logs (with --record)

Every route runs in a fresh worker process (libsumo holds one simulation per process, and a crash of
SUMO or of the agent's native code must not take the run down); the route loop does not know which
executor runs it. ``resume`` skips routes whose record exists and did not crash, and runs the others
again. Ctrl-C stops the run; what finished is on disk.
"""

from __future__ import annotations

import json
import os
import queue
import tempfile
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any, Protocol

from cmudrive.agents.base import Agent, AgentSetupError, load_agent_class
from cmudrive.bench.evaluator import AgentCrash, EvalConfig, evaluate_route
from cmudrive.bench.metrics import route_result, summarize
from cmudrive.bench.records import STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED, RouteResult
from cmudrive.bench.routes import RouteSpec

CRASHED = (STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED)
ROUTES_DIR = "routes"
PROGRESS_EVERY = 20  # ticks between progress messages from a worker


@dataclass(frozen=True)
class RouteTask:
    """Everything a worker needs to run one route (picklable)."""

    spec: RouteSpec
    agent: str  # "package.module:Class"
    config: EvalConfig


def run_task(task: RouteTask, progress: Any = None) -> RouteResult:
    """Run one route in this process; errors before the route starts become a crashed record.
    ``progress`` (a queue) receives ``(route_id, tick)`` every PROGRESS_EVERY ticks."""

    def on_tick(tick: int) -> None:
        if progress is not None and tick % PROGRESS_EVERY == 0:
            progress.put((task.spec.id, tick))

    try:
        agent_cls = load_agent_class(task.agent)
        return evaluate_route(task.spec, agent_cls, task.config, on_tick=on_tick)
    except Exception as exc:
        return crashed_record(task.spec, exc)


def crashed_record(spec: RouteSpec, exc: BaseException) -> RouteResult:
    """The record of a route that could not run: the agent's fault (it cannot be set up, or crashed)
    or anything else (bad route input, a dead worker process)."""
    status = STATUS_AGENT_CRASHED if isinstance(exc, AgentSetupError | AgentCrash) else STATUS_SIM_CRASHED
    result = route_result(
        spec.id,
        spec.town,
        spec.weather,
        spec.scenarios[0].type if spec.scenarios else "",
        [],
        seed=spec.seed,
        num_cavs=len(spec.cavs),
    )
    result.status = status
    result.error = "".join(traceback.format_exception(exc))
    return result


ProgressCallback = Callable[[str, int], None]  # (route_id, ticks done)


class Executor(Protocol):
    """Runs route tasks and yields their results as they finish."""

    def run(
        self, tasks: list[RouteTask], on_progress: ProgressCallback | None = None
    ) -> Iterator[RouteResult]: ...


class LocalExecutor:
    """Worker processes on this machine, a fresh one per route (spawned, so nothing of the parent's state
    leaks in); at most ``workers`` at a time. A worker that dies without a result (segfault, killed) gives
    a crashed record for its route; the others go on."""

    def __init__(self, workers: int = 1) -> None:
        self.workers = max(1, workers)

    def run(
        self, tasks: list[RouteTask], on_progress: ProgressCallback | None = None
    ) -> Iterator[RouteResult]:
        ctx = get_context("spawn")
        messages = ctx.Queue()
        waiting = list(reversed(tasks))
        running: dict[str, tuple[Any, RouteTask]] = {}
        delivered: set[str] = set()
        try:
            while waiting or running:
                while waiting and len(running) < self.workers:
                    task = waiting.pop()
                    proc = ctx.Process(target=_worker, args=(task, messages), daemon=True)
                    proc.start()
                    running[task.spec.id] = (proc, task)
                try:
                    yield from self._handle(messages.get(timeout=0.2), delivered, on_progress)
                except queue.Empty:
                    pass
                for route_id, (proc, task) in list(running.items()):
                    if proc.is_alive():
                        continue
                    proc.join()
                    del running[route_id]
                    for message in _drain(messages):  # its result may still be in the queue
                        yield from self._handle(message, delivered, on_progress)
                    if route_id not in delivered:
                        exc = RuntimeError(
                            f"worker process of route {route_id} died (exit code {proc.exitcode})"
                        )
                        delivered.add(route_id)
                        yield crashed_record(task.spec, exc)
        finally:
            for proc, _ in running.values():
                proc.terminate()

    @staticmethod
    def _handle(
        message: tuple[str, str, Any], delivered: set[str], on_progress: ProgressCallback | None
    ) -> Iterator[RouteResult]:
        kind, route_id, payload = message
        if kind == "progress":
            if on_progress is not None:
                on_progress(route_id, payload)
        elif route_id not in delivered:
            delivered.add(route_id)
            yield RouteResult.from_json(payload)


def _worker(task: RouteTask, messages: Any) -> None:
    """Body of a worker process: run the route, send progress and the result (as JSON-ready data)."""

    class _Progress:
        def put(self, item: tuple[str, int]) -> None:
            messages.put(("progress", item[0], item[1]))

    result = run_task(task, _Progress())
    messages.put(("result", task.spec.id, result.to_json()))


def _drain(messages: Any) -> list[tuple[str, str, Any]]:
    out = []
    while True:
        try:
            out.append(messages.get_nowait())
        except queue.Empty:
            return out


class RayExecutor:
    """Routes as Ray tasks on an existing cluster (``address``) or a local Ray instance."""

    def __init__(self, address: str | None = None, num_cpus_per_route: float = 1.0) -> None:
        try:
            import ray
        except ImportError as exc:
            raise RuntimeError("the Ray executor needs Ray: pip install 'cmudrive[ray]'") from exc
        self.ray = ray
        if not ray.is_initialized():
            if address is None:  # a local instance: keep it on loopback, without the dashboard
                ray.init(_node_ip_address="127.0.0.1", include_dashboard=False, log_to_driver=False)
            else:
                ray.init(address=address, log_to_driver=False)
        self.remote = ray.remote(num_cpus=num_cpus_per_route, max_calls=1)(run_task)

    def run(
        self, tasks: list[RouteTask], on_progress: ProgressCallback | None = None
    ) -> Iterator[RouteResult]:
        ray = self.ray  # per-tick progress is not reported from Ray workers, only finished routes
        refs = {self.remote.remote(t): t for t in tasks}
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            task = refs.pop(done[0])
            try:
                yield ray.get(done[0])
            except Exception as exc:  # the Ray worker died
                yield crashed_record(task.spec, exc)


def write_json_atomic(path: Path, data: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(data, fh, indent=1)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def finished_route_ids(out: Path) -> set[str]:
    """Routes with a record that did not crash (what --resume skips)."""
    done = set()
    for path in (out / ROUTES_DIR).glob("*.json"):
        try:
            data = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        if data.get("status") not in CRASHED:
            done.add(str(data["route_id"]))
    return done


def load_records(out: Path) -> list[RouteResult]:
    records = []
    for path in sorted((out / ROUTES_DIR).glob("*.json")):
        records.append(RouteResult.from_json(json.loads(path.read_text())))
    return records


def merge_results(out: Path, order: list[str], expected: int | None = None) -> dict[str, Any]:
    """Write OUT/results.json from the per-route records, routes in route-file order."""
    records = {r.route_id: r for r in load_records(out)}
    routes = [records[rid] for rid in order if rid in records] + [
        r for rid, r in records.items() if rid not in set(order)
    ]
    merged = {"summary": summarize(routes, expected_routes=expected), "routes": [r.to_json() for r in routes]}
    write_json_atomic(out / "results.json", merged)
    return merged


def run_evaluation(
    routes: list[RouteSpec],
    agent: str | type[Agent],
    out: Path,
    executor: Executor,
    config: EvalConfig | None = None,
    resume: bool = False,
    on_result: Callable[[RouteResult], None] | None = None,
    on_progress: ProgressCallback | None = None,
) -> dict[str, Any]:
    """Evaluate ``routes`` with ``agent`` and return the merged results (also in OUT/results.json)."""
    agent_spec = agent if isinstance(agent, str) else f"{agent.__module__}:{agent.__qualname__}"
    load_agent_class(agent_spec)  # fail fast, before any worker starts
    out.mkdir(parents=True, exist_ok=True)
    config = config or EvalConfig()
    skip = finished_route_ids(out) if resume else set()
    tasks = [RouteTask(spec, agent_spec, config) for spec in routes if spec.id not in skip]
    order = [spec.id for spec in routes]
    for result in executor.run(tasks, on_progress):
        write_json_atomic(out / ROUTES_DIR / f"{_safe(result.route_id)}.json", result.to_json())
        merge_results(out, order, expected=len(routes))
        if on_result is not None:
            on_result(result)
    return merge_results(out, order, expected=len(routes))


def _safe(route_id: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in route_id)


__all__ = [
    "Executor",
    "LocalExecutor",
    "RayExecutor",
    "RouteTask",
    "crashed_record",
    "finished_route_ids",
    "merge_results",
    "run_evaluation",
    "run_task",
]
