"""The route data model: a route (:class:`RouteSpec`), its CAVs (:class:`CavSpec`) and scenarios
(:class:`ScenarioSpec`), each checked when built, and the limits a route must keep (CAV count, seed,
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
from cmudrive.maps.coords import carla_to_map
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

# CAV starts: two CAVs whose dense routes start on the same lane less than a CAV length apart, or whose
# start points are closer than a CAV width whatever their lanes, would spawn overlapping (a collision at
# tick 0, blamed on the agent); such a route is refused. Generated routes keep 15 m (route_gen).
MIN_START_SPACING = ACTOR_TYPES["cav"].length  # [m] along a shared start lane
MIN_START_DISTANCE = ACTOR_TYPES["cav"].width  # [m] between start points on any lanes

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

    def _problem(self) -> str | None:
        if not isinstance(self.town, str) or not self.town:
            return "missing town"
        if self.weather not in WEATHERS:
            return f"unknown weather {self.weather!r}; valid: {', '.join(WEATHERS)}"
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
                f"route {self.id!r} on {road_map.name!r}: {pairs}{more} start on top of each other (starts "
                f"on one lane must be {MIN_START_SPACING:.2f} m apart, on any lanes "
                f"{MIN_START_DISTANCE:.2f} m: a CAV length and width)"
            )
        return routes


def start_conflicts(routes: Sequence[Route]) -> list[tuple[int, int, float]]:
    """Pairs of CAVs ``(i, j, distance between their start points [m])``, i < j, whose dense routes start
    overlapping: on the same lane less than ``MIN_START_SPACING`` apart along it, or less than
    ``MIN_START_DISTANCE`` apart in a straight line whatever the lanes (they would spawn in each other)."""
    if len(routes) < 2:
        return []
    xy = np.array([r.xy[0] for r in routes])
    lane = np.array([r.lane[0] for r in routes])
    s = np.array([r.s[0] for r in routes])
    i, j = np.triu_indices(len(routes), k=1)  # at most 16 CAVs: 120 pairs
    dist = np.hypot(*(xy[i] - xy[j]).T)
    along = np.abs(s[i] - s[j])
    bad = ((lane[i] == lane[j]) & (along < MIN_START_SPACING)) | (dist < MIN_START_DISTANCE)
    return [(int(a), int(b), float(d)) for a, b, d in zip(i[bad], j[bad], dist[bad], strict=True)]


def _suggest(scenario_type: str) -> str:
    close = difflib.get_close_matches(str(scenario_type), SCENARIO_TYPES, n=3)
    hint = f"did you mean {', '.join(close)}? " if close else ""
    return f"{hint}valid types are cmudrive.bench.scenario_types.SCENARIO_TYPES ({len(SCENARIO_TYPES)})"


# ------------------------------------------------------------------------------------------------- reading
