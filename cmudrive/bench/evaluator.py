"""The closed loop of one route: world, agent, criteria, tick after tick, until every CAV has finished.

``evaluate_route`` never raises for what goes wrong *inside* a route: an agent that raises (SystemExit
and KeyboardInterrupt too, in its constructor, ``setup`` or ``run_step``), hangs past the per-step
timeout or hands over controls that are not one finite number per active CAV (strings, the wrong shape,
NaN: checked right after ``run_step`` returns, before the scenarios' perturbation or the world touch
them, the message naming the control, the tick and the CAV) ends the route as "Failed - Agent crashed";
an error of the simulation (ours, after that check) ends it as "Failed - Simulation crashed"; both keep
the traceback in ``RouteResult.error`` and the scores the CAVs had reached.

The agent's ``destroy()`` runs under the same time limit as ``run_step``, after the route's scores are
final (and, in a runner's worker, sent to the parent first). When it raises or overruns, the route keeps
its result, statuses included: the clean-up is no part of the drive, so no CAV is marked crashed for it;
the problem is kept in ``RouteResult.cleanup_error`` (not ``error``: the route is not counted crashed).

What is wrong *before* the route starts (unknown town, routes that cannot be planned, scenario
parameters, an agent that cannot be imported or needs observations we do not provide) is an error of
the input and is raised with the route id in the message; the runner checks every route before the first
one starts (``route_check``) and refuses the run or records the route as "Failed - Invalid route".
"""

from __future__ import annotations

import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from cmudrive.agents.base import (
    PROVIDED,
    Agent,
    Observation,
    Observations,
    RouteSetup,
    check_observations,
    sparse_plan,
)
from cmudrive.bench.callbacks import RouteCallback, RouteStart, Step
from cmudrive.bench.compile_clock import CompileClock
from cmudrive.bench.criteria import CriteriaConfig, RouteCriteria
from cmudrive.bench.metrics import comfort_score, route_result
from cmudrive.bench.observe import ObservationBuilder, SensorConfig
from cmudrive.bench.recording import LogRecorder
from cmudrive.bench.records import (
    STATUS_AGENT_CRASHED,
    STATUS_SIM_CRASHED,
    STATUS_TICK_CAP,
    RouteResult,
)
from cmudrive.bench.route_actors import RouteActors
from cmudrive.bench.routes import RouteSpec
from cmudrive.bench.scenarios import ScenarioConfig, ScenarioError, ScenarioManager, build_scenarios
from cmudrive.maps import MapError, RoadMap, Route, load_map, load_scenery
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.dynamics import ControlError, Controls, check_controls
from cmudrive.sim.populated import populated_world
from cmudrive.sim.snapshot import Snapshot
from cmudrive.sim.world import World, WorldConfig

DT = 0.05  # [s]


class AgentCrash(RuntimeError):
    """The agent raised, returned unusable controls or exceeded the per-step time limit."""


class RouteInputError(ValueError):
    """The route cannot be run at all (bad town, unplannable waypoints); the message names the route."""


@dataclass(frozen=True)
class EvalConfig:
    tick_cap: int = 4000  # Bench2Drive: 4000 ticks = 200 s of simulated time
    step_timeout: float = 10.0  # [s] wall clock per run_step call before the agent counts as hung
    setup_timeout: float = 600.0  # [s] wall clock for the agent's setup (loading a model may take long)
    background: BackgroundConfig = field(default_factory=BackgroundConfig)
    criteria: CriteriaConfig = field(default_factory=CriteriaConfig)
    sensors: SensorConfig = field(default_factory=SensorConfig)
    scenarios: ScenarioConfig = field(default_factory=ScenarioConfig)
    record_dir: Path | None = None  # write a replayable log per route here
    # keyword arguments of the agent's constructor, e.g. {"checkpoint": "runs/a/model"} (--checkpoint)
    agent_options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.tick_cap < 1:
            raise ValueError(f"tick_cap must be >= 1 tick, got {self.tick_cap}")
        for name in ("step_timeout", "setup_timeout"):  # 0 would silently switch the time limit off
            value = getattr(self, name)
            if not value > 0.0 or not np.isfinite(value):
                raise ValueError(f"{name} must be a positive number of seconds, got {value}")


def route_background(spec: RouteSpec, background: BackgroundConfig) -> BackgroundConfig:
    """The background of one route: the evaluator's, with the route's own vehicle and pedestrian targets
    where it gives them (an imported InterDrive route runs with none, as its source does)."""
    if spec.background is None:
        return background
    return replace(background, vehicles=spec.background.vehicles, pedestrians=spec.background.pedestrians)


def plan_cav_routes(spec: RouteSpec, road_map: RoadMap) -> list[Route]:
    try:
        return spec.dense_routes(road_map)
    except MapError as exc:
        raise RouteInputError(str(exc)) from exc


@dataclass
class RouteHooks:
    """What a caller (the runner's worker) hears of a running route.

    ``tick(t)`` after every tick; ``phase(name)`` when the route enters ``"setup"`` (the agent's
    constructor or ``setup`` runs), ``"agent"`` (its ``run_step`` runs), ``"cleanup"`` (its ``destroy``
    runs) or ``"sim"`` (our code runs), so that a watchdog outside the process can tell a hung or dead
    agent from a crashed simulation; ``partial(result)`` every ``partial_every`` ticks with the scores so
    far, and once with the final record before ``destroy``, so that a route whose process dies keeps
    them."""

    tick: Callable[[int], None] | None = None
    phase: Callable[[str], None] | None = None
    partial: Callable[[RouteResult], None] | None = None
    partial_every: int = 20  # [ticks]
    current: str = field(default="sim", init=False)  # the phase entered last

    def enter(self, name: str) -> None:
        self.current = name
        if self.phase is not None:
            self.phase(name)


def evaluate_route(
    spec: RouteSpec,
    make_agent: Callable[[], Agent],
    config: EvalConfig | None = None,
    hooks: RouteHooks | None = None,
    callbacks: Sequence[RouteCallback] = (),
) -> RouteResult:
    """Run one route to the end and score it (see the module docstring for what is raised). Time that
    numba spends compiling or loading kernels is not charged to the agent (``compile_clock``).
    ``callbacks`` watch the route (:mod:`cmudrive.bench.callbacks`)."""
    config = config or EvalConfig()
    hooks = hooks or RouteHooks()
    if config.record_dir is not None:  # the replay log (--record) is a callback too
        callbacks = (LogRecorder(config.record_dir), *callbacks)
    if hooks.partial is not None:  # and so are the partial scores (first: before any other can fail)
        callbacks = (_PartialScores(hooks.partial, hooks.partial_every), *callbacks)
    with CompileClock(hooks.enter, lambda: hooks.current):
        return _run_route(spec, make_agent, config, hooks, tuple(callbacks))


def _run_route(
    spec: RouteSpec,
    make_agent: Callable[[], Agent],
    config: EvalConfig,
    hooks: RouteHooks,
    callbacks: tuple[RouteCallback, ...],
) -> RouteResult:
    started = time.perf_counter()
    try:
        town_path = spec.town_path()
        road_map = load_map(town_path)
    except MapError as exc:
        raise RouteInputError(str(exc) if spec.id in str(exc) else f"route {spec.id}: {exc}") from exc
    routes = plan_cav_routes(spec, road_map)
    hooks.enter("setup")
    try:
        agent = make_agent()
    except BaseException as exc:  # SystemExit and KeyboardInterrupt from agent code are its crash too
        raise AgentCrash(f"the agent's constructor raised: {exc!r}") from exc
    hooks.enter("sim")
    declared = check_observations(agent)
    privileged = Observation.PRIVILEGED in declared
    world_config = WorldConfig(town=str(town_path), seed=spec.seed, weather=spec.weather)
    with populated_world(world_config, road_map, routes, route_background(spec, config.background)) as world:
        cav_ids = list(world.cav_ids)
        if spec.lights == "off":  # before the first tick: the route never sees a signal
            world.lights.switch_off()
        scenery = load_scenery(road_map)  # what CAVs can hit and what hides actors from cameras
        criteria = RouteCriteria(road_map, routes, cav_ids, config.criteria, DT, scenery=scenery)
        try:
            scenarios = build_scenarios(spec, world, road_map, routes, criteria, config.scenarios)
        except ScenarioError as exc:
            _destroy(agent, config.step_timeout, hooks)
            raise RouteInputError(str(exc)) from exc
        actors = RouteActors(spec, world)  # the route's own actors, apart from the scenarios
        observer = ObservationBuilder(
            declared,
            len(routes),
            world.weather,
            scenery,
            config=config.sensors,
            rng=np.random.default_rng([spec.seed, 1]),  # sensors' own stream: traffic is unchanged
            road_map=road_map,
        )
        loop = _Loop(world, criteria, agent, observer, config, hooks, spec, scenarios, actors, callbacks)
        try:
            setups = (
                _setup(spec, road_map, routes, cav_ids, privileged),
                _setup(spec, road_map, routes, cav_ids, True),  # what callbacks see
            )
            error = _drive(loop, scenarios, criteria, *setups)
            result = _final_result(spec, routes, loop, error)
            for callback in callbacks:
                callback.on_route_end(result)
        finally:
            cleanup_error = _destroy(agent, config.step_timeout, hooks)
    result.cleanup_error = cleanup_error
    result.wall_time = time.perf_counter() - started
    return result


class _PartialScores(RouteCallback):
    """``RouteHooks.partial`` as a callback: the scores so far every ``every`` ticks, and the final record
    at the end, before the agent's ``destroy`` (a ``destroy()`` hung past the watchdog keeps them)."""

    def __init__(self, send: Callable[[RouteResult], None], every: int) -> None:
        self.send, self.every = send, every

    def on_step(self, step: Step) -> None:
        if (step.tick + 1) % self.every == 0:
            self.send(step.scores())

    def on_route_end(self, result: RouteResult) -> None:
        self.send(result)


def _drive(
    loop: _Loop,
    scenarios: ScenarioManager,
    criteria: RouteCriteria,
    setup: RouteSetup,
    privileged_setup: RouteSetup,
) -> str | None:
    """The callbacks' start, the agent's setup and the route's ticks; the traceback when the agent or the
    simulation (a callback included) crashed (the CAVs still running get that status), else None."""
    try:
        for callback in loop.callbacks:
            callback.on_route_start(RouteStart(loop.spec, privileged_setup, loop.agent))
        loop.setup(setup)
        loop.run()
        scenarios.finish()  # scenario actors leave, blocked tests resume (before the world closes)
    except AgentCrash:
        criteria.end_route(STATUS_AGENT_CRASHED)
        return traceback.format_exc()
    except Exception:  # the simulation failed: keep what was scored, record the traceback
        criteria.end_route(STATUS_SIM_CRASHED)
        return traceback.format_exc()
    return None


def _final_result(spec: RouteSpec, routes: list[Route], loop: _Loop, error: str | None) -> RouteResult:
    """The route's record once its ticks are done (comfort and first-junction shares added)."""
    cavs = loop.criteria.results()
    for i, cav in enumerate(cavs):
        cav.comfort = comfort_score(*loop.kinematics(i))
        cav.first_junction_completion = first_junction_completion(routes[i])
    scenario = spec.scenarios[0].type if spec.scenarios else ""
    result = route_result(spec.id, spec.town, spec.weather, scenario, cavs, seed=spec.seed)
    result.ticks = loop.world.step_count
    result.error = error
    result.scenario_simulated = loop.scenarios.simulated  # None without scenarios
    if loop.observer.link_stats is not None:
        result.v2v = loop.observer.link_stats.to_json()
    return result


JUNCTION_MARGIN = 9  # [route points] Bench2Drive counts a junction passed 9 points after its first point


def first_junction_completion(route: Route) -> float | None:
    """Route completion [%] at which the route has passed its first junction (Bench2Drive's Traffic_Signs
    rule: the first in-junction point + 9 points, its loop's last index), None without a junction."""
    hits = np.flatnonzero(route.in_junction)
    if len(hits) == 0:
        return None
    return 100.0 * min(int(hits[0]) + JUNCTION_MARGIN, len(route)) / len(route)


def _setup(
    spec: RouteSpec, road_map: RoadMap, routes: list[Route], cav_ids: list[str], privileged: bool
) -> RouteSetup:
    return RouteSetup(
        route_id=spec.id,
        town=spec.town,
        weather=spec.weather,
        dt=DT,
        cavs=tuple(sparse_plan(cid, r, privileged) for cid, r in zip(cav_ids, routes, strict=True)),
        road_map=road_map if privileged else None,
    )


def _destroy(agent: Agent, timeout: float, hooks: RouteHooks) -> str | None:
    """The agent's ``destroy()`` under ``run_step``'s time limit (phase ``"cleanup"`` for the runner's
    watchdog); what went wrong, or None. A failing clean-up never hides the route's result."""
    hooks.enter("cleanup")
    problem: str | None = None
    try:
        with _time_limit(timeout):
            agent.destroy()
    except _StepTimeout:
        problem = f"the agent's destroy() took longer than {timeout:.1f} s and was interrupted"
    except BaseException as exc:  # SystemExit and KeyboardInterrupt from agent code too
        problem = f"the agent's destroy() raised: {''.join(traceback.format_exception(exc))}"
    hooks.enter("sim")
    if problem is not None:
        print(f"route result kept; {problem}", file=sys.stderr)
    return problem


class _Loop:
    """The tick loop of one route, and the CAV kinematics it keeps for the comfort metric."""

    def __init__(
        self,
        world: World,
        criteria: RouteCriteria,
        agent: Agent,
        observer: ObservationBuilder,
        config: EvalConfig,
        hooks: RouteHooks,
        spec: RouteSpec,
        scenarios: ScenarioManager | None = None,
        actors: RouteActors | None = None,
        callbacks: tuple[RouteCallback, ...] = (),
    ) -> None:
        self.world, self.criteria, self.agent = world, criteria, agent
        self.callbacks = callbacks
        self.scenarios = scenarios or ScenarioManager([], [], [])
        self.actors = actors
        self.observer, self.config = observer, config
        self.privileged = Observation.PRIVILEGED in observer.declared
        self.asks_partners = observer.network is not None
        self.requested: np.ndarray | None = None  # partners the agent named at the last tick
        self.hooks, self.spec = hooks, spec
        n = len(world.cav_ids)
        self.trace = np.full((config.tick_cap + 1, n, 4), np.nan)  # x, y, yaw, speed per tick and CAV

    def setup(self, setup: RouteSetup) -> None:
        """The agent's ``setup``: anything it raises (SystemExit and KeyboardInterrupt too) is its crash."""
        self.hooks.enter("setup")
        try:
            with _time_limit(self.config.setup_timeout):
                self.agent.setup(setup)
        except _StepTimeout as exc:
            raise AgentCrash(f"setup took longer than {self.config.setup_timeout:.1f} s") from exc
        except BaseException as exc:
            raise AgentCrash(f"setup raised: {exc!r}") from exc
        self.hooks.enter("sim")

    def partial(self) -> RouteResult:
        """The route's scores so far (comfort and the first-junction share are left for the end)."""
        s = self.spec
        scenario = s.scenarios[0].type if s.scenarios else ""
        result = route_result(s.id, s.town, s.weather, scenario, self.criteria.results(), seed=s.seed)
        result.ticks = self.world.step_count
        result.scenario_simulated = self.scenarios.simulated  # as in the final record
        return result

    def run(self) -> None:
        world, criteria, hooks = self.world, self.criteria, self.hooks
        snap = world.snapshot()
        for tick in range(self.config.tick_cap):
            rows, index = _active_cavs(snap, world)
            controls, obs = self._agent_step(snap, tick, rows, index)
            self.scenarios.update(snap)  # scripted actors move before the world ticks
            if self.actors is not None:
                self.actors.update(DT)  # and so do the route's own actors
            applied = self.scenarios.perturb(controls, index)  # ControlLoss noise on the CAVs' controls
            seen, snap = (
                snap,
                world.tick(applied),
            )  # the agent's controls were checked: a ControlError is ours
            self._trace(snap, tick + 1)
            criteria.update(snap, world.collisions)
            step = Step(
                tick, obs.time, seen, rows, index, obs, controls, self.agent, applied, snap, self.partial
            )
            for callback in self.callbacks:
                callback.on_step(step)
            for i in np.flatnonzero(criteria.newly_finished()):
                world.remove_cav(int(i))
            if hooks.tick is not None:
                hooks.tick(tick + 1)
            if criteria.finished().all():
                return
        criteria.end_route(STATUS_TICK_CAP)

    def _agent_step(
        self, snap: Snapshot, tick: int, rows: np.ndarray, index: np.ndarray
    ) -> tuple[Controls, Observations]:
        obs = self.observer.build(snap, tick, rows, index, self.privileged, self._requested_for(index))
        self.hooks.enter("agent")
        try:
            with _time_limit(self.config.step_timeout):
                controls = self.agent.run_step(obs)
                requested = self.agent.next_partners() if self.asks_partners else None
        except _StepTimeout as exc:
            raise AgentCrash(
                f"run_step took longer than {self.config.step_timeout:.1f} s at tick {tick}"
            ) from exc
        except BaseException as exc:  # SystemExit and KeyboardInterrupt from agent code are its crash too
            raise AgentCrash(f"run_step raised at tick {tick}: {exc!r}") from exc
        self.hooks.enter("sim")
        if not isinstance(controls, Controls):
            raise AgentCrash(f"run_step returned {type(controls).__name__}, not Controls, at tick {tick}")
        try:  # before the scenarios or the world touch them: what fails later is ours
            controls = check_controls(controls, [self.world.cav_ids[i] for i in index])
        except ControlError as exc:
            raise AgentCrash(f"run_step returned unusable controls at tick {tick}: {exc}") from exc
        self.requested = self._check_partners(requested, index, tick)
        return controls, obs

    def _check_partners(self, requested: object, index: np.ndarray, tick: int) -> np.ndarray | None:
        """The agent's named partners as a full (K,) table by CAV index (-1: default), or None."""
        if requested is None:
            return None
        named = np.asarray(requested)
        if named.shape != index.shape or not np.issubdtype(named.dtype, np.integer):
            raise AgentCrash(
                f"next_partners returned {named.dtype} of shape {named.shape} at tick {tick}; "
                f"expected integer CAV indices of shape {index.shape}"
            )
        table = np.full(len(self.world.cav_ids), -1, np.int64)
        table[index] = named
        return table

    def _requested_for(self, index: np.ndarray) -> np.ndarray | None:
        return None if self.requested is None else self.requested[index]

    def _trace(self, snap: Snapshot, tick: int) -> None:
        rows, index = _active_cavs(snap, self.world)
        self.trace[tick, index] = np.stack(
            [snap.x[rows], snap.y[rows], snap.yaw[rows], snap.speed[rows]], axis=1
        )

    def kinematics(self, cav: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(t, x, y, yaw, speed) of one CAV over the ticks it was in the world."""
        rows = np.flatnonzero(~np.isnan(self.trace[:, cav, 0]))
        x, y, yaw, v = self.trace[rows, cav].T
        return rows * DT, x, y, np.unwrap(yaw), v


def _active_cavs(snap: Snapshot, world: World) -> tuple[np.ndarray, np.ndarray]:
    """Snapshot rows of the CAVs still in the world, and their CAV indices ("cav3" -> 3). CAVs that finished
    in the last tick are still in ``snap`` (taken before they left) and are dropped here."""
    rows, index = snap.cav_rows()
    keep = world.cav_active[index]
    return rows[keep], index[keep]


class _StepTimeout(BaseException):
    """Raised into the agent's code when it overruns: a BaseException, so that the agent's own
    ``except Exception`` cannot swallow it (a hang in native code never sees it: the runner's parent
    process watches for that)."""


@contextmanager
def _time_limit(seconds: float) -> Iterator[None]:
    """Interrupt the block after ``seconds`` of wall time (SIGALRM; only in a process's main thread,
    elsewhere the block runs unguarded)."""
    if seconds <= 0 or threading.current_thread() is not threading.main_thread():
        yield
        return

    def fire(signum: int, frame: object) -> None:
        raise _StepTimeout

    previous = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)


__all__ = [
    "PROVIDED",
    "AgentCrash",
    "EvalConfig",
    "RouteHooks",
    "RouteInputError",
    "evaluate_route",
    "plan_cav_routes",
    "route_background",
]
