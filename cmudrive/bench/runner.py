"""Run many routes: executors (local processes or Ray), per-route result files, resume, merge.

Layout of an output folder::

    OUT/run.json             what produced the folder: the run's setup and each invocation (manifest.py)
    OUT/routes/<stem>.json   one RouteResult per finished route, written atomically as it finishes
    OUT/results.json         {"summary": {...}, "routes": [...], "run": {...}}, rewritten after every route
    OUT/logs/<stem>.npz      replayable route logs (with --record)

``<stem>`` is ``records.record_stem(route_id)``: the id itself when it is short and file-safe, else its
file-safe form cut to 80 characters, ``~`` and a hash of the exact id (ids of any length and characters
work, and no two ids share a file).

Every route runs in a fresh worker process (libsumo holds one simulation per process, and a crash of
SUMO or of the agent's native code must not take the run down); the route loop does not know which
executor runs it. ``resume`` skips routes whose record exists and did not crash, and runs the others
again, with the setup that wrote the folder only (``manifest.py``: each record is stamped with its
setup's hash, its route's and the code version); a new run into a folder that already holds records is
refused (resume it, or use another folder), and results only ever merge the records of the routes of
this run's file. Ctrl-C or SIGTERM (``kill``, a job scheduler) stops the run and its workers; what
finished is on disk. A worker and every process its agent starts end with the route, when the worker is
killed, and when the run ends, SIGKILL of the parent included (``reaper.py``).

**The local executor's watchdog.** A worker tells the parent, through shared memory, which phase it is
in (``setup``: the agent's constructor and ``setup``; ``agent``: ``run_step``; ``sim``: the simulator;
``compile``: numba compiles or loads a kernel, whoever called it, see ``compile_clock``) and since when, and
sends its route's scores every second of simulated time. A worker silent in one phase for longer than that
phase allows (``setup_timeout`` / ``step_timeout`` + ``WATCHDOG_GRACE``, or ``SIM_SILENCE`` in our code) is
killed, which stops an agent stuck in native code that no in-process timeout can interrupt. A killed or dead
worker's route is recorded with the last scores it sent, "Failed - Agent crashed" when the agent's code was
running (hung, ``os._exit``, a segfault in the agent's extension), "Failed - Simulation crashed" otherwise.
"""

from __future__ import annotations

import json
import os
import queue
import resource
import signal
import threading
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any, Protocol

from cmudrive.agents.base import Agent, AgentSetupError, agent_factory, load_agent_class
from cmudrive.bench.compile_clock import COMPILE_PHASE
from cmudrive.bench.evaluator import AgentCrash, EvalConfig, RouteHooks, RouteInputError, evaluate_route
from cmudrive.bench.manifest import read_manifest, run_setup, start_run
from cmudrive.bench.metrics import route_result, route_status, summarize
from cmudrive.bench.reaper import hold_descendants, kill_group, kill_tree
from cmudrive.bench.records import (
    STATUS_AGENT_CRASHED,
    STATUS_INVALID_ROUTE,
    STATUS_RUNNING,
    STATUS_SIM_CRASHED,
    RouteResult,
    record_stem,
    write_json_atomic,
)
from cmudrive.bench.routes import RouteSpec, route_sha256, shift_seeds

CRASHED = (STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED)
RERUN = (*CRASHED, STATUS_INVALID_ROUTE)  # what --resume runs again (an invalid route is checked again)
ROUTES_DIR = "routes"
PROGRESS_EVERY = 20  # ticks between progress messages (and partial scores) from a worker
WATCHDOG_GRACE = 5.0  # [s] added to the agent's time limits before its worker is killed
SIM_SILENCE = 300.0  # [s] our own code silent this long (no tick, no phase change) counts as hung
# the thread counts a worker sets to its share of the cores (a value the user exported wins)
WORKER_THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")
OMP_SPIN_COUNT = 200_000  # spins of an idle libgomp thread before it sleeps (~0.1-1 ms; libgomp's own
# default is 300,000 when no wait policy is set, and without end under OMP_WAIT_POLICY=ACTIVE)
# what a worker is running, as stored in its shared phase slot; "compile": numba compiles or loads a
# kernel; "cleanup": the agent's destroy()
PHASES = ("sim", "setup", "agent", COMPILE_PHASE, "cleanup")


class OutputFolderError(ValueError):
    """The output folder holds records of an earlier run and this run is not a resume."""


class InvalidRoutesError(ValueError):
    """Routes of the run cannot run (bad town, unplannable waypoints, scenario parameters); the message
    lists every one with its problem."""


class RouteJob(Protocol):
    """What a worker runs for one route: ``evaluate_route``'s signature. A job wraps it to do more in the
    worker (``cmudrive.data`` collects a dataset shard); it must pickle (a module-level function, or an
    instance of a module-level class)."""

    def __call__(
        self,
        spec: RouteSpec,
        make_agent: Callable[[], Agent],
        config: EvalConfig,
        hooks: RouteHooks,
    ) -> RouteResult: ...


def check_routes(routes: Sequence[RouteSpec]) -> None:
    """A run needs at least one route and unique route ids (records and shards are named by them)."""
    if not routes:
        raise ValueError("no route to run")
    dup = sorted(i for i, n in Counter(spec.id for spec in routes).items() if n > 1)
    if dup:
        raise ValueError(f"duplicate route ids: {dup}")


@dataclass(frozen=True)
class RouteTask:
    """Everything a worker needs to run one route (picklable)."""

    spec: RouteSpec
    agent: str  # "package.module:Class"
    config: EvalConfig
    max_memory: float | None = None  # [GiB] address-space limit of the worker process (local executor)
    job: RouteJob | None = None  # run instead of evaluate_route (same arguments); None: evaluate


def run_task(task: RouteTask, progress: Any = None, hooks: RouteHooks | None = None) -> RouteResult:
    """Run one route in this process; errors before the route starts become a crashed record.
    ``progress`` (a queue) receives ``(route_id, tick)`` every PROGRESS_EVERY ticks."""
    hooks = hooks or RouteHooks()

    def on_tick(tick: int) -> None:
        if hooks.tick is not None:
            hooks.tick(tick)
        if progress is not None and tick % PROGRESS_EVERY == 0:
            progress.put((task.spec.id, tick))

    try:
        make_agent = agent_factory(load_agent_class(task.agent), task.config.agent_options)
        if task.job is not None:
            return task.job(task.spec, make_agent, task.config, replace(hooks, tick=on_tick))
        return evaluate_route(task.spec, make_agent, task.config, hooks=replace(hooks, tick=on_tick))
    except Exception as exc:
        return crashed_record(task.spec, exc)


def crashed_record(spec: RouteSpec, exc: BaseException) -> RouteResult:
    """The record of a route that could not run: the agent's fault (it cannot be set up, or crashed),
    the route's (bad route input) or anything else (a dead worker process)."""
    if isinstance(exc, AgentSetupError | AgentCrash):
        status = STATUS_AGENT_CRASHED
    else:
        status = STATUS_INVALID_ROUTE if isinstance(exc, RouteInputError) else STATUS_SIM_CRASHED
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
    leaks in); at most ``workers`` at a time, each watched by the parent (module docstring). A worker that
    dies or is killed gives its route a crashed record with the scores it last sent; the others go on."""

    def __init__(self, workers: int = 1) -> None:
        self.workers = max(1, workers)

    def run(
        self, tasks: list[RouteTask], on_progress: ProgressCallback | None = None
    ) -> Iterator[RouteResult]:
        ctx = get_context("spawn")
        messages = ctx.Queue()
        waiting = list(reversed(tasks))
        running: dict[str, _Running] = {}
        delivered: set[str] = set()
        restore = _exit_on_sigterm()
        try:
            while waiting or running:
                while waiting and len(running) < self.workers:
                    task = waiting.pop()
                    beat = ctx.RawArray("d", [time.monotonic(), 0.0, 0.0])  # since when, phase, own group
                    threads = max(1, (os.cpu_count() or 1) // self.workers)
                    args = (task, messages, beat, threads, os.getpid())
                    proc = ctx.Process(target=_worker, args=args, daemon=True)
                    proc.start()
                    running[task.spec.id] = _Running(proc, task, beat)
                try:
                    yield from self._handle(messages.get(timeout=0.2), delivered, running, on_progress)
                except queue.Empty:
                    pass
                for route_id, job in list(running.items()):
                    alive = job.proc.is_alive()  # once: a False reaps the process, its pid is free then
                    verdict = job.hung() if alive else None
                    if alive and verdict is None:
                        continue
                    if verdict is not None:
                        job.kill()
                    job.proc.join()
                    job.kill_group()  # what a worker that died on its own left in its group
                    del running[route_id]
                    for message in _drain(messages):  # its result may still be in the queue
                        yield from self._handle(message, delivered, running, on_progress, job)
                    if route_id not in delivered:
                        delivered.add(route_id)
                        yield job.lost(verdict)
        finally:
            for job in running.values():
                job.kill()
            restore()

    @staticmethod
    def _handle(
        message: tuple[str, str, Any],
        delivered: set[str],
        running: dict[str, _Running],
        on_progress: ProgressCallback | None,
        finished: _Running | None = None,
    ) -> Iterator[RouteResult]:
        kind, route_id, payload = message
        job = running.get(route_id, finished if finished and finished.task.spec.id == route_id else None)
        if kind == "progress":
            if on_progress is not None:
                on_progress(route_id, payload)
        elif kind == "partial":
            if job is not None:
                job.partial = payload
        elif route_id not in delivered:
            delivered.add(route_id)
            yield RouteResult.from_json(payload)


def _exit_on_sigterm() -> Callable[[], None]:
    """Until the returned function is called, SIGTERM (a job scheduler's or ``kill``'s stop) exits this
    process through Python (``SystemExit(143)``), so that the executor's cleanup kills its workers: the
    signal's default action ends the process at once and leaves them running (daemon workers are only
    ended on a normal exit). Only the main thread may set a handler; elsewhere nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def stop(signum: int, frame: object) -> None:
        raise SystemExit(128 + signum)

    previous = signal.signal(signal.SIGTERM, stop)

    def restore() -> None:
        signal.signal(signal.SIGTERM, previous)

    return restore


@dataclass
class _Running:
    """A worker process, its task, its shared heartbeat and the last scores it sent."""

    proc: Any
    task: RouteTask
    beat: Any  # RawArray [monotonic time of the last phase change, index into PHASES, 1.0: leads a group]
    partial: dict[str, Any] | None = None

    def phase(self) -> str:
        return PHASES[int(self.beat[1])]

    def kill(self) -> None:
        """Kill the worker, every process below it and its process group (``bench/reaper.py``)."""
        kill_tree(self.proc.pid)
        self.proc.kill()  # where there is no /proc to find the tree in
        self.kill_group()

    def kill_group(self) -> None:
        if self.beat[2]:  # the worker made the group: its id is the worker's pid
            kill_group(self.proc.pid)

    def hung(self) -> str | None:
        """Why the worker counts as hung now, or None."""
        cfg = self.task.config
        agent_step = cfg.step_timeout + WATCHDOG_GRACE
        limit = {"setup": cfg.setup_timeout + WATCHDOG_GRACE, "agent": agent_step, "cleanup": agent_step}.get(
            self.phase(),
            SIM_SILENCE,  # our code: the simulation and numba's compiler
        )
        silent = time.monotonic() - self.beat[0]
        if silent <= limit:
            return None
        what = {
            "sim": "the simulation",
            "setup": "the agent's setup",
            "agent": "run_step",
            COMPILE_PHASE: "numba's compiler",
            "cleanup": "the agent's destroy()",
        }[self.phase()]
        return f"{what} made no progress for {silent:.0f} s (limit {limit:.0f} s): worker killed"

    def lost(self, verdict: str | None) -> RouteResult:
        """The record of a route whose worker died (``verdict`` None) or was killed as hung. In the
        agent's ``destroy()`` the last scores sent are the route's final record: it stands, the problem
        in ``cleanup_error``."""
        agent_fault = self.phase() in ("setup", "agent", "cleanup")
        status = STATUS_AGENT_CRASHED if agent_fault else STATUS_SIM_CRASHED
        why = verdict or f"worker process died (exit code {self.proc.exitcode})"
        where = {
            "sim": "the simulator (libsumo's step or our world and criteria)",
            COMPILE_PHASE: "numba compiled or loaded a kernel (our code)",
        }.get(self.phase(), "the agent")
        message = f"route {self.task.spec.id}: {why} while {where} ran"
        if self.phase() == "cleanup" and self.partial is not None:
            record = RouteResult.from_json(self.partial)
            record.cleanup_error = message
            return record
        if self.partial is None:
            record = crashed_record(self.task.spec, RuntimeError(message))
            record.status = status
            return record
        record = RouteResult.from_json(self.partial)
        for cav in record.cavs:
            if cav.status == STATUS_RUNNING:
                cav.status = status
        record.status = route_status(record.cavs)
        record.error = message
        return record


def worker_threads(threads: int, environ: Mapping[str, str]) -> dict[str, str]:
    """The thread counts a worker sets (:data:`WORKER_THREAD_VARIABLES`): a variable the user exported is
    kept; the others get the user's ``OMP_NUM_THREADS`` where it is exported, else ``threads`` (the
    worker's share of the cores). One exported ``OMP_NUM_THREADS=1`` thus limits every runtime: torch's
    matrix products run in MKL, which reads ``MKL_NUM_THREADS``; left at the share of 2 beside a second
    busy process, its second thread spun at ~50 % of a core and the sgemm barriers waited for it, and
    a V2V-VLA route took several times as long."""
    share = environ.get("OMP_NUM_THREADS", str(threads))
    return {name: environ.get(name, share) for name in WORKER_THREAD_VARIABLES}


def limit_numba_threads() -> None:
    """Numba read ``NUMBA_NUM_THREADS`` when this module imported it, before a worker could set it: read the
    environment again (numba re-reads it whenever it compiles, and refuses a value other than the one it
    read when its threads started) and run parallel kernels on that many threads (its pool, sized at
    import, keeps the others idle)."""
    import numba

    numba.config.reload_config()
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]  # read from the env


def _worker(task: RouteTask, messages: Any, beat: Any, threads: int = 1, parent: int | None = None) -> None:
    """Body of a worker process: run the route, send progress, partial scores and the result (as
    JSON-ready data), and keep ``beat`` (the phase and since when) current for the parent's watchdog.
    The worker leads its own session and process group and holds every process the route starts, and a
    guard kills them all with it when ``parent`` dies (``bench/reaper.py``); what is left running when
    the route ends is killed.
    ``threads``: this worker's share of the cores, the intra-op thread count of an agent's torch/BLAS
    (set before anything imports them; a value the user exported wins), so that N workers do not each
    start a thread per core. Idle OpenMP threads spin only briefly, then sleep: the camera's numba
    kernels and torch each bring an OpenMP runtime, and threads spinning without end starved each other
    (a V2V-VLA tick with 16 CAVs took 300 ms instead of 80 ms), while threads that sleep at once pay a
    wake-up per parallel region, hundreds per forward pass of a small model: with ``GOMP_SPINCOUNT``
    (libgomp, torch's and numba's runtime on Linux; it takes precedence over the wait policy) at
    OMP_SPIN_COUNT a 16-CAV tick takes 45.9 ms instead of 62.1 ms (``benchmarks/closed_loop.py``). Numba's
    parallel kernels (the camera) take the same share (``NUMBA_NUM_THREADS``): left at one per core, they
    share torch's libgomp and, with every core busy, a 3-CAV V2V-VLA tick took 485 ms instead of 31 ms."""
    if parent is not None:
        beat[2] = float(hold_descendants(parent))  # first: the guard must not inherit the limits below
    os.environ.update(worker_threads(threads, os.environ))
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # other OpenMP runtimes: sleep at once
    os.environ.setdefault("GOMP_SPINCOUNT", str(OMP_SPIN_COUNT))
    limit_numba_threads()  # starts numba's OpenMP runtime: after its settings
    if task.max_memory is not None:
        limit = int(task.max_memory * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    class _Progress:
        def put(self, item: tuple[str, int]) -> None:
            messages.put(("progress", item[0], item[1]))

    def phase(name: str) -> None:
        beat[0], beat[1] = time.monotonic(), float(PHASES.index(name))

    def tick(_: int) -> None:
        beat[0] = time.monotonic()

    def partial(result: RouteResult) -> None:
        messages.put(("partial", task.spec.id, result.to_json()))

    hooks = RouteHooks(tick=tick, phase=phase, partial=partial, partial_every=PROGRESS_EVERY)
    try:
        result = run_task(task, _Progress(), hooks)
        messages.put(("result", task.spec.id, result.to_json()))
    finally:
        kill_tree(os.getpid(), include_root=False)  # what the agent left running, and the guard


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


def record_path(out: Path, route_id: str) -> Path:
    return out / ROUTES_DIR / f"{record_stem(route_id)}.json"


def finished_route_ids(out: Path, route_ids: list[str]) -> set[str]:
    """Routes of ``route_ids`` with a record that did not crash and is not invalid (what --resume
    skips)."""
    return set(_finished(out, route_ids))


def _finished(out: Path, route_ids: list[str]) -> dict[str, RouteResult]:
    return {rid: record for rid, record in _records(out, route_ids).items() if record.status not in RERUN}


def _records(out: Path, route_ids: list[str]) -> dict[str, RouteResult]:
    """The records of these routes found in ``out`` (unreadable ones are left out: they run again)."""
    return load_records(out / ROUTES_DIR, route_ids)


def load_records(folder: Path, route_ids: Iterable[str]) -> dict[str, RouteResult]:
    """The records ``<stem>.json`` of these routes in ``folder`` (unreadable ones are left out)."""
    found = {}
    for rid in route_ids:
        try:
            record = RouteResult.from_json(json.loads((folder / f"{record_stem(rid)}.json").read_text()))
        except (OSError, ValueError, KeyError, TypeError, RecursionError):  # (invalid records included)
            continue
        if record.route_id == rid:
            found[rid] = record
    return found


def merge_results(out: Path, order: list[str], expected: int | None = None) -> dict[str, Any]:
    """Write OUT/results.json from the records of the routes ``order`` (route-file order) and the run
    manifest (``run``: OUT/run.json, None without one); records of other routes in the folder are not
    this run's and are left out."""
    records = _records(out, order)
    routes = [records[rid] for rid in order if rid in records]
    merged = {
        "summary": summarize(routes, expected_routes=expected),
        "routes": [r.to_json() for r in routes],
        "run": read_manifest(out),
    }
    write_json_atomic(out / "results.json", merged)
    return merged


def check_agent(cls: type[Agent], options: dict[str, Any]) -> None:
    """The agent can run with these options: its constructor takes them, its observations declaration
    is valid, and its own ``check_options`` (a checkpoint that loads) passes; AgentSetupError else."""
    agent_factory(cls, options)
    try:
        cls.check_options(options)
    except Exception as exc:
        raise AgentSetupError(f"agent {cls.__name__} cannot run: {exc}") from exc


def _invalid_routes(routes: Sequence[RouteSpec], skip_invalid: bool) -> dict[str, str]:
    """Route id -> problem of the routes that cannot run; InvalidRoutesError listing them all unless
    ``skip_invalid``."""
    from cmudrive.bench.route_check import route_problems

    problems = route_problems(routes)
    if problems and not skip_invalid:
        lines = "\n".join(f"  {problems[spec.id]}" for spec in routes if spec.id in problems)
        raise InvalidRoutesError(
            f"{len(problems)} of {len(routes)} routes cannot run (fix them, or pass --skip-invalid to "
            f"record them as {STATUS_INVALID_ROUTE!r} and run the others):\n{lines}"
        )
    return problems


def run_evaluation(
    routes: list[RouteSpec],
    agent: str | type[Agent],
    out: Path,
    executor: Executor,
    config: EvalConfig | None = None,
    resume: bool = False,
    on_result: Callable[[RouteResult], None] | None = None,
    on_progress: ProgressCallback | None = None,
    max_memory: float | None = None,
    skip_invalid: bool = False,
    seed: int = 0,
    routes_file: Path | None = None,
) -> dict[str, Any]:
    """Evaluate ``routes`` with ``agent`` and return the merged results (also in OUT/results.json).

    Before any route starts, the agent (class, options: ``Agent.check_options``, observations) and every
    route (``route_check.route_problems``) are checked: an agent that cannot run raises
    :class:`AgentSetupError`; invalid routes raise :class:`InvalidRoutesError` listing each, or, with
    ``skip_invalid``, get a "Failed - Invalid route" record and do not run (the summary counts them apart).
    ``seed`` is added to every route's seed (``cmudrive eval --seed``: the same routes with other traffic);
    ``routes_file``, where the routes came from, is recorded in OUT/run.json with its hash. Without
    ``resume``, ``out`` must not hold route records yet (:class:`OutputFolderError`); with it, the run's
    setup must be the one that wrote them (``SetupMismatchError``, ``bench/manifest.py``)."""
    agent_spec = agent if isinstance(agent, str) else f"{agent.__module__}:{agent.__qualname__}"
    config = config or EvalConfig()
    check_agent(load_agent_class(agent_spec), config.agent_options)  # fail fast, before any worker starts
    check_routes(routes)
    ids = [spec.id for spec in routes]
    old = sorted((out / ROUTES_DIR).glob("*.json")) if (out / ROUTES_DIR).is_dir() else []
    if old and not resume:
        raise OutputFolderError(
            f"{out} already holds {len(old)} route records of an earlier run: continue it with --resume, "
            "or write to another --out folder"
        )
    if max_memory is not None and not max_memory > 0.0:
        raise ValueError(f"max_memory must be a positive number of GiB, got {max_memory}")
    invalid = _invalid_routes(routes, skip_invalid)  # every route checked before the first one runs
    setup = run_setup("eval", agent_spec, config, seed=seed, max_memory=max_memory)
    hashes = {spec.id: route_sha256(spec) for spec in routes}
    kept = _finished(out, ids) if resume else {}
    settings = {"executor": type(executor).__name__, "workers": getattr(executor, "workers", None)}
    run = start_run(out, setup, hashes, resume, kept, len(old), settings, routes_file)
    specs = [s for s in shift_seeds(routes, seed) if s.id not in kept]
    for spec in specs:
        if spec.id in invalid:
            record = crashed_record(spec, RouteInputError(invalid[spec.id]))
            record.error = invalid[spec.id]  # the problem, no traceback: nothing ran
            record.provenance = run.stamp(hashes[spec.id])
            write_json_atomic(record_path(out, spec.id), record.to_json())
            if on_result is not None:
                on_result(record)
    tasks = [RouteTask(spec, agent_spec, config, max_memory) for spec in specs if spec.id not in invalid]
    for result in executor.run(tasks, on_progress):
        result.provenance = run.stamp(hashes[result.route_id])
        write_json_atomic(record_path(out, result.route_id), result.to_json())
        merge_results(out, ids, expected=len(routes))
        if on_result is not None:
            on_result(result)
    return merge_results(out, ids, expected=len(routes))


__all__ = [
    "Executor",
    "InvalidRoutesError",
    "LocalExecutor",
    "OutputFolderError",
    "RayExecutor",
    "RouteJob",
    "RouteTask",
    "check_agent",
    "check_routes",
    "crashed_record",
    "finished_route_ids",
    "load_records",
    "merge_results",
    "run_evaluation",
    "run_task",
]
