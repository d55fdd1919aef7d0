"""The benchmark route sets: 44 scenario types x N routes, each route a placed scenario and 2-16 CAVs.

``generate_set("cmudrive220")`` builds the paper's benchmark (Table 1: 220 routes, 2-16 CAVs, mean
6.56): for every type of ``scenario_types.SCENARIO_TYPES`` five routes on different towns or junctions,
under the five weather presets. A route is made in four steps, each drawn from
``numpy.random.default_rng([seed, type index, k, attempt])``:

1. **CAV 0's route** (50-220 m, Bench2Drive-like). Junction types pick a connection through a junction
   of the kind the type needs (turn direction, traffic light / no light / stop sign, T-junction) and
   drive from 20-60 m before it to 30-90 m after it; road types start on a random lane point and plan
   60-200 m ahead. The trigger point lies 3-15 m after the start (as in Bench2Drive-220).
2. **Parameters**: Bench2Drive-220's ranges per type (``route_rules.RULES``, from
   ``reference/SCENARIOS.md``), flow locations derived from the junction's topology
   (:mod:`cmudrive.bench.authoring.flow_places`).
3. **Placement check**: the scenario class is built on the map exactly as the evaluator builds it
   (``REGISTRY[type](spec, ctx)`` computes every actor's place at construction); a ``ScenarioError``
   or a broken placement rule of :mod:`cmudrive.bench.route_rules` (CAV 0's route reaches the scenario's
   end, no junction inside InvadingTurn, HighwayCutIn's car merges from a ramp into CAV 0's lane)
   rejects the candidate and the next attempt is drawn.
4. **Other CAVs** by :func:`route_gen.add_cavs` (own lanes near CAV 0's start, off the lanes of CAV 0's
   first 60 m and of the 60 m after the trigger, starts >= 15 m apart), with the route's drawn count; a
   draw where a CAV starts against a scenario actor (``cav-clear-of-actors``) is rejected as well.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass

import numpy as np

from cmudrive.bench.authoring.flow_places import FLOW_PLACERS
from cmudrive.bench.authoring.route_gen import MIN_START_GAP, add_cavs
from cmudrive.bench.authoring.route_geometry import (
    COORD_DECIMALS,
    LANE_END_MARGIN,
    Topology,
    carla_points,
    route_keypoints,
)
from cmudrive.bench.authoring.route_rules import RULES, TypeRule
from cmudrive.bench.route_check import build_placed
from cmudrive.bench.route_rules import rule_violations
from cmudrive.bench.routes import CavSpec, RouteSpec, ScenarioSpec
from cmudrive.bench.scenario_types import SCENARIO_TYPES
from cmudrive.bench.scenarios.base import first_real_junction
from cmudrive.bench.scenarios.flows import VehicleFlow
from cmudrive.bench.scenarios.params import ScenarioError
from cmudrive.bench.scenarios.placement import LanePoint, walk
from cmudrive.maps import LanePos, RoadMap, RoadOption, Route, RouteError, densify, load_map
from cmudrive.maps.coords import map_to_carla
from cmudrive.maps.model import JunctionKind, TurnDir

PRESETS = ("ClearNoon", "CloudySunset", "HardRainNoon", "ClearNight", "FogMorning")
ROUTE_LENGTH = (50.0, 220.0)  # [m] CAV 0's dense route
ROAD_ROUTE = (60.0, 200.0)  # [m] planned length of a road type's CAV 0 route
BEFORE_JUNCTION = (20.0, 60.0)  # [m] a junction type's start before the junction entry
AFTER_JUNCTION = (30.0, 90.0)  # [m] its goal past the junction exit
JUNCTION_CAV_ROUTE = (100.0, 250.0)  # [m] planned route of a CAV from another entry of the junction
ATTEMPTS_PER_TOWN = 40  # [-] candidates tried per town before the next town is tried
SAME_PLACE = 30.0  # [m] two triggers of one type closer than this are the same place
CAV_RANGE = (2, 16)  # [-] CAVs per route (paper Table 1)
CAV_MEAN = 6.56  # [-] mean CAVs per route of the 220 (paper Table 1)


# ------------------------------------------------------------------------------------------ route pieces
class _Town:
    """A loaded town with its generation queries (cached per process)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.map = load_map(name)
        self.topo = Topology(self.map)
        m = self.map
        links = np.flatnonzero(
            ~m.lane_internal[m.link_from]
            & ~m.lane_internal[m.link_to]
            & m.driving[m.link_from]
            & m.driving[m.link_to]
            & (m.link_junction >= 0)
            & (m.link_dir != TurnDir.TURN)
        )
        self.links = links  # (k,) candidate links of junction types
        approaches = {}
        for j in np.unique(m.link_junction[links]).tolist():
            here = links[m.link_junction[links] == j]
            approaches[j] = len(np.unique(m.lane_edge[m.link_from[here]]))
        self.approaches = approaches  # junction -> number of incoming driving edges


_TOWNS: dict[str, _Town] = {}


def _town(name: str) -> _Town:
    if name not in _TOWNS:
        _TOWNS[name] = _Town(name)
    return _TOWNS[name]


def _turn_ok(direction: int, want: str) -> bool:
    left = direction in (TurnDir.LEFT, TurnDir.PARTLY_LEFT)
    right = direction in (TurnDir.RIGHT, TurnDir.PARTLY_RIGHT)
    return {
        "left": left,
        "right": right,
        "straight": direction == TurnDir.STRAIGHT,
        "turn": left or right,
        "any": True,
    }[want]


def _control_ok(m: RoadMap, link: int, want: str) -> bool:
    j = int(m.link_junction[link])
    signal = int(m.link_tls[link]) >= 0
    stop = str(m.link_state[link]) in ("s", "w")  # this approach must stop
    return {
        "signal": signal,
        "nosignal": not signal and int(m.junction_kind[j]) != JunctionKind.TRAFFIC_LIGHT,
        "stop": stop and not signal,
        "any": True,
    }[want]


def _junction_route(town: _Town, rule: TypeRule, rng: np.random.Generator) -> Route | None:
    """A route through a junction link of the kind ``rule`` asks for."""
    m = town.map
    ok = [
        k
        for k in town.links.tolist()
        if _turn_ok(int(m.link_dir[k]), rule.junction)
        and _control_ok(m, k, rule.control)
        and (not rule.three_way or town.approaches.get(int(m.link_junction[k]), 0) == 3)
    ]
    if not ok:
        return None
    link = int(rng.choice(ok))
    a, b = int(m.link_from[link]), int(m.link_to[link])
    before = float(rng.uniform(*BEFORE_JUNCTION))
    before = max(before, rule.trigger_at[1] + 10.0)
    start = walk_back(m, a, before)
    goal = walk_fwd(m, b, float(rng.uniform(*(rule.after_junction or AFTER_JUNCTION))))
    try:
        route = town.topo.planner.plan_lanes(LanePos(start[0], start[1]), LanePos(goal[0], goal[1]))
    except RouteError:
        return None
    if a not in route.path.tolist() or b not in route.path.tolist():
        return None
    return route


def walk_back(m: RoadMap, lane: int, d: float) -> tuple[int, float]:
    p = walk(m, LanePoint(lane, float(m.lane_length[lane])), -d, through_junctions=False)
    return p.lane, max(p.s, 0.5)


def walk_fwd(m: RoadMap, lane: int, d: float) -> tuple[int, float]:
    p = walk(m, LanePoint(lane, 0.0), d, through_junctions=False)
    return p.lane, min(p.s, float(m.lane_length[p.lane]) - 0.5)


def _shift_route(town: _Town, rng: np.random.Generator) -> Route | None:
    """A route from the right lane of a road with >= 3 same-direction lanes to its lane two to the left,
    90-180 m ahead (the planner inserts the two lane changes)."""
    m, topo = town.map, town.topo
    left = m.lane_left
    ok = np.flatnonzero(
        topo.normal[topo.cand_lane]
        & (left[topo.cand_lane] >= 0)
        & (left[np.maximum(left[topo.cand_lane], 0)] >= 0)
    )
    if len(ok) == 0:
        return None
    pick = int(rng.choice(ok))
    lane, s = int(topo.cand_lane[pick]), float(topo.cand_s[pick])
    target = int(left[left[lane]])
    if not m.driving[target]:
        return None
    s_target, _ = m.index.project(topo.cand_xy[pick][None], np.array([target]))
    goal = walk(
        m, LanePoint(target, float(s_target[0])), float(rng.uniform(90.0, 180.0)), through_junctions=True
    )
    if m.lane_internal[goal.lane]:
        return None
    try:
        route = topo.planner.plan_lanes(LanePos(lane, s), LanePos(goal.lane, goal.s))
    except RouteError:
        return None
    return route


def _left_changes(route: Route) -> int:
    """Number of left lane changes along a dense route (runs of CHANGELANELEFT points)."""
    change = route.option == RoadOption.CHANGELANELEFT
    return int(np.sum(change[1:] & ~change[:-1]) + int(change[0]))


def _road_route(town: _Town, rng: np.random.Generator) -> Route | None:
    topo = town.topo
    pick = int(rng.integers(len(topo.cand_lane)))
    start = LanePos(int(topo.cand_lane[pick]), float(topo.cand_s[pick]))
    plan = topo.plan_from(start, ROAD_ROUTE, rng)
    if plan is None:
        return None
    try:
        return densify(town.map, plan[0])
    except RouteError:
        return None


def _draw_params(rule: TypeRule, rng: np.random.Generator) -> dict[str, str | dict[str, str]]:
    out: dict[str, str | dict[str, str]] = {}
    for name, spec in rule.params:
        if isinstance(spec, str):
            out[name] = spec
        elif isinstance(spec[0], str):  # choices
            out[name] = str(spec[int(rng.integers(len(spec)))])
        elif isinstance(spec[0], tuple):  # a from/to range
            lo, hi = spec
            a = int(rng.integers(lo[0], lo[1] + 1))
            b = int(rng.integers(max(hi[0], a), hi[1] + 1))
            out[name] = {"from": str(a), "to": str(b)}
        elif isinstance(spec[0], float):
            out[name] = repr(round(float(rng.uniform(spec[0], spec[1])), 2))
        else:
            out[name] = str(int(rng.integers(spec[0], spec[1] + 1)))
    return out


# ----------------------------------------------------------------------------------------------- a route
@dataclass(frozen=True)
class _Candidate:
    spec: RouteSpec  # CAV 0 only
    place: tuple[str, int, float, float]  # town, junction (-1 for road types), trigger x, y (map frame)


def _candidate(
    type_name: str, town: _Town, rng: np.random.Generator, route_id: str, weather: str, seed: int
) -> _Candidate | None:
    rule, m = RULES[type_name], town.map
    if rule.junction:
        route = _junction_route(town, rule, rng)
    else:
        route = _shift_route(town, rng) if rule.lane_shift else _road_route(town, rng)
    if route is None or not ROUTE_LENGTH[0] <= route.length <= ROUTE_LENGTH[1]:
        return None
    keypoints = np.round(route_keypoints(route), COORD_DECIMALS)
    try:
        dense = densify(m, keypoints)
    except RouteError:
        return None
    if (
        abs(dense.length - route.length) > 0.05 * route.length
        or not ROUTE_LENGTH[0] <= dense.length <= ROUTE_LENGTH[1]
    ):
        return None
    if rule.lane_shift and _left_changes(dense) < 2:
        return None
    k0 = int(np.searchsorted(dense.distance, float(rng.uniform(*rule.trigger_at))))
    if k0 >= len(dense) - 1 or dense.in_junction[k0]:
        return None
    junction = -1
    if rule.junction:
        first = first_real_junction(m, dense, k0)
        if first < 0 or dense.distance[first] - dense.distance[k0] < 5.0:
            return None
        junction = int(m.lane_junction[dense.lane[first]])
    params = _draw_params(rule, rng)
    if type_name.startswith("OppositeVehicle"):
        params["direction"] = _adversary_side(m, dense, k0, rng)
    placer = FLOW_PLACERS.get(type_name)
    if placer is not None:
        where = placer(m, dense, k0, rng)
        if where is None:
            return None
        params = {**where, **params}
    xy = map_to_carla(dense.xy[k0][None])[0]
    yaw = round(-math.degrees(float(dense.heading[k0])), 1) + 0.0
    trigger = (round(float(xy[0]), 2) + 0.0, round(float(xy[1]), 2) + 0.0, 0.0, yaw)
    sc = ScenarioSpec(f"{type_name}_1", type_name, trigger, params)
    spec = RouteSpec(route_id, town.name, weather, seed, (CavSpec(0, carla_points(keypoints)),), (sc,))
    try:
        placed = build_placed(spec, m, [dense])
    except ScenarioError:
        return None
    if rule_violations([dense], placed):  # CAV 0's layout breaks what the type needs
        return None
    return _Candidate(spec, (town.name, junction, float(dense.xy[k0, 0]), float(dense.xy[k0, 1])))


def actor_lanes(scenarios: Sequence[object]) -> set[int]:
    """Lanes the placed scenarios' actors and flows use: every ``LanePoint`` and every flow's lane path
    found among the scenario objects' attributes (one level into lists, tuples and pairs)."""
    out: set[int] = set()

    def visit(value: object, depth: int) -> None:
        if isinstance(value, LanePoint):
            out.add(int(value.lane))
        elif isinstance(value, VehicleFlow):
            out.update(int(x) for x in value.path.path)
        elif isinstance(value, (list, tuple)) and depth < 2:
            for v in value:
                visit(v, depth + 1)

    for sc in scenarios:
        for value in vars(sc).values():
            visit(value, 0)
    return out


def _junction_cavs(
    spec: RouteSpec, town: _Town, junction: int, n_add: int, rng: np.random.Generator, avoid: set[int]
) -> RouteSpec:
    """``spec`` with up to ``n_add`` CAVs that start 20-50 m up other entry lanes of CAV 0's junction (one
    per lane, off ``avoid``, >= ``MIN_START_GAP`` m from other starts) and drive through it 100-250 m."""
    m, topo = town.map, town.topo
    dense = spec.dense_routes(m)
    starts = [r.xy[0] for r in dense]
    own = {int(x) for r in dense for x in r.path}
    lanes = np.unique(
        m.link_from[(m.link_junction == junction) & m.driving[m.link_from] & ~m.lane_internal[m.link_from]]
    )
    cavs = list(spec.cavs)
    for lane in rng.permutation(lanes).tolist():
        if len(cavs) - len(spec.cavs) >= n_add:
            break
        if lane in avoid or lane in own:
            continue
        s = float(m.lane_length[lane]) - float(rng.uniform(20.0, 50.0))
        if s < LANE_END_MARGIN:
            continue
        xy = m.index.frenet_to_xy(np.array([lane]), np.array([s]))[0]
        if min(float(np.linalg.norm(xy - p)) for p in starts) < MIN_START_GAP:
            continue
        plan = topo.plan_from(LanePos(int(lane), s), JUNCTION_CAV_ROUTE, rng)
        if plan is None:
            continue
        cavs.append(CavSpec(len(cavs), carla_points(plan[0])))
        starts.append(xy)
        own.add(int(lane))
    return dataclasses.replace(spec, cavs=tuple(cavs))


def _adversary_side(m: RoadMap, route: Route, k0: int, rng: np.random.Generator) -> str:
    """The approach of the OppositeVehicle* adversary, so that its straight path crosses CAV 0's: for a left
    turn the opposite approach or the right one, for a right turn the left one, straight on left or right
    (Bench2Drive-220's pairs)."""
    first = first_real_junction(m, route, k0)
    after = np.flatnonzero(~route.in_junction[first:]) + first
    end = int(after[0]) if len(after) else len(route) - 1
    turn = (route.heading[end] - route.heading[first - 1] + math.pi) % (2 * math.pi) - math.pi
    if turn > math.radians(30.0):
        options: tuple[str, ...] = ("opposite", "right")
    elif turn < -math.radians(30.0):
        options = ("left",)
    else:
        options = ("left", "right")
    return options[int(rng.integers(len(options)))]


def _taken(place: tuple[str, int, float, float], used: Sequence[tuple[str, int, float, float]]) -> bool:
    town, junction, x, y = place
    for t, j, ux, uy in used:
        if t == town and ((junction >= 0 and j == junction) or math.hypot(x - ux, y - uy) < SAME_PLACE):
            return True
    return False


def _route_key(spec: RouteSpec) -> bytes:
    """CAV 0's waypoints as bytes: two routes with the same key drive CAV 0 the same way."""
    return spec.cavs[0].waypoints.tobytes()


def generate_route(
    type_name: str,
    k: int,
    num_cavs: int,
    weather: str,
    seed: int,
    route_id: str,
    sumo_seed: int,
    used: Sequence[tuple[str, int, float, float]] = (),
    taken_routes: Collection[bytes] = (),
) -> tuple[RouteSpec, tuple[str, int, float, float]]:
    """Route ``k`` of a type: a placed scenario on a town of the type's list (route ``k`` tries
    ``towns[k % len]`` first, towns this type has used least before others) at a place not in ``used``,
    whose CAV 0 waypoints (``_route_key``) are not in ``taken_routes``, with ``num_cavs`` CAVs.
    RouteError when no town of the list has one."""
    ti = SCENARIO_TYPES.index(type_name)
    towns = RULES[type_name].towns
    order = [towns[(k + i) % len(towns)] for i in range(len(towns))]
    counts = {t: sum(1 for u in used if u[0] == t) for t in towns}
    order.sort(key=lambda t: counts[t])  # stable: the rotation breaks ties
    for town_name in order:
        town = _town(town_name)
        ti_town = towns.index(town_name)
        for attempt in range(ATTEMPTS_PER_TOWN):
            rng = np.random.default_rng([seed, ti, k, ti_town, attempt])
            cand = _candidate(type_name, town, rng, route_id, weather, sumo_seed)
            if cand is None or _taken(cand.place, used) or _route_key(cand.spec) in taken_routes:
                continue
            spec, m = cand.spec, town.map
            avoid = actor_lanes(build_placed(spec, m, spec.dense_routes(m)))
            if cand.place[1] >= 0:  # junction types: CAVs from the junction's other entries first
                n_add = num_cavs // 2  # about half of the added CAVs
                spec = _junction_cavs(spec, town, cand.place[1], n_add, rng, avoid)
            try:
                spec = add_cavs(spec, num_cavs, rng, m, avoid_lanes=avoid)
            except RouteError:
                continue
            routes = spec.dense_routes(m)
            if rule_violations(routes, build_placed(spec, m, routes)):  # a CAV starts against an actor
                continue
            return spec, cand.place
    raise RouteError(f"{type_name}: no route {k} with {num_cavs} CAVs on {', '.join(towns)}")


# ------------------------------------------------------------------------------------------- route sets
def cav_counts(n: int, seed: int, mean: float = CAV_MEAN, bounds: tuple[int, int] = CAV_RANGE) -> np.ndarray:
    """(n,) int CAV counts with min ``bounds[0]``, max ``bounds[1]`` (each at least once) and sum
    round(mean * n): a right-skewed draw (2 + exponential), clipped, then nudged one CAV at a time."""
    lo, hi = bounds
    rng = np.random.default_rng([seed, 6])
    c = np.clip(np.rint(lo + rng.exponential(mean - lo, n)), lo, hi).astype(np.int64)
    if n >= 2:
        c[0 if n < 3 else int(rng.integers(n))] = lo
        fixed = set(np.flatnonzero(c == lo)[:1].tolist())
        free = [i for i in range(n) if i not in fixed]
        c[free[int(rng.integers(len(free)))]] = hi
        fixed |= set(np.flatnonzero(c == hi)[:1].tolist())
    else:
        fixed = set()
    target = round(mean * n)
    while int(c.sum()) != target:
        step = 1 if c.sum() < target else -1
        ok = [i for i in range(n) if i not in fixed and lo <= c[i] + step <= hi]
        if not ok:
            break
        c[ok[int(rng.integers(len(ok)))]] += step
    return c


@dataclass(frozen=True)
class RouteSet:
    """A named route set: ``per_type`` routes of every type (``one_per_type``: only route ``i % per_type``
    of type ``i``, so that the mini split spreads over towns and weathers as the full set does)."""

    name: str
    seed: int
    per_type: int
    id_prefix: str = ""
    one_per_type: bool = False
    avoid: str = ""  # a route set whose places this one stays away from


ROUTE_SETS: dict[str, RouteSet] = {
    "cmudrive220": RouteSet("cmudrive220", 0, 5),
    "cmudrive44": RouteSet("cmudrive44", 0, 5, one_per_type=True),
    "training": RouteSet("training", 1, 3, id_prefix="train_", avoid="cmudrive220"),
}


def _places(specs: Sequence[RouteSpec]) -> dict[str, list[tuple[str, int, float, float]]]:
    out: dict[str, list[tuple[str, int, float, float]]] = {}
    for spec in specs:
        for sc in spec.scenarios:
            x, y, _ = sc.map_trigger()
            out.setdefault(sc.type, []).append((spec.town, -1, x, y))
    return out


def generate_set(
    name: str,
    types: Sequence[str] = SCENARIO_TYPES,
    avoid: Sequence[RouteSpec] | None = None,
    progress: Callable[[str], None] | None = None,
) -> list[RouteSpec]:
    """The routes of the named set (``ROUTE_SETS``) for ``types`` (all 44 by default), deterministic.

    The CAV counts are drawn over the whole set (all 44 types) so that a subset of types gets the counts
    it has in the full set. ``avoid`` (default: the set named by ``avoid``, generated) gives places the
    set must not reuse (per type: trigger places; any type: CAV 0 routes)."""
    rs = ROUTE_SETS[name]
    if rs.avoid and avoid is None:
        avoid = generate_set(rs.avoid, types)
    far = _places(avoid or [])
    taken = {_route_key(spec) for spec in avoid or []}  # another type's CAV 0 route there is taken too
    counts = cav_counts(len(SCENARIO_TYPES) * rs.per_type, rs.seed)
    out = []
    for type_name in types:
        ti = SCENARIO_TYPES.index(type_name)
        used = list(far.get(type_name, []))
        keep = ti % rs.per_type if rs.one_per_type else -1
        for k in range(keep + 1 if rs.one_per_type else rs.per_type):
            index = ti * rs.per_type + k
            weather = PRESETS[(ti + k + rs.seed) % len(PRESETS)]
            spec, place = generate_route(
                type_name,
                k,
                int(counts[index]),
                weather,
                rs.seed,
                f"{rs.id_prefix}{type_name}_{k}",
                index,
                used,
                taken,
            )
            used.append(place)
            if keep >= 0 and k != keep:
                continue
            out.append(spec)
            if progress is not None:
                progress(f"{spec.id}: {spec.town}, {len(spec.cavs)} CAVs")
    return out


def set_stats(specs: Sequence[RouteSpec]) -> dict[str, object]:
    """Table 1's row and the per-type, per-town and per-weather counts of a route set."""
    n = np.array([len(s.cavs) for s in specs])

    def count(key: Callable[[RouteSpec], str]) -> dict[str, int]:
        out: dict[str, int] = {}
        for s in specs:
            out[key(s)] = out.get(key(s), 0) + 1
        return out

    return {
        "routes": len(specs),
        "min": int(n.min()) if len(n) else 0,
        "max": int(n.max()) if len(n) else 0,
        "avg": float(n.mean()) if len(n) else 0.0,
        "types": count(lambda s: s.scenarios[0].type if s.scenarios else "-"),
        "towns": count(lambda s: s.town),
        "weathers": count(lambda s: s.weather),
    }


def stats_lines(specs: Sequence[RouteSpec]) -> list[str]:
    """Plain-text stats for a file's header: Table 1's row, then towns and weathers."""
    st = set_stats(specs)
    towns = st["towns"]
    weathers = st["weathers"]
    assert isinstance(towns, dict) and isinstance(weathers, dict)
    return [
        f"{st['routes']} routes, CAVs per route min {st['min']}, max {st['max']}, avg {st['avg']:.2f}",
        "towns: " + ", ".join(f"{k} {v}" for k, v in sorted(towns.items())),
        "weathers: " + ", ".join(f"{k} {v}" for k, v in weathers.items()),
    ]


__all__ = [
    "PRESETS",
    "ROUTE_SETS",
    "RouteSet",
    "actor_lanes",
    "cav_counts",
    "generate_route",
    "generate_set",
    "set_stats",
    "stats_lines",
]
