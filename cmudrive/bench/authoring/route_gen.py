"""Generated multi-CAV routes: extra CAVs around a scenario route, and scenario-free route sets.

The paper: "starting locations and destinations of the additional cooperative vehicles are automatically
generated according to the road topology of each scenario". ``add_cavs`` starts each added CAV on its own
lane within a ring around CAV 0's start, away from the lanes CAV 0 and its scenarios use at first, and
plans it a route through the lane graph; ``generate_routes`` makes scenario-free routes for smoke tests.
Routes are stored as sparse keypoints (CARLA coordinates), as route files hold them, with the route
geometry of ``route_geometry``. ``cmudrive routes generate`` (``cmudrive.cli.routes``) writes them to a
file.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Sequence
from pathlib import Path

import numpy as np

from cmudrive.bench.authoring.route_geometry import Topology, carla_points
from cmudrive.bench.routes import MAX_CAVS, CavSpec, RouteSpec, ScenarioSpec
from cmudrive.maps import LanePos, RoadMap, Route, RouteError, load_map
from cmudrive.maps.cache import resolve_map_path
from cmudrive.sim.weather import get_weather

START_RING = (30.0, 150.0)  # [m] straight-line distance of an added CAV's start from CAV 0's start
START_RING_WIDENED = (250.0, 400.0)  # [m] outer radii tried in turn when the ring has too few free lanes
MIN_START_GAP = 15.0  # [m] between the starts of any two CAVs
SCENARIO_CLEARANCE = 60.0  # [m] of CAV 0's route ahead: no other CAV starts on the lanes it uses there
MIN_CAV_ROUTE = 150.0  # [m] shortest route of an added CAV
MAX_CAV_ROUTE_FACTOR = 1.0  # [-] added CAVs' routes are at most this times CAV 0's route (but >= 250 m)
MIN_MAX_CAV_ROUTE = 250.0  # [m] floor of that upper bound
ROUTE_ATTEMPTS = 50  # [-] CAV 0 routes tried per generated route


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
    topo = Topology(road_map)
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
            cavs.append(CavSpec(len(cavs), carla_points(plan[0])))
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
    topo = Topology(road_map)
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
                (CavSpec(0, carla_points(plan[0])),),
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


__all__ = ["add_cavs", "generate_route_set", "generate_routes"]
