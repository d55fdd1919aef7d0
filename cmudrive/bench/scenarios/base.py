"""The scenario life cycle shared by every type: instantiate, activate, update, end, time out.

A :class:`Scenario` is built at route setup from its ``<scenario>`` element (parameters parsed and checked,
trigger point located on CAV 0's route, actors placed: errors name the route, scenario and parameter).
Then, once per tick *before* the world ticks, :meth:`Scenario.step`:

1. **instantiate** once CAV 0 is within ``instantiation_distance`` of the trigger along its route
   (the "present from instantiation" actors appear: :meth:`Scenario.on_instantiate`);
2. **activate** once CAV 0's matched route point is within ``activation_distance`` (2 m) of the trigger
   (:meth:`Scenario.on_activate`); the blocked test of every *affected* CAV is suspended while the
   scenario's timeout runs (the reference's ST240);
3. **update** every tick (:meth:`Scenario.on_update` returns True when the scenario's own end holds);
4. **end**, by its own condition or by the timeout: on timeout CAV 0, if it is still running and has
   not passed the scenario, gets ``scenario_timeouts``; then :meth:`Scenario.on_end` cleans up (the
   actors this scenario spawned are removed) and the blocked tests resume.

**CAV 0 is the scenario's ego**, as the one ego of Bench2Drive's scenarios: activation, the triggers of
the behaviour (TTA and distance triggers, ``behaviours.py``), whom a cut-in or an emergency vehicle acts
on, the end condition (:meth:`Scenario.ego_passed`) and the scenario-scoped criteria (scenario timeout,
yield to the emergency vehicle) all follow CAV 0 alone. A CAV that is not CAV 0 never releases an
adversary early and never holds the actors in the world after CAV 0 is done with them.

*Affected* CAVs are those whose route passes within ``affected_distance`` of the trigger point (CAV 0
always): they meet the same obstacle, so the scenario suspends their blocked test while it runs and lets
them use the opposite lane where it lets CAV 0 (the TwoWays obstacles). Every CAV is scored by the usual
route criteria: collisions with scenario actors included, with no scenario involved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import ClassVar

import numpy as np

from cmudrive.bench.criteria import RouteCriteria
from cmudrive.bench.route_spec import TRIGGER_TOLERANCE, ScenarioSpec
from cmudrive.bench.scenarios.params import Param, ScenarioError, parse_params
from cmudrive.bench.scenarios.placement import LanePoint, heading, point_xy, walk
from cmudrive.bench.scenarios.plan import PlanItem, point
from cmudrive.maps import RoadMap, Route
from cmudrive.maps.model import LaneKind
from cmudrive.sim.background_commands import BackgroundCommands
from cmudrive.sim.dynamics import Controls
from cmudrive.sim.snapshot import Role, Snapshot
from cmudrive.sim.world import World

EGO = 0  # the scenario's ego: CAV 0, whose route holds the trigger point
PROGRESS_WINDOW = 30  # [route points] searched ahead of a CAV's last matched point per tick
JUNCTION_SEARCH = 150.0  # [m] along CAV 0's route past T where the junction of a junction type must lie


@dataclass(frozen=True)
class ScenarioConfig:
    """Engine constants (``reference/SCENARIOS.md``, "Scenario life cycle")."""

    timeout: float = 240.0  # [s] ST240: the scenario's own timeout from activation
    # [m] CAV 0's matched route point this close to T activates it (the route file's trigger tolerance)
    activation_distance: float = TRIGGER_TOLERANCE
    instantiation_distance: float = 500.0  # [m] along CAV 0's route before T: present actors appear
    affected_distance: float = 2.0  # [m] a route this close to T makes its CAV an affected one

    def __post_init__(self) -> None:
        for name in ("timeout", "activation_distance", "instantiation_distance", "affected_distance"):
            value = getattr(self, name)
            if not value > 0.0 or not math.isfinite(value):
                raise ValueError(f"ScenarioConfig.{name} must be a positive number, got {value}")


@dataclass
class ScenarioContext:
    """What a scenario acts on: the world, the map, the CAV routes, the criteria, one random stream."""

    route_id: str
    world: World | None  # None: built only for its plan (``plan_scenarios``); the life cycle needs one
    map: RoadMap
    routes: list[Route]
    criteria: RouteCriteria | None
    rng: np.random.Generator
    config: ScenarioConfig = field(default_factory=ScenarioConfig)


class RouteProgress:
    """Each CAV's matched point on its dense route (a forward search, as the route criteria do)."""

    def __init__(self, routes: list[Route]) -> None:
        self.routes = routes
        self.index = np.zeros(len(routes), np.int64)
        self.xy = np.array([r.xy[0] for r in routes], np.float64)  # (n, 2) last seen centre [m]
        self.yaw = np.array([r.heading[0] for r in routes], np.float64)
        self.speed = np.zeros(len(routes))
        self.present = np.zeros(len(routes), bool)  # in the world at the last update

    def update(self, snap: Snapshot) -> None:
        rows, cav = snap.cav_rows()
        self.present[:] = False
        self.present[cav] = True
        self.xy[cav] = np.column_stack([snap.x[rows], snap.y[rows]])
        self.yaw[cav], self.speed[cav] = snap.yaw[rows], np.abs(snap.speed[rows])
        for i in cav.tolist():
            r, k = self.routes[i], int(self.index[i])
            window = r.xy[k : k + PROGRESS_WINDOW]
            self.index[i] = k + int(np.argmin(np.linalg.norm(window - self.xy[i], axis=1)))


def first_real_junction(m: RoadMap, route: Route, k: int) -> int:
    """Index of the first point of ``route`` at or after ``k`` inside a junction that is not a mere road
    join (``RoadMap.junction_is_join``), or -1."""
    inside = np.flatnonzero(route.in_junction[k:]) + k
    if len(inside) == 0:
        return -1
    joins = m.junction_is_join[m.lane_junction[route.lane[inside]]]
    real = inside[~joins & (inside > 0)]
    return int(real[0]) if len(real) else -1


class Phase(IntEnum):
    PENDING = 0
    INSTANTIATED = 1
    ACTIVE = 2
    ENDED = 3


class Scenario:
    """Base of every scenario type. Subclasses set ``type_name``, ``params``, ``uses_timeout`` and
    override the ``on_*`` hooks; actors go through :meth:`spawn` so that the end removes them."""

    type_name: ClassVar[str] = ""
    params: ClassVar[tuple[Param, ...]] = ()
    uses_timeout: ClassVar[bool] = True  # the reference's ST240

    def __init__(self, spec: ScenarioSpec, ctx: ScenarioContext) -> None:
        self.spec, self.ctx = spec, ctx
        self.p = parse_params(spec, ctx.route_id, self.params)
        cfg, route = ctx.config, ctx.routes[0]
        tx, ty, _ = spec.map_trigger()
        self.trigger_xy = np.array([tx, ty])
        gap = np.linalg.norm(route.xy - self.trigger_xy, axis=1)
        near = np.flatnonzero(gap < cfg.activation_distance)
        if len(near) == 0:
            raise self.error(
                f"trigger point (x={tx:.1f}, y={ty:.1f} in the map frame) is {gap.min():.1f} m from CAV 0's "
                f"route; it must lie within {cfg.activation_distance:g} m of it"
            )
        self.trigger_index = int(near[np.argmin(gap[near])])
        self.activation_index = int(near[0])  # the first route point within the activation distance
        self.t_wp = LanePoint(int(route.lane[self.trigger_index]), float(route.s[self.trigger_index]))
        self.route_lanes = frozenset(int(x) for x in route.path)
        gaps = [float(np.min(np.linalg.norm(r.xy - self.trigger_xy, axis=1))) for r in ctx.routes]
        self.affected = np.array(gaps) < cfg.affected_distance
        self.affected[EGO] = True
        self.passed = False  # the ego (CAV 0) has met the scenario's end condition
        self.phase = Phase.PENDING
        self.activated_at = math.nan  # [s] world time of activation
        self.ended_by_timeout = False
        self.actors: list[str] = []  # layer actors this scenario spawned (removed at the end)
        self.halted_lanes: list[int] = []  # background halted on these lanes until the end (stop_lane)
        self.held = np.zeros(len(ctx.routes), bool)  # CAVs the scenario may hold at its junction
        self.place()

    # ------------------------------------------------------------------ hooks for subclasses
    def place(self) -> None:
        """Compute the actors' places at setup (raise :meth:`error` when the map has no place)."""

    def plan(self) -> list[PlanItem]:
        """What this scenario will spawn and where (points) and how its actors or flows move (paths), from
        the placement computed at setup; the base has no actors."""
        return []

    def on_instantiate(self) -> None:
        """Spawn the actors that are present from instantiation."""

    def on_activate(self, snap: Snapshot) -> None:
        """The behaviour starts."""

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        """One tick while active; True ends the scenario."""
        return True

    def on_end(self) -> None:
        """Clean-up beyond removing the spawned actors (BA commands back to normal, ...)."""

    def perturb(self, controls: Controls, cav: np.ndarray, progress: RouteProgress) -> Controls:
        """Change the controls (n,) of the CAVs ``cav`` (n,) before the world applies them (ControlLoss);
        called every tick while the scenario is active."""
        return controls

    # ------------------------------------------------------------------ shared tools
    @property
    def world(self) -> World:
        if self.ctx.world is None:
            raise RuntimeError(f"scenario {self.spec.name} was built for its plan only: it has no world")
        return self.ctx.world

    @property
    def background(self) -> BackgroundCommands | None:
        """The world's background activity, as the commands a scenario gives it (None: the world has none)."""
        return self.world.background

    @property
    def criteria(self) -> RouteCriteria:
        if self.ctx.criteria is None:
            raise RuntimeError(f"scenario {self.spec.name} was built for its plan only: it has no criteria")
        return self.ctx.criteria

    @property
    def map(self) -> RoadMap:
        return self.ctx.map

    @property
    def time(self) -> float:
        return self.world.time

    def num(self, name: str) -> float:
        """A numeric parameter's value, in its own unit."""
        value = self.p[name]
        if not isinstance(value, float):
            raise TypeError(f"parameter {name!r} of {self.type_name} is not a number: {value!r}")
        return value

    def span(self, name: str) -> tuple[float, ...]:
        """A range parameter's (from, to), or a location parameter's CARLA-frame (x, y, z) [m]."""
        value = self.p[name]
        if not isinstance(value, tuple):
            raise TypeError(f"parameter {name!r} of {self.type_name} is not a range or location: {value!r}")
        return value

    def error(self, problem: str) -> ScenarioError:
        return ScenarioError(self.ctx.route_id, self.spec.name, problem)

    def fwd(self, start: LanePoint, distance: float, what: str) -> LanePoint:
        """fwd(distance) that refuses to stop short at a junction."""
        stop = walk(self.map, start, distance, through_junctions=False, prefer=self.route_lanes)
        through = walk(self.map, start, distance, through_junctions=True, prefer=self.route_lanes)
        if stop != through:
            raise self.error(
                f"no place for the {what}: a junction lies less than {distance:g} m downstream of lane "
                f"{self.map.lane_ids[start.lane]} at s={start.s:.1f} (the layout needs junction-free road)"
            )
        return stop

    def junction_exit(self) -> tuple[int, int, float]:
        """CAV 0's route indices of the last point before and the first point after its first junction past
        T, and the turn angle [rad] (+ left) between them. Nodes that only join roads end to end
        (``RoadMap.junction_is_join``: no junction in CARLA's map) are passed over."""
        route, m = self.ctx.routes[0], self.map
        k0 = self.trigger_index
        first = first_real_junction(m, route, k0)
        if first < 0 or route.distance[first] - route.distance[k0] > JUNCTION_SEARCH:
            raise self.error(
                f"no place for the scenario: CAV 0's route has no junction within {JUNCTION_SEARCH:g} m of T"
            )
        after = np.flatnonzero(~route.in_junction[first:]) + first
        if len(after) == 0:
            raise self.error("no place for the scenario: CAV 0's route ends inside the junction")
        last = int(after[0])
        turn = (route.heading[last] - route.heading[first - 1] + math.pi) % (2 * math.pi) - math.pi
        return first - 1, last, float(turn)

    def route_point(self, k: int) -> LanePoint:
        route = self.ctx.routes[0]
        return LanePoint(int(route.lane[k]), float(route.s[k]))

    def light_point(self, lane: int) -> PlanItem:
        """A plan marker at the end of ``lane`` (its stop line): a signal the scenario forces."""
        end = LanePoint(lane, float(self.map.lane_length[lane]))
        return point("light", point_xy(self.map, end), heading(self.map, end))

    def spawn(
        self, suffix: str, type_name: str, xy: np.ndarray, yaw: float, speed: float = 0.0, prop: bool = False
    ) -> str:
        """A layer actor named ``<scenario>:<suffix>`` (Role.PROP for static props, else SCENARIO)."""
        actor_id = f"{self.spec.name}:{suffix}"
        role = Role.PROP if prop else Role.SCENARIO
        self.world.add_layer_actor(actor_id, type_name, float(xy[0]), float(xy[1]), float(yaw), speed, role)
        self.actors.append(actor_id)
        return actor_id

    def despawn(self, actor_id: str) -> None:
        if actor_id in self.actors:
            self.actors.remove(actor_id)
            self.world.remove_layer_actor(actor_id)

    def stop_entries(self, junction: int) -> None:
        """``Junction{stopEntries}``: background vehicles on the entries of ``junction`` that CAV 0's route
        does not take halt (and any that arrive there later) until the scenario ends."""
        if junction < 0:
            return
        m, via = self.map, self.map.link_via
        into = (via >= 0) & (m.lane_junction[np.maximum(via, 0)] == junction) & ~m.lane_internal[m.link_from]
        into &= m.lane_kind[m.link_from] == LaneKind.DRIVING
        self.halt_lanes(sorted({int(x) for x in m.link_from[into]} - self.route_lanes))
        self.hold_at(junction)

    def hold_at(self, junction: int) -> None:
        """This scenario holds traffic at ``junction`` until it ends (forced reds, halted entries): a CAV
        whose route passes through it may wait there as long as CAV 0 needs the junction, through no fault
        of its own, so its blocked test is suspended until the scenario ends (upstream, with one ego,
        nobody else waits there). CAV 0's own test follows the scenario's timeout rule."""
        for i, r in enumerate(self.ctx.routes):
            if i != EGO and not self.held[i] and bool(np.any(self.map.lane_junction[r.lane] == junction)):
                self.held[i] = True
                self.criteria.suspend_blocked(i, True)

    def halt_lanes(self, lanes: list[int], before: float = np.inf) -> None:
        """Background vehicles on ``lanes`` halt (and any that drive onto them) until the scenario ends;
        with ``before`` [m of lane arc length], only those behind that point (StopBack)."""
        if self.background is not None:
            self.halted_lanes += lanes
            self.background.stop_lane(lanes, before)

    def ego_running(self) -> bool:
        """CAV 0's evaluation is still running (it has not finished, failed or been blocked)."""
        return not bool(self.criteria.finished()[EGO])

    def ego_passed(self) -> bool:
        """The scenario's own end, as far as its ego goes: CAV 0 has met the type's end condition
        (``passed``), or its evaluation ended first (upstream, the scenario ends with its ego's route)."""
        return self.passed or not self.ego_running()

    def ego_driven(self, progress: RouteProgress) -> float:
        """[m] CAV 0's distance along its own route at its matched point."""
        return float(self.ctx.routes[EGO].distance[progress.index[EGO]])

    # ------------------------------------------------------------------ the life cycle
    def step(self, snap: Snapshot, progress: RouteProgress) -> None:
        """One tick of the life cycle (called before the world ticks)."""
        if self.phase == Phase.ENDED:
            return
        cfg, route = self.ctx.config, self.ctx.routes[0]
        k = int(progress.index[0])
        if self.phase == Phase.PENDING:
            if route.distance[self.trigger_index] - route.distance[k] > cfg.instantiation_distance:
                return
            self.on_instantiate()
            self.phase = Phase.INSTANTIATED
        if self.phase == Phase.INSTANTIATED:
            if k < self.activation_index or not progress.present[0]:
                return
            self.phase, self.activated_at = Phase.ACTIVE, self.time
            self._suspend_blocked(True)
            self.on_activate(snap)
        done = self.on_update(snap, progress)
        if not done and self.uses_timeout and self.time - self.activated_at >= cfg.timeout:
            self._time_out(snap)
            done = True
        if done:
            self.finish()

    def finish(self) -> None:
        """End now: clean up and resume the blocked tests (also at the end of the route)."""
        if self.phase == Phase.ENDED:
            return
        was_active = self.phase == Phase.ACTIVE
        self.phase = Phase.ENDED
        if was_active:
            self.on_end()
            if self.halted_lanes and self.background is not None:
                self.background.release_lane(self.halted_lanes)
            for i in np.flatnonzero(self.held).tolist():
                self.criteria.suspend_blocked(i, False)
            self._suspend_blocked(False)
        for actor_id in list(self.actors):
            self.despawn(actor_id)

    def _time_out(self, snap: Snapshot) -> None:
        self.ended_by_timeout = True
        message = (
            f"Scenario {self.spec.name} ({self.type_name}) timed out after {self.ctx.config.timeout:g} s"
        )
        if self.ego_running() and not self.passed:
            self.criteria.record_scenario_timeout(EGO, int(snap.step), message)

    def _suspend_blocked(self, suspended: bool) -> None:
        if not self.uses_timeout:
            return
        for i in np.flatnonzero(self.affected).tolist():
            self.criteria.suspend_blocked(i, suspended)
