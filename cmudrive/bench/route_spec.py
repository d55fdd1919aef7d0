"""The route data model: a route (:class:`RouteSpec`), its CAVs (:class:`CavSpec`), scenarios
(:class:`ScenarioSpec`), free actors (:class:`ActorSpec`: the pedestrians, bicycles, vehicles and props
another benchmark's route places, apart from any scenario) and background density
(:class:`BackgroundSpec`), each checked when built, and the limits a route must keep (CAV count, seed,
route length, CAV starts). Reading and writing route files is :mod:`cmudrive.bench.routes`, which
re-exports these names.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cmudrive.bench.records import route_id_problem
from cmudrive.bench.scenario_types import SCENARIO_TYPES
from cmudrive.maps import MapError, RoadMap, Route, RouteError, densify
from cmudrive.maps.cache import resolve_map_path
from cmudrive.maps.coords import carla_to_map, carla_yaw_to_map
from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.weather import WEATHERS

MIN_CAVS = 2  # [-] CAVs per route in a route file (``min_cavs=1`` allows single-ego files)
MAX_CAVS = 16  # [-] CAVs per route
MIN_WAYPOINTS = 2  # [-] per CAV
MAX_SEED = 2**31 - 1  # SUMO's --seed is a 32-bit signed integer
MAX_COORDINATE = 1.0e6  # [m] |x|, |y|, |z| of a waypoint or trigger point (CARLA towns span < 10 km)
MIN_ROUTE_LENGTH = 10.0  # [m] a CAV route shorter than this cannot be driven and completed
MAX_ROUTE_LENGTH = 20_000.0  # [m] a CAV route (Bench2Drive's longest is ~2 km; 4000 ticks ~ 5 km)
DETOUR_FACTOR = 3.0  # a dense route longer than this x its waypoints' polyline + DETOUR_SLACK loops
DETOUR_SLACK = 500.0  # [m]
# [m] a scenario's trigger point must lie this close to CAV 0's dense route: the route point that close to
# it activates the scenario (ScenarioConfig.activation_distance), so a farther trigger never fires.
# ``routes check`` and ``eval`` both use it.
TRIGGER_TOLERANCE = 2.0

# CAV starts: two CAVs whose footprints (a CAV's length x width at the start point and heading of its
# dense route) overlap would spawn inside each other (a collision at tick 0, blamed on the agent); such a
# route is refused. On one lane that is closer than a CAV length; side by side on neighbouring lanes
# (InterDrive starts CAVs 3.5 m apart across a highway) it is not. Generated routes keep 15 m (route_gen).
MIN_START_SPACING = ACTOR_TYPES["cav"].length  # [m] the footprint's length
MIN_START_DISTANCE = ACTOR_TYPES["cav"].width  # [m] the footprint's width: closer centres always overlap

LIGHTS = ("on", "off")  # RouteSpec.lights
MAX_ACTORS = 200  # [-] free actors per route (InterDrive has none, MDrive-style folders a handful)
MAX_ACTOR_SPEED = 60.0  # [m/s] a free actor's speed (216 km/h: anything faster is a unit mistake)
MAX_BACKGROUND = 1000  # [-] background vehicles or pedestrians a route may ask for

# a scenario parameter's name (and the attribute names of a parameter element)
_XML_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.-]*$")

ParamValue = str | dict[str, str]


class RouteSpecError(ValueError):
    """A route (file) that breaks the format; ``str()`` names the file, route and CAV where known."""

    def __init__(
        self, problem: str, path: str | None = None, route_id: str | None = None, cav_id: int | None = None
    ) -> None:
        super().__init__(problem, path, route_id, cav_id)  # args rebuild the error after pickling
        self.problem, self.path, self.route_id, self.cav_id = problem, path, route_id, cav_id

    def within(self, path: str | None = None, route_id: str | None = None) -> RouteSpecError:
        """The same error with the file and route filled in where still unknown."""
        return RouteSpecError(self.problem, self.path or path, self.route_id or route_id, self.cav_id)

    @property
    def detail(self) -> str:
        """The problem, prefixed with the CAV but not the file or route."""
        return self.problem if self.cav_id is None else f"CAV {self.cav_id}: {self.problem}"

    def __str__(self) -> str:
        where = [] if self.path is None else [str(self.path)]
        if self.route_id is not None:
            where.append(f"route {self.route_id!r}")
        return ", ".join(where) + (": " if where else "") + self.detail


# ---------------------------------------------------------------------------------------------- data model
@dataclass(frozen=True, eq=False)
class CavSpec:
    """One CAV of a route: its id (0 = the scenario ego) and its route keypoints."""

    id: int
    waypoints: np.ndarray  # (n, 3) float64 CARLA world x, y, z [m], n >= 2, read-only

    def __post_init__(self) -> None:
        if isinstance(self.id, bool) or not isinstance(self.id, int | np.integer) or self.id < 0:
            raise RouteSpecError(f"CAV id must be a non-negative integer, got {self.id!r}")
        object.__setattr__(self, "id", int(self.id))
        wps = np.array(self.waypoints, dtype=np.float64)
        if wps.ndim != 2 or wps.shape[1] != 3:
            raise RouteSpecError(f"waypoints must have shape (n, 3), got {wps.shape}", cav_id=self.id)
        if len(wps) < MIN_WAYPOINTS:
            raise RouteSpecError(f"needs at least {MIN_WAYPOINTS} waypoints, got {len(wps)}", cav_id=self.id)
        if not np.all(np.isfinite(wps)):
            bad = int(np.flatnonzero(~np.all(np.isfinite(wps), axis=1))[0])
            raise RouteSpecError(f"waypoint {bad} has a non-finite coordinate", cav_id=self.id)
        wps.flags.writeable = False
        object.__setattr__(self, "waypoints", wps)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CavSpec):
            return NotImplemented
        return self.id == other.id and np.array_equal(self.waypoints, other.waypoints)

    def __hash__(self) -> int:
        return hash((self.id, self.waypoints.tobytes()))


@dataclass(frozen=True)
class ScenarioSpec:
    """One scenario: instance name, type (one of ``SCENARIO_TYPES``), trigger pose and raw parameters.

    ``params`` keeps each parameter element's attributes: ``<distance value="40"/>`` -> ``"40"``; any
    other attribute set, e.g. ``<frequency from="20" to="100"/>``, -> ``{"from": "20", "to": "100"}``."""

    name: str
    type: str
    trigger: tuple[float, float, float, float]  # CARLA world x, y, z [m], yaw [deg]
    params: dict[str, ParamValue] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise RouteSpecError(f"scenario name must be a non-empty string, got {self.name!r}")
        where = f"scenario {self.name!r}"
        if self.type not in SCENARIO_TYPES:
            raise RouteSpecError(f"{where}: unknown scenario type {self.type!r}; {_suggest(self.type)}")
        trigger = tuple(float(v) for v in self.trigger)
        if len(trigger) != 4 or not all(math.isfinite(v) for v in trigger):
            raise RouteSpecError(
                f"{where}: trigger must be 4 finite numbers (x, y, z, yaw), got {self.trigger}"
            )
        object.__setattr__(self, "trigger", trigger)
        params: dict[str, ParamValue] = {}
        for key, value in self.params.items():
            if not isinstance(key, str) or not _XML_NAME.match(key) or key == "trigger_point":
                raise RouteSpecError(f"{where}: invalid parameter name {key!r}")
            if isinstance(value, dict):
                if not all(
                    isinstance(k, str) and _XML_NAME.match(k) and isinstance(v, str) for k, v in value.items()
                ):
                    raise RouteSpecError(f"{where}: parameter {key!r} must map attribute names to strings")
                params[key] = value["value"] if set(value) == {"value"} else dict(value)
            elif isinstance(value, str):
                params[key] = value
            else:
                raise RouteSpecError(f"{where}: parameter {key!r} must be a string or a dict, got {value!r}")
        object.__setattr__(self, "params", params)

    def map_trigger(self) -> tuple[float, float, float]:
        """Trigger point in the map frame: x, y [m] and yaw [rad]."""
        (xy,), yaw = carla_to_map(np.array([self.trigger[:2]]), self.trigger[3])
        return float(xy[0]), float(xy[1]), float(yaw)


@dataclass(frozen=True, eq=False)
class ActorSpec:
    """A free actor of a route: it appears when the route starts and, when it has two or more waypoints
    and a positive speed, follows them as a polyline at that speed, then stands at the last one;
    otherwise it stands at its first waypoint facing ``yaw`` for the whole route.

    ``type`` is one of ``cmudrive.sim.actor_types.ACTOR_TYPES`` (not ``cav``): its kind decides the
    collision key (a pedestrian, a vehicle, or layout for props). ``model`` keeps the CARLA blueprint the
    actor stands for, for the record; ``static`` marks a prop or parked vehicle (``Role.PROP``)."""

    id: str
    type: str
    waypoints: np.ndarray  # (n, 3) float64 CARLA world x, y, z [m], n >= 1, read-only
    yaw: float = 0.0  # [deg] CARLA yaw of a standing actor (a moving one faces along its path)
    speed: float = 0.0  # [m/s]
    static: bool = False
    model: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.id, str) or route_id_problem(self.id) is not None:
            raise RouteSpecError(f"actor id must be 1-255 printable characters, got {self.id!r}")
        where = f"actor {self.id!r}"
        if self.type not in ACTOR_TYPES or self.type == "cav":
            known = ", ".join(t for t in ACTOR_TYPES if t != "cav")
            raise RouteSpecError(f"{where}: unknown actor type {self.type!r}; known: {known}")
        wps = np.array(self.waypoints, dtype=np.float64)
        if wps.ndim != 2 or wps.shape[1] != 3 or len(wps) < 1:
            raise RouteSpecError(f"{where}: waypoints must have shape (n, 3), n >= 1, got {wps.shape}")
        if not np.all(np.isfinite(wps)):
            raise RouteSpecError(f"{where}: a waypoint has a non-finite coordinate")
        wps.flags.writeable = False
        object.__setattr__(self, "waypoints", wps)
        for name, top in (("yaw", math.inf), ("speed", MAX_ACTOR_SPEED)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.floating):
                raise RouteSpecError(f"{where}: {name} must be a number, got {value!r}")
            if not math.isfinite(value) or (name == "speed" and not 0.0 <= value <= top):
                raise RouteSpecError(f"{where}: {name} must be finite (speed in 0..{top:g} m/s), got {value}")
            object.__setattr__(self, name, float(value))
        if not isinstance(self.model, str) or not isinstance(self.static, bool):
            raise RouteSpecError(f"{where}: model must be a string and static a bool")

    @property
    def moves(self) -> bool:
        """Follows its waypoints (two or more, a positive speed, not static) rather than standing."""
        return not self.static and len(self.waypoints) >= 2 and self.speed > 0.0

    def map_waypoints(self) -> np.ndarray:
        """Waypoints in the map frame, shape (n, 2) [m]."""
        return carla_to_map(self.waypoints[:, :2])

    def map_yaw(self) -> float:
        """``yaw`` in the map frame [rad]."""
        return float(carla_yaw_to_map(self.yaw))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ActorSpec):
            return NotImplemented
        mine = (self.id, self.type, self.yaw, self.speed, self.static, self.model)
        theirs = (other.id, other.type, other.yaw, other.speed, other.static, other.model)
        return mine == theirs and np.array_equal(self.waypoints, other.waypoints)

    def __hash__(self) -> int:
        return hash((self.id, self.type, self.waypoints.tobytes()))


@dataclass(frozen=True)
class BackgroundSpec:
    """The background a route asks for, overriding the evaluator's (``BackgroundConfig``): target numbers
    of background vehicles and pedestrians around the CAVs (0 and 0: the CAVs and the route's own actors
    only, as InterDrive's parameter file runs its scenarios)."""

    vehicles: int
    pedestrians: int

    def __post_init__(self) -> None:
        for name in ("vehicles", "pedestrians"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_BACKGROUND:
                raise RouteSpecError(
                    f"background {name} must be an integer in 0..{MAX_BACKGROUND}, got {value!r}"
                )


@dataclass(frozen=True)
class RouteSpec:
    """One route: town (a town name, or a ``.net.xml`` path), weather preset, SUMO seed, CAVs ``0..N-1``
    in order (CAV 0 drives the scenario route) and scenarios. A town name is looked up in ``town_dirs``
    (the route file's folder, then ``--town-dir`` folders), then among the committed towns."""

    id: str
    town: str
    weather: str  # a key of cmudrive.sim.weather.WEATHERS
    seed: int
    cavs: tuple[CavSpec, ...]
    scenarios: tuple[ScenarioSpec, ...] = ()
    town_dirs: tuple[str, ...] = field(default=(), compare=False)  # where a town name is looked up first
    actors: tuple[ActorSpec, ...] = ()  # free actors, apart from the scenarios (imported benchmarks)
    background: BackgroundSpec | None = None  # None: the evaluator's background
    # "on": every traffic light runs its program; "off": all switched off for the whole route (SUMO's "off"
    # program: each junction's right of way applies, minor links yield; no light can be run), as
    # InterDrive's runs hold its lights (``turn_off_light``)
    lights: str = "on"

    def town_path(self) -> Path:
        """The network file of this route's town (MapError naming the route when there is none)."""
        try:
            return resolve_map_path(self.town, self.town_dirs)
        except MapError as exc:
            raise MapError(f"route {self.id}: {exc}") from None

    def __post_init__(self) -> None:
        problem = route_id_problem(self.id)
        if problem:
            raise RouteSpecError(problem)
        err = self._problem()
        if err:
            raise RouteSpecError(err, route_id=self.id)
        object.__setattr__(self, "cavs", tuple(self.cavs))
        object.__setattr__(self, "scenarios", tuple(self.scenarios))
        object.__setattr__(self, "actors", tuple(self.actors))

    def _problem(self) -> str | None:
        if not isinstance(self.town, str) or not self.town:
            return "missing town"
        if self.weather not in WEATHERS:
            return f"unknown weather {self.weather!r}; valid: {', '.join(WEATHERS)}"
        if self.lights not in LIGHTS:
            return f"lights must be one of {', '.join(LIGHTS)}, got {self.lights!r}"
        if isinstance(self.seed, bool) or not isinstance(self.seed, int | np.integer):
            return f"seed must be an integer in 0..{MAX_SEED}, got {self.seed!r}"
        if not 0 <= self.seed <= MAX_SEED:
            return f"seed must be an integer in 0..{MAX_SEED}, got {self.seed!r}"
        if not 1 <= len(self.cavs) <= MAX_CAVS:
            return f"needs 1-{MAX_CAVS} CAVs, got {len(self.cavs)}"
        ids = [c.id for c in self.cavs]
        if ids != list(range(len(ids))):
            return f"CAV ids must be 0..{len(ids) - 1} in order, got {ids}"
        names = [s.name for s in self.scenarios]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            return f"duplicate scenario names {dup}"
        if len(self.actors) > MAX_ACTORS:
            return f"{len(self.actors)} actors, more than the {MAX_ACTORS} a route may have"
        actor_ids = [a.id for a in self.actors]
        dup = sorted({n for n in actor_ids if actor_ids.count(n) > 1})
        if dup:
            return f"duplicate actor ids {dup}"
        return None

    def map_waypoints(self, cav: int) -> np.ndarray:
        """Waypoints of CAV ``cav`` in the map frame, shape (n, 2) [m] (for ``cmudrive.maps.densify``)."""
        if not 0 <= cav < len(self.cavs):
            raise RouteSpecError(f"no CAV {cav} (route has {len(self.cavs)})", route_id=self.id)
        return carla_to_map(self.cavs[cav].waypoints[:, :2])

    def dense_routes(self, road_map: RoadMap) -> list[Route]:
        """Every CAV's waypoints joined into a dense 1 m route (``cmudrive.maps.densify``), in CAV order;
        a RouteError names the route and the CAV. A route must be ``MIN_ROUTE_LENGTH`` to
        ``MAX_ROUTE_LENGTH`` long, and at most ``DETOUR_FACTOR`` x its waypoints' polyline +
        ``DETOUR_SLACK``: waypoints that go back and forth make the planner loop round blocks. No two
        CAVs may start overlapping (:func:`start_conflicts`)."""
        routes = []
        for cav in self.cavs:
            points = self.map_waypoints(cav.id)
            polyline = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
            cap = min(MAX_ROUTE_LENGTH, DETOUR_FACTOR * polyline + DETOUR_SLACK)
            where = f"route {self.id!r} on {road_map.name!r}, CAV {cav.id}"
            try:
                route = densify(road_map, points, max_length=cap)
            except RouteError as exc:
                raise RouteError(f"{where}: {exc}") from None
            if route.length < MIN_ROUTE_LENGTH:
                raise RouteError(
                    f"{where}: the route is {route.length:.1f} m long, shorter than {MIN_ROUTE_LENGTH:.0f} m "
                    "(its waypoints are (nearly) all the same point)"
                )
            routes.append(route)
        clashes = start_conflicts(routes)
        if clashes:
            pairs = ", ".join(f"CAVs {a} and {b} ({gap:.1f} m)" for a, b, gap in clashes[:5])
            more = f" and {len(clashes) - 5} more pairs" if len(clashes) > 5 else ""
            raise RouteError(
                f"route {self.id!r} on {road_map.name!r}: {pairs}{more} start on top of each other (their "
                f"{MIN_START_SPACING:.2f} x {MIN_START_DISTANCE:.2f} m footprints at the start overlap: on "
                f"one lane starts must be a CAV length apart)"
            )
        return routes


def start_conflicts(routes: Sequence[Route]) -> list[tuple[int, int, float]]:
    """Pairs of CAVs ``(i, j, distance between their start points [m])``, i < j, whose footprints at the
    start of their dense routes overlap (``MIN_START_SPACING`` x ``MIN_START_DISTANCE`` boxes at the first
    route point and heading; a separating-axis test): they would spawn inside each other. Two starts on one
    lane less than a CAV length apart, or closer than a CAV width on any lanes, always overlap."""
    if len(routes) < 2:
        return []
    xy = np.array([r.xy[0] for r in routes])
    yaw = np.array([r.heading[0] for r in routes])
    i, j = np.triu_indices(len(routes), k=1)  # at most 16 CAVs: 120 pairs
    d = xy[j] - xy[i]  # (P, 2)
    half = np.array([MIN_START_SPACING, MIN_START_DISTANCE]) / 2.0
    fwd = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)  # (N, 2) each footprint's axes
    left = np.stack([-np.sin(yaw), np.cos(yaw)], axis=1)
    separated = np.zeros(len(i), bool)
    for axis in (fwd[i], left[i], fwd[j], left[j]):  # the four candidate separating axes, (P, 2) each
        reach = sum(
            h * np.abs(np.sum(u * axis, axis=1))
            for k in (i, j)
            for h, u in zip(half, (fwd[k], left[k]), strict=True)
        )
        separated |= np.abs(np.sum(d * axis, axis=1)) >= reach
    dist = np.hypot(*d.T)
    bad = ~separated
    return [(int(a), int(b), float(g)) for a, b, g in zip(i[bad], j[bad], dist[bad], strict=True)]


def _suggest(scenario_type: str) -> str:
    close = difflib.get_close_matches(str(scenario_type), SCENARIO_TYPES, n=3)
    hint = f"did you mean {', '.join(close)}? " if close else ""
    return f"{hint}valid types are cmudrive.bench.scenario_types.SCENARIO_TYPES ({len(SCENARIO_TYPES)})"


# ------------------------------------------------------------------------------------------------- reading
