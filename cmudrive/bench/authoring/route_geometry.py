"""Route geometry shared by the route generators (``route_gen``, ``benchmark_gen``): candidate start
points on the lane graph, routes planned from them, and the sparse keypoints (CARLA frame) a route file
stores.
"""

from __future__ import annotations

import heapq

import numpy as np

from cmudrive.maps import LanePos, RoadMap, RoadOption, Route, RouteError, RoutePlanner, densify
from cmudrive.maps.coords import map_to_carla

KEYPOINT_SPACING = 50.0  # [m] between stored keypoints of a generated route
LANE_END_MARGIN = 8.0  # [m] starts and goals keep this far from both ends of their lane
CANDIDATE_STEP = 5.0  # [m] spacing of candidate start points along a lane
DENSIFY_TOLERANCE = (
    0.05  # [-] relative length difference allowed between the plan and its densified keypoints
)
COORD_DECIMALS = 2  # generated coordinates are rounded to 1 cm
GOAL_ATTEMPTS = 12  # [-] destinations tried per start before the start is given up


class Topology:
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
            keypoints = np.round(route_keypoints(route), COORD_DECIMALS)
            try:
                dense = densify(m, keypoints)
            except RouteError:
                continue
            same = abs(dense.length - route.length) <= DENSIFY_TOLERANCE * route.length
            if same and length[0] <= dense.length <= length[1]:
                return keypoints, dense.length
        return None


def route_keypoints(route: Route) -> np.ndarray:
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


def carla_points(keypoints_map: np.ndarray) -> np.ndarray:
    """Map-frame keypoints (m, 2) -> CARLA (m, 3) with z = 0 (our maps are flat), rounded to 1 cm."""
    xy = map_to_carla(keypoints_map) + 0.0  # + 0.0 turns -0.0 into 0.0
    return np.round(np.column_stack([xy, np.zeros(len(xy))]), COORD_DECIMALS) + 0.0


__all__ = [
    "CANDIDATE_STEP",
    "COORD_DECIMALS",
    "DENSIFY_TOLERANCE",
    "GOAL_ATTEMPTS",
    "KEYPOINT_SPACING",
    "LANE_END_MARGIN",
    "Topology",
    "carla_points",
    "route_keypoints",
]
