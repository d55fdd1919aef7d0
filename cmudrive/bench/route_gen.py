"""Generated multi-CAV routes: extra CAVs around a scenario route, and scenario-free route sets.

The paper: "starting locations and destinations of the additional cooperative vehicles are automatically
generated according to the road topology of each scenario". ``add_cavs`` starts each added CAV on its own
lane within a ring around CAV 0's start, away from the lanes CAV 0 and its scenarios use at first, and
plans it a route through the lane graph; ``generate_routes`` makes scenario-free routes for smoke tests.
Routes are stored as sparse keypoints (CARLA coordinates), as route files hold them.

``cmudrive routes generate -o FILE ...`` (or ``python -m cmudrive.bench.route_gen generate ...``) writes
a route file and records the command in its header.
"""

from __future__ import annotations

import argparse
import dataclasses
import heapq
import sys
from collections.abc import Collection, Sequence
from pathlib import Path

import numpy as np

from cmudrive.bench.routes import MAX_CAVS, CavSpec, RouteSpec, ScenarioSpec, write_routes
from cmudrive.maps import LanePos, RoadMap, RoadOption, Route, RouteError, RoutePlanner, densify, load_map
from cmudrive.maps.cache import resolve_map_path
from cmudrive.maps.coords import map_to_carla
from cmudrive.sim.weather import get_weather

START_RING = (30.0, 150.0)  # [m] straight-line distance of an added CAV's start from CAV 0's start
START_RING_WIDENED = (250.0, 400.0)  # [m] outer radii tried in turn when the ring has too few free lanes
MIN_START_GAP = 15.0  # [m] between the starts of any two CAVs
SCENARIO_CLEARANCE = 60.0  # [m] of CAV 0's route ahead: no other CAV starts on the lanes it uses there
MIN_CAV_ROUTE = 150.0  # [m] shortest route of an added CAV
MAX_CAV_ROUTE_FACTOR = 1.0  # [-] added CAVs' routes are at most this times CAV 0's route (but >= 250 m)
MIN_MAX_CAV_ROUTE = 250.0  # [m] floor of that upper bound
KEYPOINT_SPACING = 50.0  # [m] between stored keypoints of a generated route
LANE_END_MARGIN = 8.0  # [m] starts and goals keep this far from both ends of their lane
CANDIDATE_STEP = 5.0  # [m] spacing of candidate start points along a lane
DENSIFY_TOLERANCE = (
    0.05  # [-] relative length difference allowed between the plan and its densified keypoints
)
COORD_DECIMALS = 2  # generated coordinates are rounded to 1 cm
GOAL_ATTEMPTS = 12  # [-] destinations tried per start before the start is given up
ROUTE_ATTEMPTS = 50  # [-] CAV 0 routes tried per generated route


# ---------------------------------------------------------------------------------------------- generation
class _Topology:
    """Lane-graph queries for generation: candidate start points, reachability, keypoints."""

    def __init__(self, road_map: RoadMap) -> None:
        m = road_map
        self.map = m
        self.planner = RoutePlanner(m)
        self.driving = m.driving
        normal = m.driving & ~m.lane_internal & (m.lane_length > 2.0 * LANE_END_MARGIN)
        lanes, s = [], []
        for lane in np.flatnonzero(normal):
            ss = np.arange(LANE_END_MARGIN, m.lane_length[lane] - LANE_END_MARGIN + 1e-9, CANDIDATE_STEP)
            lanes.append(np.full(len(ss), lane))
            s.append(ss)
        self.normal = normal
        self.cand_lane = np.concatenate(lanes).astype(np.int64)  # (C,) candidate start points
        self.cand_s = np.concatenate(s)
        self.cand_xy = m.index.frenet_to_xy(self.cand_lane, self.cand_s)  # (C, 2) [m]

    def entry_distance(self, start: LanePos) -> np.ndarray:
        """(N,) distance [m] along lane successors from ``start`` to the beginning of every lane (inf if
        unreachable without lane changes); the start lane itself gets ``-start.s``."""
        m = self.map
        dist = np.full(m.num_lanes, np.inf)
        dist[start.lane] = -start.s
        heap = [(-start.s, start.lane)]
        done = np.zeros(m.num_lanes, bool)
        while heap:
            d, lane = heapq.heappop(heap)
            if done[lane]:
                continue
            done[lane] = True
            reach = d + m.lane_length[lane]
            for nxt in m.successors(lane).tolist():
                if self.driving[nxt] and reach < dist[nxt] and nxt != start.lane:
                    dist[nxt] = reach
                    heapq.heappush(heap, (reach, nxt))
        return dist

    def plan_from(
        self, start: LanePos, length: tuple[float, float], rng: np.random.Generator
    ) -> tuple[np.ndarray, float] | None:
        """Keypoints (m, 2) [map frame] and length [m] of a route from ``start`` whose planned length lies in
        ``length`` and whose keypoints densify back to it; None when no destination works."""
        m = self.map
        entry = self.entry_distance(start)
        lo = np.maximum(length[0] - entry, LANE_END_MARGIN)  # s range on each lane for the goal
        hi = np.minimum(length[1] - entry, m.lane_length - LANE_END_MARGIN)
        options = np.flatnonzero(self.normal & np.isfinite(entry) & (hi > lo))
        for lane in rng.permutation(options)[:GOAL_ATTEMPTS].tolist():
            goal = LanePos(int(lane), float(rng.uniform(lo[lane], hi[lane])))
            try:
                route = self.planner.plan_lanes(start, goal)
            except RouteError:
                continue
            if not length[0] <= route.length <= length[1]:
                continue
            keypoints = np.round(_keypoints(route), COORD_DECIMALS)
            try:
                dense = densify(m, keypoints)
            except RouteError:
                continue
            same = abs(dense.length - route.length) <= DENSIFY_TOLERANCE * route.length
            if same and length[0] <= dense.length <= length[1]:
                return keypoints, dense.length
        return None


def _keypoints(route: Route) -> np.ndarray:
    """Sparse keypoints (m, 2) of a dense route: its start, a point every ~``KEYPOINT_SPACING`` m (moved
    forward off junctions and lane changes, where lanes overlap), and its end."""
    calm = ~route.in_junction & (route.option == RoadOption.LANEFOLLOW)
    last = len(route) - 1
    picks = [0]
    for target in np.arange(KEYPOINT_SPACING, route.length - 0.5 * KEYPOINT_SPACING, KEYPOINT_SPACING):
        ok = np.flatnonzero(calm & (route.distance >= target) & (route.distance < route.length - 10.0))
        if len(ok) and ok[0] > picks[-1] and route.distance[ok[0]] - route.distance[picks[-1]] >= 20.0:
            picks.append(int(ok[0]))
    picks.append(last)
    return route.xy[picks]


def _carla_points(keypoints_map: np.ndarray) -> np.ndarray:
    """Map-frame keypoints (m, 2) -> CARLA (m, 3) with z = 0 (our maps are flat), rounded to 1 cm."""
    xy = map_to_carla(keypoints_map) + 0.0  # + 0.0 turns -0.0 into 0.0
    return np.round(np.column_stack([xy, np.zeros(len(xy))]), COORD_DECIMALS) + 0.0


def _clear_lanes(route0: Route, scenarios: Sequence[ScenarioSpec]) -> set[int]:
    """Lanes of CAV 0's route in its first ``SCENARIO_CLEARANCE`` m and in the ``SCENARIO_CLEARANCE`` m
    after each scenario trigger (the route point nearest the trigger)."""
    keep = route0.distance <= SCENARIO_CLEARANCE
    for sc in scenarios:
        x, y, _ = sc.map_trigger()
        at = route0.distance[int(np.argmin(np.linalg.norm(route0.xy - [x, y], axis=1)))]
        keep |= (route0.distance >= at) & (route0.distance <= at + SCENARIO_CLEARANCE)
    return {int(k) for k in np.unique(route0.lane[keep])}


def add_cavs(
    spec: RouteSpec,
    n_total: int,
    rng: np.random.Generator,
    road_map: RoadMap | None = None,
    length: tuple[float, float] | None = None,
    avoid_lanes: Collection[int] = (),
) -> RouteSpec:
    """``spec`` with CAVs added until it has ``n_total`` (existing CAVs are kept).

    Each added CAV starts on a normal driving lane no other CAV starts on, ``START_RING`` (30-150 m,
    straight line) from CAV 0's start, at least ``MIN_START_GAP`` m from every other start, and off the
    lanes CAV 0 drives in its first ``SCENARIO_CLEARANCE`` m and in the ``SCENARIO_CLEARANCE`` m after each
    scenario trigger and off ``avoid_lanes`` (e.g. the lanes of the scenario's actors); the ring widens
    (``START_RING_WIDENED``) when it has too few free lanes. It drives to
    a destination reachable along the lane graph, ``length`` metres away (default: ``MIN_CAV_ROUTE`` to
    max(CAV 0's length, ``MIN_MAX_CAV_ROUTE``)). Routes are stored as keypoints every ~50 m plus the end,
    CARLA frame, z = 0. RouteError naming the route when CAV 0's route is not on the map or too few fit."""
    if not len(spec.cavs) <= n_total <= MAX_CAVS:
        raise ValueError(f"route {spec.id!r}: n_total must be in {len(spec.cavs)}..{MAX_CAVS}, got {n_total}")
    if n_total == len(spec.cavs):
        return spec
    road_map = road_map if road_map is not None else load_map(spec.town_path())
    topo = _Topology(road_map)
    where = f"route {spec.id!r} on {road_map.name!r}"
    dense = spec.dense_routes(road_map)
    route0 = dense[0]
    starts = [r.xy[0] for r in dense]
    used = (
        {int(r.lane[0]) for r in dense} | _clear_lanes(route0, spec.scenarios) | {int(x) for x in avoid_lanes}
    )
    if length is None:
        length = (MIN_CAV_ROUTE, max(MAX_CAV_ROUTE_FACTOR * route0.length, MIN_MAX_CAV_ROUTE))
    radius = np.linalg.norm(topo.cand_xy - route0.xy[0], axis=1)
    cavs = list(spec.cavs)
    tried: set[int] = set()
    for outer in (START_RING[1], *START_RING_WIDENED):
        in_ring = (radius >= START_RING[0]) & (radius <= outer)
        for lane in rng.permutation(np.unique(topo.cand_lane[in_ring])).tolist():
            if len(cavs) == n_total:
                break
            if lane in used or lane in tried:
                continue
            tried.add(lane)
            points = np.flatnonzero(in_ring & (topo.cand_lane == lane))
            gaps = np.min(np.linalg.norm(topo.cand_xy[points, None] - np.array(starts)[None], axis=2), axis=1)
            points = points[gaps >= MIN_START_GAP]
            if len(points) == 0:
                continue
            pick = int(rng.choice(points))
            plan = topo.plan_from(LanePos(lane, float(topo.cand_s[pick])), length, rng)
            if plan is None:
                continue
            cavs.append(CavSpec(len(cavs), _carla_points(plan[0])))
            starts.append(topo.cand_xy[pick])
            used.add(lane)
    if len(cavs) < n_total:
        raise RouteError(
            f"{where}: found starts for only {len(cavs)} of {n_total} CAVs within "
            f"{START_RING_WIDENED[-1]:.0f} m of CAV 0's start (distinct lanes, "
            f">= {MIN_START_GAP:.0f} m apart, routes >= {MIN_CAV_ROUTE:.0f} m)"
        )
    return dataclasses.replace(spec, cavs=tuple(cavs))


def generate_routes(
    town: str,
    num_routes: int,
    num_cavs: int,
    weather: str = "ClearNoon",
    seed: int = 0,
    length: tuple[float, float] = (200.0, 400.0),
) -> list[RouteSpec]:
    """``num_routes`` scenario-free routes on ``town`` with ``num_cavs`` CAVs each, deterministic by ``seed``.

    Every CAV drives ``length`` metres (min, max): CAV 0 from a random normal driving lane, the others
    placed by :func:`add_cavs`. Route ``i`` is drawn from ``numpy.random.default_rng([seed, i])``, has id
    ``<town>_<i:03d>`` and SUMO seed ``seed + i``."""
    get_weather(weather)  # ValueError naming the presets
    if not 1 <= num_cavs <= MAX_CAVS:
        raise ValueError(f"num_cavs must be in 1..{MAX_CAVS}, got {num_cavs}")
    if num_routes < 0 or not 0.0 < length[0] <= length[1]:
        raise ValueError(f"need num_routes >= 0 and 0 < min length <= max length, got {num_routes}, {length}")
    path = resolve_map_path(town)
    road_map = load_map(path)
    # a network file keeps only its town's name in the route file (movable: see RouteSpec.town_dirs)
    name, town_dirs = (road_map.name, (str(path.resolve().parent),)) if Path(town) == path else (town, ())
    topo = _Topology(road_map)
    out = []
    for i in range(num_routes):
        rng = np.random.default_rng([seed, i])
        last: Exception | None = None
        for _ in range(ROUTE_ATTEMPTS):
            pick = int(rng.integers(len(topo.cand_lane)))
            plan = topo.plan_from(LanePos(int(topo.cand_lane[pick]), float(topo.cand_s[pick])), length, rng)
            if plan is None:
                continue
            spec = RouteSpec(
                f"{road_map.name}_{i:03d}",
                name,
                weather,
                seed + i,
                (CavSpec(0, _carla_points(plan[0])),),
                town_dirs=town_dirs,
            )
            try:
                out.append(add_cavs(spec, num_cavs, rng, road_map, length))
                break
            except RouteError as exc:
                last = exc
        else:
            raise RouteError(
                f"no route of {length[0]:.0f}-{length[1]:.0f} m with {num_cavs} CAVs on {town!r}: {last}"
            )
    return out


def generate_route_set(
    entries: Sequence[tuple[str, int, str]],
    seed: int = 0,
    length: tuple[float, float] = (200.0, 400.0),
    id_prefix: str = "route",
) -> list[RouteSpec]:
    """One route per ``(town, num_cavs, weather)`` entry; entry ``j`` is ``generate_routes(town, 1, num_cavs,
    weather, seed + j, length)`` renamed ``<id_prefix>_<j:02d>``."""
    return [
        dataclasses.replace(
            generate_routes(town, 1, cavs, weather, seed + j, length)[0], id=f"{id_prefix}_{j:02d}"
        )
        for j, (town, cavs, weather) in enumerate(entries)
    ]


# --------------------------------------------------------------------------------------------------- CLI
def _summary(specs: Sequence[RouteSpec]) -> list[str]:
    lines = []
    for spec in specs:
        m = load_map(spec.town_path())
        lengths = [densify(m, spec.map_waypoints(c.id)).length for c in spec.cavs]
        lines.append(
            f"{spec.id}: {spec.town}, {spec.weather}, seed {spec.seed}, {len(spec.cavs)} CAVs, "
            f"route lengths {', '.join(f'{v:.0f}' for v in lengths)} m"
        )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    """``cmudrive routes generate -o FILE [-s SEED] [-l MIN MAX] [-p PREFIX] [-c CAVS]
    [-w WEATHER] TOWN[:CAVS[:WEATHER]] ...``: one generated route per entry, written to FILE with the
    command and a summary in its header comment; or ``cmudrive routes generate -b NAME -o FILE``: the
    named benchmark route set (``benchmark_gen.ROUTE_SETS``). Options are written single-dash in the
    header because an XML comment cannot hold ``--``."""
    parser = argparse.ArgumentParser(prog="cmudrive routes")
    sub = parser.add_subparsers(dest="command", required=True)
    gen = sub.add_parser("generate", help="generate multi-CAV routes: scenario-free ones, or a benchmark set")
    gen.add_argument("entries", nargs="*", metavar="TOWN[:CAVS[:WEATHER]]")
    gen.add_argument("-o", "--output", required=True, type=Path)
    gen.add_argument(
        "-b", "--benchmark", default=None, help="a named route set: cmudrive220, cmudrive44, training"
    )
    gen.add_argument("-s", "--seed", type=int, default=0)
    gen.add_argument("-l", "--length", type=float, nargs=2, default=(200.0, 400.0), metavar=("MIN", "MAX"))
    gen.add_argument("-p", "--id-prefix", default="route")
    gen.add_argument("-c", "--cavs", type=int, default=4, help="CAVs of entries that do not name a number")
    gen.add_argument("-w", "--weather", default="ClearNoon", help="weather of entries that do not name one")
    args = parser.parse_args(argv)
    if args.benchmark is not None:
        if args.entries:
            parser.error("give either -b NAME or TOWN entries, not both")
        return _main_benchmark(args.benchmark, args.output)
    if not args.entries:
        parser.error("give TOWN entries or -b NAME")
    entries = []
    for entry in args.entries:
        town, *rest = entry.split(":")
        entries.append(
            (town, int(rest[0]) if rest else args.cavs, rest[1] if len(rest) > 1 else args.weather)
        )
    length = (float(args.length[0]), float(args.length[1]))
    specs = generate_route_set(entries, args.seed, length, args.id_prefix)
    command = (
        f"cmudrive routes generate -o {args.output.as_posix()} -s {args.seed} "
        f"-l {length[0]:g} {length[1]:g} -p {args.id_prefix} "
        + " ".join(f"{t}:{c}:{w}" for t, c, w in entries)
    )
    summary = _summary(specs)
    write_routes(specs, args.output, comment="\n".join(["Generated by:", f"  {command}", "", *summary]))
    print("\n".join([f"wrote {len(specs)} routes to {args.output}", *summary]))
    return 0


def _main_benchmark(name: str, output: Path) -> int:
    from cmudrive.bench.benchmark_gen import ROUTE_SETS, generate_set, stats_lines

    if name not in ROUTE_SETS:
        raise ValueError(f"unknown route set {name!r}; known: {', '.join(ROUTE_SETS)}")
    specs = generate_set(name, progress=lambda line: print(line, flush=True))
    lines = stats_lines(specs)
    command = f"cmudrive routes generate -b {name} -o {output.as_posix()}"
    write_routes(specs, output, comment="\n".join(["Generated by:", f"  {command}", "", *lines]))
    print("\n".join([f"wrote {len(specs)} routes to {output}", *lines]))
    return 0


__all__ = ["add_cavs", "generate_route_set", "generate_routes", "main"]

if __name__ == "__main__":
    sys.exit(main())
