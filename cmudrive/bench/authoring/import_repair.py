"""Small changes that let another benchmark's CAV routes plan on our import of its town, each reported.

CARLA's global route planner changes lanes at once where the markings allow, so InterDrive (CoLMDriver)
writes keypoints a few metres after a lane change, goals a few metres past the junction that two turning
CAVs merge into, and CAVs 5 m apart on one lane. Our planner (``cmudrive.maps.routing``) changes lanes
over 8-20 m and never inside a junction, so it can reach such a keypoint only by a loop round the block
(hundreds of metres for a 30 m route), and a CAV whose route begins with a lane change starts turned a
little, its footprint a few centimetres into the CAV ahead. The importer tries, per CAV and in this order,
the least change that avoids the loop or the overlap, and says what it changed:

* ``repair_keypoints``: leave out interior keypoints (fewest first), else move the goal 10-40 m on along
  its lane;
* ``separate_starts``: move the rear CAV of two overlapping starts 0.5-3 m back along its lane.

A CAV that no change helps is left as it is: it loops, which the report of a run shows as a long route,
or ``RouteSpec.dense_routes`` refuses it naming the route and the CAV.
"""

from __future__ import annotations

from dataclasses import replace
from itertools import combinations

import numpy as np

from cmudrive.bench.route_spec import CavSpec, RouteSpec, start_conflicts
from cmudrive.bench.scenarios.placement import LanePoint, point_xy, walk
from cmudrive.maps import RoadMap, Route, RouteError
from cmudrive.maps.coords import carla_to_map
from cmudrive.maps.routing import RoutePlanner

LOOP_FACTOR = 2.0  # a CAV route planned longer than this x its keypoints' polyline + LOOP_SLACK loops
LOOP_SLACK = 40.0  # [m]
GOAL_EXTENSIONS = (10.0, 20.0, 30.0, 40.0)  # [m] how far a goal may be moved on along its lane
START_SETBACKS = (0.5, 1.0, 1.5, 2.0, 3.0)  # [m] how far a CAV's start may be moved back along its lane


def _dense(points: np.ndarray, road_map: RoadMap) -> Route | None:
    """The route planned through CARLA keypoints (n, 3) as ``RouteSpec.dense_routes`` plans a CAV's (with
    its detour bound), None when it cannot be planned."""
    spec = RouteSpec("probe", road_map.name, "ClearNoon", 0, (CavSpec(0, points),))
    try:
        return spec.dense_routes(road_map)[0]
    except RouteError:
        return None


def _dense_all(spec: RouteSpec, road_map: RoadMap) -> list[Route] | None:
    routes = [_dense(cav.waypoints, road_map) for cav in spec.cavs]
    return None if any(r is None for r in routes) else routes  # type: ignore[return-value]


def _direct(points: np.ndarray, road_map: RoadMap) -> bool:
    """The keypoints plan without a loop (``LOOP_FACTOR``, ``LOOP_SLACK``)."""
    route = _dense(points, road_map)
    polyline = float(np.linalg.norm(np.diff(points[:, :2], axis=0), axis=1).sum())
    return route is not None and route.length <= LOOP_FACTOR * polyline + LOOP_SLACK


def _moved_along_lane(points: np.ndarray, road_map: RoadMap, index: int, distance: float) -> np.ndarray:
    """``points`` with point ``index`` (0 or -1) moved ``distance`` [m] along the lane it snaps to
    (negative: back), snapped with the heading of its chord as ``densify`` snaps it."""
    xy = carla_to_map(points[:, :2])
    chord = xy[1] - xy[0] if index == 0 else xy[-1] - xy[-2]
    pos = RoutePlanner(road_map).snap(xy[index], float(np.arctan2(chord[1], chord[0])))
    end = point_xy(road_map, walk(road_map, LanePoint(pos.lane, pos.s), distance, through_junctions=True))
    out = points.copy()
    out[index, :2] = round(float(end[0]), 2), round(float(-end[1]), 2)  # back to CARLA's frame
    return out


def _with_cav(spec: RouteSpec, k: int, points: np.ndarray) -> RouteSpec:
    return replace(spec, cavs=tuple(CavSpec(c.id, points) if c.id == k else c for c in spec.cavs))


def _fmt(point: np.ndarray) -> str:
    return f"({point[0]:g}, {point[1]:g})"


def repair_keypoints(spec: RouteSpec, road_map: RoadMap) -> tuple[RouteSpec, list[str]]:
    """``spec`` with every CAV whose keypoints plan only by a loop (or not at all) changed the least that
    makes it plan directly (see the module docstring), and a note ``"CAV k: ..."`` per change."""
    notes: list[str] = []
    for k, cav in enumerate(spec.cavs):
        wps = cav.waypoints
        if _direct(wps, road_map):
            continue
        interior = range(1, len(wps) - 1)
        drops = (combo for n in range(1, len(interior) + 1) for combo in combinations(interior, n))
        keep = next(
            (
                [i for i in range(len(wps)) if i not in drop]
                for drop in drops
                if _direct(wps[[i for i in range(len(wps)) if i not in drop]], road_map)
            ),
            None,
        )
        if keep is not None:
            spec = _with_cav(spec, k, wps[keep])
            left_out = ", ".join(_fmt(wps[i]) for i in range(len(wps)) if i not in keep)
            notes.append(
                f"CAV {k}: left out keypoint(s) {left_out}, which our planner reaches only by a loop"
            )
            continue
        for distance in GOAL_EXTENSIONS:
            try:
                moved = _moved_along_lane(wps, road_map, -1, distance)
            except RouteError:  # the goal is on no lane: nothing to move along (check_planned names it)
                break
            if _direct(moved, road_map):
                spec = _with_cav(spec, k, moved)
                notes.append(
                    f"CAV {k}: goal {_fmt(wps[-1])} moved {distance:g} m on along its lane to "
                    f"{_fmt(moved[-1])}, reached without a loop"
                )
                break
    return spec, notes


def separate_starts(spec: RouteSpec, road_map: RoadMap) -> tuple[RouteSpec, list[str]]:
    """``spec`` with the rear CAV of every pair whose start footprints overlap (``start_conflicts``) moved
    back 0.5-3 m along its lane until it is clear, and a note ``"CAV k: ..."`` per move."""
    notes: list[str] = []
    for _ in range(len(spec.cavs)):
        dense = _dense_all(spec, road_map)
        clashes = start_conflicts(dense) if dense is not None else []
        if dense is None or not clashes:
            break
        a, b, _ = clashes[0]
        ahead = np.array([np.cos(dense[b].heading[0]), np.sin(dense[b].heading[0])])
        rear = a if float(np.dot(dense[a].xy[0] - dense[b].xy[0], ahead)) < 0.0 else b
        for distance in START_SETBACKS:
            moved = _with_cav(
                spec, rear, _moved_along_lane(spec.cavs[rear].waypoints, road_map, 0, -distance)
            )
            after = _dense_all(moved, road_map)
            if after is not None and all(rear not in pair[:2] for pair in start_conflicts(after)):
                spec = moved
                notes.append(
                    f"CAV {rear}: start moved {distance:g} m back along its lane, clear of CAV {a + b - rear}"
                )
                break
        else:
            break
    return spec, notes


__all__ = ["repair_keypoints", "separate_starts"]
