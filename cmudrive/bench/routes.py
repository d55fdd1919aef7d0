"""Multi-CAV route files: the data model, reading, checking and writing.

A route is one town, one weather preset, one SUMO seed, 1-16 CAV routes and any number of scenarios
(``docs/route_format.md`` has the schema)::

    <routes>
      <route id="smoke_00" town="downtown" weather="ClearNoon" seed="0">
        <cav id="0"><waypoints><position x="141.0" y="-199.9" z="0.0"/> ...</waypoints></cav>
        <cav id="1"> ... </cav>
        <scenarios>
          <scenario name="Accident_1" type="Accident">
            <trigger_point x="..." y="..." z="..." yaw="..."/> <distance value="40"/> ...
          </scenario>
        </scenarios>
      </route>
    </routes>

Positions and trigger points are CARLA world coordinates (metres, yaw in degrees; the mirror image in y of
our map frame, see ``cmudrive.maps.coords``). CAV 0 drives the scenario route. A route file holds 2-16 CAVs
per route (``MIN_CAVS``..``MAX_CAVS``); a :class:`RouteSpec` in memory may hold one (a single-ego route as
imported from Bench2Drive), and ``min_cavs=1`` reads and writes such files.

Generating routes (placing CAVs by the road topology) is ``cmudrive.bench.authoring.route_gen``'s job.
"""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
import math
import os
import re
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, overload

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
# Input bounds. Reading and planning are linear in the waypoints (each keypoint is snapped and joined to
# the next by one lane-graph search, ~0.3 ms per waypoint on a laptop core), so these bounds cap the work
# of `routes check` and of route setup in `eval`: a 45 MB file of 800 k waypoints took minutes without an
# answer. The committed sets hold at most 9 waypoints per CAV and 6909 in a file (cmudrive220.xml, 0.5 MB).
MAX_FILE_BYTES = 16 * 2**20  # [bytes] a route file (Bench2Drive's and Leaderboard 2.0's are ~1-3 MB)
MAX_WAYPOINTS = 2000  # [-] per CAV: a 20 km route (MAX_ROUTE_LENGTH) with a keypoint every 10 m
MAX_FILE_WAYPOINTS = 100_000  # [-] <position>/<waypoint> elements in a file (~30 s of planning)
# CAV starts: two CAVs whose dense routes start on the same lane less than a CAV length apart, or whose
# start points are closer than a CAV width whatever their lanes, would spawn overlapping (a collision at
# tick 0, blamed on the agent); such a route is refused. Generated routes keep 15 m (route_gen).
MIN_START_SPACING = ACTOR_TYPES["cav"].length  # [m] along a shared start lane
MIN_START_DISTANCE = ACTOR_TYPES["cav"].width  # [m] between start points on any lanes

# numbers as route files write them: ASCII decimal only (str.isdigit and float accept "²", "١٢", "1_000")
_INT = re.compile(r"[0-9]+", re.ASCII)
_FLOAT = re.compile(  # (nan and inf pass here to be refused as non-finite)
    r"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|nan|inf|infinity)", re.ASCII | re.IGNORECASE
)
_XML_SPACE = " \t\r\n"  # what XML calls white space (a no-break space is not)

# names and attributes an XML route file may hold
_XML_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.-]*$")
_ROUTE_ATTRS = frozenset({"id", "town", "weather", "seed"})
_POSITION_ATTRS = frozenset({"x", "y", "z", "pitch", "roll", "yaw"})  # pitch/roll/yaw are ignored
_TRIGGER_ATTRS = frozenset({"x", "y", "z", "yaw", "pitch", "roll"})  # pitch/roll are ignored

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
def _number(elem: ET.Element, attr: str, what: str, default: float | None = None) -> float:
    raw = elem.get(attr)
    if raw is None:
        if default is not None:
            return default
        raise RouteSpecError(f"{what}: missing attribute {attr!r}")
    if not _FLOAT.fullmatch(raw.strip(_XML_SPACE)):
        raise RouteSpecError(f"{what}: non-numeric {attr}={raw!r} (ASCII decimal numbers only)")
    value = float(raw)
    if not math.isfinite(value):
        raise RouteSpecError(f"{what}: non-finite {attr}={raw!r}")
    if attr in ("x", "y", "z") and abs(value) > MAX_COORDINATE:
        raise RouteSpecError(f"{what}: {attr}={raw} is beyond +-{MAX_COORDINATE:.0e} m, off any map")
    return value


def _integer(raw: str | None, what: str, largest: int) -> int:
    """A non-negative ASCII decimal integer up to ``largest``; RouteSpecError naming ``what``."""
    text = (raw or "").strip(_XML_SPACE)
    if not _INT.fullmatch(text) or len(text) > 18 or int(text) > largest:  # (int() refuses 4300+ digits)
        raise RouteSpecError(f"{what} must be an integer in 0..{largest}, got {raw!r}")
    return int(text)


def _check_attrs(elem: ET.Element, allowed: frozenset[str], what: str) -> None:
    unknown = sorted(set(elem.attrib) - allowed)
    if unknown:
        raise RouteSpecError(f"{what}: unknown attributes {unknown}; allowed: {sorted(allowed)}")


def points_from_xml(elems: Iterable[ET.Element], cav_id: int | None = None) -> np.ndarray:
    """``<position x y z/>`` (or Leaderboard 1.0 ``<waypoint>``) elements -> (n, 3) CARLA points; z defaults
    to 0 and pitch/roll/yaw are ignored."""
    elems = list(elems)
    if len(elems) > MAX_WAYPOINTS:
        raise RouteSpecError(
            f"{len(elems)} waypoints, more than the {MAX_WAYPOINTS} a CAV may have (waypoints are keypoints "
            "of the route, ~50 m apart: see docs/route_format.md)",
            cav_id=cav_id,
        )
    rows = []
    for i, elem in enumerate(elems):
        try:
            _check_attrs(elem, _POSITION_ATTRS, f"waypoint {i}")
            rows.append([_number(elem, k, f"waypoint {i}", 0.0 if k == "z" else None) for k in "xyz"])
        except RouteSpecError as exc:
            raise RouteSpecError(exc.problem, cav_id=cav_id) from None
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


def scenario_from_xml(elem: ET.Element, index: int) -> ScenarioSpec:
    """A ``<scenario name type>`` element with its ``<trigger_point>`` and parameter elements."""
    name = elem.get("name") or ""
    what = f"scenario {name or index!r}"
    _check_attrs(elem, frozenset({"name", "type"}), what)
    if not name:
        raise RouteSpecError(f"scenario {index}: missing name")
    if elem.get("type") is None:
        raise RouteSpecError(f"{what}: missing type")
    triggers = elem.findall("trigger_point")
    if len(triggers) != 1:
        raise RouteSpecError(f"{what}: needs exactly one <trigger_point>, got {len(triggers)}")
    trig = triggers[0]
    _check_attrs(trig, _TRIGGER_ATTRS, f"{what} trigger_point")
    trigger = tuple(
        _number(trig, k, f"{what} trigger_point", 0.0 if k == "z" else None) for k in ("x", "y", "z", "yaw")
    )
    params: dict[str, ParamValue] = {}
    for child in elem:
        if child.tag == "trigger_point":
            continue
        if child.tag in params:
            raise RouteSpecError(f"{what}: parameter <{child.tag}> given twice")
        attrs = dict(child.attrib)
        params[child.tag] = attrs["value"] if set(attrs) == {"value"} else attrs
    return ScenarioSpec(name=name, type=str(elem.get("type")), trigger=trigger, params=params)  # type: ignore[arg-type]


def _route_from_xml(elem: ET.Element, min_cavs: int) -> RouteSpec:
    for tag, hint in (("waypoints", "its waypoints"), ("weathers", "a <weathers> element")):
        if elem.find(tag) is not None:
            raise RouteSpecError(
                f"has {hint} directly under <route>: this looks like a single-ego Leaderboard/Bench2Drive "
                "route file; convert it with cmudrive.bench.authoring.bench2drive.import_leaderboard_routes"
            )
    _check_attrs(elem, _ROUTE_ATTRS, "<route>")
    unknown = sorted({c.tag for c in elem} - {"cav", "scenarios"})
    if unknown:
        raise RouteSpecError(f"unknown elements {unknown} in <route>; allowed: <cav>, <scenarios>")
    for attr in ("town", "weather"):
        if not elem.get(attr):
            raise RouteSpecError(f"missing {attr}")
    seed = _integer(elem.get("seed", "0"), "seed", MAX_SEED)
    cavs = [_cav_from_xml(c, i) for i, c in enumerate(elem.findall("cav"))]
    if not min_cavs <= len(cavs) <= MAX_CAVS:
        raise RouteSpecError(f"needs {min_cavs}-{MAX_CAVS} <cav> elements, got {len(cavs)}")
    ids = sorted(c.id for c in cavs)
    if ids != list(range(len(cavs))):
        raise RouteSpecError(f"CAV ids must be 0..{len(cavs) - 1}, each once; got {[c.id for c in cavs]}")
    scenarios: list[ScenarioSpec] = []
    for block in elem.findall("scenarios"):
        for child in block:
            if child.tag != "scenario":
                raise RouteSpecError(f"unknown element <{child.tag}> in <scenarios>")
            scenarios.append(scenario_from_xml(child, len(scenarios)))
    return RouteSpec(
        id=str(elem.get("id")),
        town=str(elem.get("town")),
        weather=str(elem.get("weather")),
        seed=seed,
        cavs=tuple(sorted(cavs, key=lambda c: c.id)),
        scenarios=tuple(scenarios),
    )


def _cav_from_xml(elem: ET.Element, index: int) -> CavSpec:
    cav_id = _integer(elem.get("id"), f"the id of <cav> number {index}", 10**9)
    try:
        _check_attrs(elem, frozenset({"id"}), "<cav>")
        unknown = sorted({c.tag for c in elem} - {"waypoints"})
        if unknown:
            raise RouteSpecError(f"unknown elements {unknown} in <cav>; allowed: <waypoints>")
        blocks = elem.findall("waypoints")
        if len(blocks) != 1:
            raise RouteSpecError(
                "missing <waypoints>" if not blocks else f"{len(blocks)} <waypoints> elements"
            )
        bad = sorted({c.tag for c in blocks[0]} - {"position"})
        if bad:
            raise RouteSpecError(f"unknown elements {bad} in <waypoints>; allowed: <position>")
        return CavSpec(cav_id, points_from_xml(blocks[0].findall("position"), cav_id))
    except RouteSpecError as exc:
        raise RouteSpecError(exc.problem, cav_id=cav_id) from None


def parse_xml(path: str | Path, root_tag: str) -> ET.Element:
    """Root element of an XML file, checked to be ``<root_tag>``; RouteSpecError naming the file otherwise.
    A file larger than ``MAX_FILE_BYTES`` is refused before it is parsed, one with more than
    ``MAX_FILE_WAYPOINTS`` waypoints before any is read."""
    try:
        size = os.stat(path).st_size
        if size > MAX_FILE_BYTES:
            raise RouteSpecError(
                f"the file is {size / 2**20:.1f} MiB, larger than the {MAX_FILE_BYTES // 2**20} MiB a route "
                "file may be",
                path=str(path),
            )
        root = ET.parse(path).getroot()
    except FileNotFoundError:
        raise RouteSpecError("route file not found", path=str(path)) from None
    except (ET.ParseError, OSError, LookupError, UnicodeError) as exc:  # LookupError: unknown encoding
        raise RouteSpecError(f"not readable as XML: {exc}", path=str(path)) from None
    if root.tag != root_tag:
        raise RouteSpecError(f"root element is <{root.tag}>, expected <{root_tag}>", path=str(path))
    count = sum(1 for e in root.iter() if e.tag in ("position", "waypoint"))
    if count > MAX_FILE_WAYPOINTS:
        raise RouteSpecError(
            f"{count} waypoints, more than the {MAX_FILE_WAYPOINTS} a route file may hold", path=str(path)
        )
    return root


def _reported_id(elem: ET.Element, k: int) -> str:
    """The id a route is reported under: its own, or ``#k`` (1-based position) when it has none or a bad
    one."""
    raw_id = elem.get("id")
    return raw_id if raw_id and route_id_problem(raw_id) is None else f"#{k}"


def route_ids(path: str | Path) -> list[str]:
    """The ids of a route file's routes in file order, as :func:`read_routes` reports them (``#k`` for a
    route without a usable id), without reading the routes themselves."""
    return [_reported_id(elem, k) for k, elem in enumerate(parse_xml(path, "routes"), start=1)]


@overload
def read_routes(
    path: str | Path, strict: Literal[True] = True, min_cavs: int = MIN_CAVS
) -> list[RouteSpec]: ...
@overload
def read_routes(
    path: str | Path, strict: Literal[False], min_cavs: int = MIN_CAVS
) -> tuple[list[RouteSpec], list[tuple[str, str]]]: ...
def read_routes(
    path: str | Path, strict: bool = True, min_cavs: int = MIN_CAVS
) -> list[RouteSpec] | tuple[list[RouteSpec], list[tuple[str, str]]]:
    """Read a route file.

    ``strict=True`` raises :class:`RouteSpecError` (naming the file, route and CAV) on the first bad route;
    ``strict=False`` returns ``(good_routes, [(route_id, error message), ...])``. A route without an id is
    reported as ``#k`` (its 1-based position), as is one whose id breaks the id rules
    (:func:`route_id_problem`). A file that cannot be read at all, or is too large (``MAX_FILE_BYTES``,
    ``MAX_FILE_WAYPOINTS``), always raises."""
    root = parse_xml(path, "routes")
    routes: list[RouteSpec] = []
    errors: list[tuple[str, str]] = []
    seen: set[str] = set()
    for k, elem in enumerate(root, start=1):
        raw_id = elem.get("id")
        rid = _reported_id(elem, k)
        try:
            if elem.tag != "route":
                raise RouteSpecError(f"unknown element <{elem.tag}> in <routes>")
            if not raw_id:
                raise RouteSpecError("missing route id")
            problem = route_id_problem(raw_id)
            if problem:
                raise RouteSpecError(problem)
            if rid in seen:
                raise RouteSpecError("duplicate route id")
            seen.add(rid)
            spec = _route_from_xml(elem, min_cavs)
            routes.append(replace(spec, town_dirs=(str(Path(path).resolve().parent),)))
        except RouteSpecError as exc:
            err = exc.within(path=str(path), route_id=rid)
            if strict:
                raise err from None
            errors.append((rid, str(err)))
    return routes if strict else (routes, errors)


# ------------------------------------------------------------------------------------------------- writing
def _num(value: float) -> str:
    return repr(float(value))  # shortest string that reads back to the same float


def _route_to_xml(spec: RouteSpec) -> ET.Element:
    elem = ET.Element(
        "route", {"id": spec.id, "town": spec.town, "weather": spec.weather, "seed": str(spec.seed)}
    )
    for cav in spec.cavs:
        wps = ET.SubElement(ET.SubElement(elem, "cav", {"id": str(cav.id)}), "waypoints")
        for x, y, z in cav.waypoints:
            ET.SubElement(wps, "position", {"x": _num(x), "y": _num(y), "z": _num(z)})
    if spec.scenarios:
        block = ET.SubElement(elem, "scenarios")
        for sc in spec.scenarios:
            s = ET.SubElement(block, "scenario", {"name": sc.name, "type": sc.type})
            ET.SubElement(
                s, "trigger_point", dict(zip(("x", "y", "z", "yaw"), map(_num, sc.trigger), strict=True))
            )
            for key, value in sc.params.items():
                ET.SubElement(s, key, {"value": value} if isinstance(value, str) else dict(value))
    return elem


def route_sha256(spec: RouteSpec) -> str:
    """SHA-256 of a route as a route file writes it: id, town, weather, seed, every CAV's waypoints and the
    scenarios, not the folders its town is looked up in. Equal routes have equal hashes, whichever file
    they were read from (a run's provenance records it per route)."""
    return hashlib.sha256(ET.tostring(_route_to_xml(spec), encoding="utf-8")).hexdigest()


def shift_seeds(routes: Sequence[RouteSpec], seed: int) -> list[RouteSpec]:
    """``routes`` with ``seed`` added to every route's seed (modulo ``MAX_SEED + 1``): the same routes with
    other background traffic and pedestrians (``cmudrive eval --seed``)."""
    if not seed:
        return list(routes)
    return [replace(s, seed=(s.seed + seed) % (MAX_SEED + 1)) for s in routes]


def write_routes(
    routes: Sequence[RouteSpec], path: str | Path, comment: str | None = None, min_cavs: int = MIN_CAVS
) -> None:
    """Write ``routes`` to ``path`` atomically (temporary file + rename); ``read_routes`` gives them back
    exactly. ``comment`` (no ``--`` inside) goes into a header comment."""
    path = Path(path)
    ids = [r.id for r in routes]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise RouteSpecError(f"duplicate route ids {dup}", path=str(path))
    for r in routes:
        if not min_cavs <= len(r.cavs) <= MAX_CAVS:
            raise RouteSpecError(f"needs {min_cavs}-{MAX_CAVS} CAVs, got {len(r.cavs)}", str(path), r.id)
    if comment is not None and ("--" in comment or comment.endswith("-")):
        raise ValueError("an XML comment may not contain '--' or end with '-'")
    root = ET.Element("routes")
    root.extend(_route_to_xml(r) for r in routes)
    ET.indent(root, space="  ")
    text = '<?xml version="1.0" encoding="utf-8"?>\n'
    if comment:
        text += "<!--\n" + "\n".join(f"  {line}".rstrip() for line in comment.splitlines()) + "\n-->\n"
    text += ET.tostring(root, encoding="unicode") + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


__all__ = [
    "MAX_CAVS",
    "MIN_CAVS",
    "CavSpec",
    "RouteSpec",
    "RouteSpecError",
    "ScenarioSpec",
    "points_from_xml",
    "read_routes",
    "route_id_problem",
    "route_ids",
    "route_sha256",
    "scenario_from_xml",
    "shift_seeds",
    "start_conflicts",
    "write_routes",
]
