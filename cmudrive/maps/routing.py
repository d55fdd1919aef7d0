"""Lane-level route planning, in the manner of CARLA's ``GlobalRoutePlanner``.

The search runs Dijkstra over driving lanes. A label is (lane, entry arc length); from a lane entered at
``s_in`` one can follow it to its end and step to a successor (internal junction lane or next edge), at a
cost of the distance driven, or change to the left/right neighbour of the same edge over
``LANE_CHANGE_LENGTH`` metres, at that distance plus ``LANE_CHANGE_PENALTY``. Changes are not allowed
inside junctions. The plan is returned as a dense :class:`Route` at ``spacing`` (default 1 m) with, per
point, position, heading, lane, speed limit, in-junction flag and a CARLA ``RoadOption``.

:func:`densify` joins sparse keypoints (leaderboard route files hold points up to ~180 m apart) with
planned paths, like the leaderboard's ``interpolate_trajectory``.

Search state is one label per (lane, entered at s = 0 or not): a lane entered mid-way through a lane
change and the same lane entered from its start are kept apart, which is what a route that loops back to
a point behind its start needs. Within each kind the first (cheapest) arrival wins.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from cmudrive.maps.errors import RouteError
from cmudrive.maps.index import wrap_angle
from cmudrive.maps.model import NO_INDEX, RoadMap, TurnDir

LANE_CHANGE_LENGTH = 20.0  # [m] longitudinal distance over which a planned lane change happens
LANE_CHANGE_MIN_ROOM = 6.0  # [m] a change needs at least this much lane left
LANE_CHANGE_PENALTY = 10.0  # [m] extra cost of a lane change, so routes prefer to stay in lane
# where the room is short (several changes between two close route points, as on CARLA's Town06
# highway), a change may take only this long, at this extra cost on top of the penalty
SHORT_CHANGE_LENGTH = 8.0  # [m]
SHORT_CHANGE_EXTRA = 15.0  # [m] more than the time saved, so a full-length change is taken when it fits
MAX_SNAP_DISTANCE = 10.0  # [m] a start/goal point farther than this from any driving lane is an error
FINE_STEP = 0.25  # [m] internal sampling before the route is resampled to its spacing


class RoadOption(IntEnum):
    """CARLA's ``RoadOption`` values, so that route files and agents interoperate."""

    VOID = -1
    LEFT = 1
    RIGHT = 2
    STRAIGHT = 3
    LANEFOLLOW = 4
    CHANGELANELEFT = 5
    CHANGELANERIGHT = 6


_TURN_TO_OPTION = {
    TurnDir.STRAIGHT: RoadOption.STRAIGHT,
    TurnDir.LEFT: RoadOption.LEFT,
    TurnDir.PARTLY_LEFT: RoadOption.LEFT,
    TurnDir.TURN: RoadOption.LEFT,
    TurnDir.RIGHT: RoadOption.RIGHT,
    TurnDir.PARTLY_RIGHT: RoadOption.RIGHT,
    TurnDir.INVALID: RoadOption.STRAIGHT,
}


@dataclass(frozen=True)
class LanePos:
    """A point on a lane: lane index and arc length [m]."""

    lane: int
    s: float


@dataclass(frozen=True)
class Route:
    """A dense route of ``n`` points, ``spacing`` apart along the path (the last gap may be shorter)."""

    xy: np.ndarray  # (n, 2) float64 position [m]
    heading: np.ndarray  # (n,) float64 direction of travel [rad]
    lane: np.ndarray  # (n,) int32 lane index
    s: np.ndarray  # (n,) float64 arc length on that lane [m]
    speed_limit: np.ndarray  # (n,) float64 [m/s]
    in_junction: np.ndarray  # (n,) bool
    option: np.ndarray  # (n,) int8 RoadOption
    distance: np.ndarray  # (n,) float64 distance along the route from its start [m]
    # (k,) int32 every lane the plan traverses, in order, without repeats: unlike ``lane`` it keeps lanes
    # shorter than the point spacing (imported towns have sub-metre edges between two junctions), so it
    # is what a SUMO route of the same path must be built from
    path: np.ndarray

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    @property
    def length(self) -> float:
        return float(self.distance[-1]) if len(self) else 0.0


@dataclass(frozen=True)
class _Piece:
    """Part of a plan on one lane from s0 to s1; a lane change piece blends from lane ``src``."""

    lane: int
    s0: float
    s1: float
    option: RoadOption
    src: int = NO_INDEX  # lane changed from (lane-change pieces only)


class RoutePlanner:
    """Plans lane-level routes on a :class:`RoadMap`."""

    def __init__(
        self,
        road_map: RoadMap,
        lane_change_penalty: float = LANE_CHANGE_PENALTY,
        lanes: np.ndarray | None = None,
    ) -> None:
        """``lanes``: (N,) bool mask of the lanes routes may use (default: the driving lanes; a bicycle
        flow plans on the bike lanes)."""
        self.map = road_map
        self.penalty = lane_change_penalty
        self._driving = road_map.driving if lanes is None else np.asarray(lanes, bool)
        # the option of every (internal) lane, from the turn direction of the link that leads into it
        option = np.full(road_map.num_lanes, RoadOption.LANEFOLLOW, np.int8)
        for lane in np.flatnonzero(road_map.lane_internal & self._driving):
            links = np.flatnonzero(road_map.succ_lane == lane)
            if len(links):
                turn = TurnDir(int(road_map.link_dir[road_map.succ_link[links[0]]]))
                option[lane] = _TURN_TO_OPTION[turn]
        self._lane_option = option

    # ------------------------------------------------------------------ snapping
    def snap(self, xy: np.ndarray | tuple[float, float], heading: float | None = None) -> LanePos:
        """The driving-lane position of a world point (heading-filtered when given)."""
        point = np.asarray(xy, np.float64).reshape(1, 2)
        proj = self.map.index.nearest_lane(point, heading=heading, max_distance=MAX_SNAP_DISTANCE)
        if proj.lane[0] < 0 and heading is not None:
            proj = self.map.index.nearest_lane(point, max_distance=MAX_SNAP_DISTANCE)
        if proj.lane[0] < 0:
            raise RouteError(
                f"point ({point[0, 0]:.1f}, {point[0, 1]:.1f}) is more than {MAX_SNAP_DISTANCE:.0f} m from "
                f"any driving lane of map {self.map.name!r}"
            )
        return LanePos(int(proj.lane[0]), float(proj.s[0]))

    # ------------------------------------------------------------------ planning
    def plan(
        self,
        start: np.ndarray | tuple[float, float],
        goal: np.ndarray | tuple[float, float],
        start_heading: float | None = None,
        goal_heading: float | None = None,
        spacing: float = 1.0,
    ) -> Route:
        """Dense route from a world start pose to a world goal point."""
        return self.plan_lanes(self.snap(start, start_heading), self.snap(goal, goal_heading), spacing)

    def plan_lanes(self, start: LanePos, goal: LanePos, spacing: float = 1.0) -> Route:
        return self._render(self._search(start, goal), spacing)

    def plan_through(self, stops: list[LanePos], spacing: float = 1.0, max_length: float = math.inf) -> Route:
        """One route through several lane positions in order, resampled as a whole; RouteError as soon as
        the legs planned so far are longer than ``max_length`` [m] (so a bad input is refused early)."""
        pieces: list[_Piece] = []
        length = 0.0
        for i in range(len(stops) - 1):
            try:
                leg = self._search(stops[i], stops[i + 1])
            except RouteError as exc:
                raise RouteError(f"between route points {i} and {i + 1}: {exc}") from None
            pieces.extend(leg)
            length += sum(p.s1 - p.s0 for p in leg)
            if length > max_length:
                raise RouteError(
                    f"the route is longer than {max_length:.0f} m by route point {i + 1} "
                    f"({length:.0f} m planned): its waypoints make it loop or it is too long"
                )
        return self._render(pieces, spacing)

    def _search(self, start: LanePos, goal: LanePos) -> list[_Piece]:
        m = self.map
        length = m.lane_length
        # heap entries: (cost, tiebreak, label id); labels: (lane, s_in, parent label, piece)
        labels: list[tuple[int, float, int, _Piece | None]] = [(start.lane, start.s, -1, None)]
        heap: list[tuple[float, int, int]] = [(0.0, 0, 0)]
        done: set[tuple[int, float]] = set()  # (lane, where it was entered [m], to 0.1 m)
        goal_label = -1
        counter = 1
        while heap:
            cost, _, lid = heapq.heappop(heap)
            lane, s_in, _, _ = labels[lid]
            if lane == -2:  # the goal pseudo-label
                goal_label = lid
                break
            key = (lane, round(s_in, 1))
            if key in done and lid != 0:
                continue
            if lid != 0:
                done.add(key)
            pushes: list[tuple[float, tuple[int, float, int, _Piece | None]]] = []
            if lane == goal.lane and s_in <= goal.s + 1e-6:
                piece = _Piece(lane, s_in, goal.s, RoadOption(int(self._lane_option[lane])))
                pushes.append((cost + goal.s - s_in, (-2, 0.0, lid, piece)))
            rest = length[lane] - s_in
            follow = _Piece(lane, s_in, float(length[lane]), RoadOption(int(self._lane_option[lane])))
            for nxt in m.successors(lane).tolist():
                if self._driving[nxt] and (nxt, 0.0) not in done:
                    pushes.append((cost + rest, (nxt, 0.0, lid, follow)))
            if not m.lane_internal[lane] and rest >= LANE_CHANGE_MIN_ROOM:
                full = min(LANE_CHANGE_LENGTH, rest - 1.0)
                changes = [(full, self.penalty)]
                if full > SHORT_CHANGE_LENGTH:
                    changes.append((SHORT_CHANGE_LENGTH, self.penalty + SHORT_CHANGE_EXTRA))
                for nxt, opt in (
                    (m.lane_left[lane], RoadOption.CHANGELANELEFT),
                    (m.lane_right[lane], RoadOption.CHANGELANERIGHT),
                ):
                    for change, extra in changes:
                        state = (int(nxt), round(s_in + change, 1))
                        if nxt >= 0 and self._driving[nxt] and state not in done:
                            piece = _Piece(int(nxt), s_in, s_in + change, opt, src=lane)
                            pushes.append((cost + change + extra, (int(nxt), s_in + change, lid, piece)))
            for new_cost, label in pushes:
                labels.append(label)
                heapq.heappush(heap, (new_cost, counter, len(labels) - 1))
                counter += 1
        if goal_label < 0:
            raise RouteError(
                f"no route in map {m.name!r} from lane {m.lane_ids[start.lane]} (s={start.s:.1f} m) "
                f"to lane {m.lane_ids[goal.lane]} (s={goal.s:.1f} m)"
            )
        pieces: list[_Piece] = []
        lid = goal_label
        while lid > 0:
            _, _, parent, step = labels[lid]
            if step is not None:
                pieces.append(step)
            lid = parent
        pieces.reverse()
        return [p for p in pieces if p.s1 - p.s0 > 1e-6 or p.src >= 0] or [pieces[-1]]

    # ------------------------------------------------------------------ rendering
    def _render(self, pieces: list[_Piece], spacing: float) -> Route:
        m = self.map
        index = m.index
        chunks_xy, chunks_lane, chunks_s, chunks_opt = [], [], [], []
        for p in pieces:
            n = max(2, int(np.ceil((p.s1 - p.s0) / FINE_STEP)) + 1)
            s = np.linspace(p.s0, p.s1, n)
            lane = np.full(n, p.lane, np.int32)
            xy = index.frenet_to_xy(lane, s)
            if p.src >= 0:  # blend from the source lane with a smooth (cosine) lateral profile
                src_xy = index.frenet_to_xy(np.full(n, p.src), s)
                f = 0.5 - 0.5 * np.cos(np.pi * np.linspace(0.0, 1.0, n))
                xy = (1.0 - f)[:, None] * src_xy + f[:, None] * xy
            chunks_xy.append(xy)
            chunks_lane.append(lane)
            chunks_s.append(s)
            chunks_opt.append(np.full(n, p.option, np.int8))
        xy = np.concatenate(chunks_xy)
        lane = np.concatenate(chunks_lane)
        s = np.concatenate(chunks_s)
        opt = np.concatenate(chunks_opt)
        step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        keep = np.concatenate([[True], step > 1e-6])
        xy, lane, s, opt = xy[keep], lane[keep], s[keep], opt[keep]
        dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
        if len(xy) == 1:
            out_d = np.array([0.0])
        else:
            out_d = np.arange(0.0, dist[-1], spacing)
            if dist[-1] - out_d[-1] > 1e-6:
                out_d = np.append(out_d, dist[-1])
        src = np.clip(np.searchsorted(dist, out_d, side="right") - 1, 0, len(xy) - 1)
        out_xy = np.stack([np.interp(out_d, dist, xy[:, 0]), np.interp(out_d, dist, xy[:, 1])], axis=1)
        out_lane = lane[src]
        frac = np.clip((out_d - dist[src]) / np.maximum(np.append(np.diff(dist), 1.0)[src], 1e-12), 0, 1)
        nxt = np.minimum(src + 1, len(xy) - 1)
        same = lane[nxt] == lane[src]
        out_s = np.where(same, s[src] + frac * (s[nxt] - s[src]), s[src])
        return Route(
            xy=out_xy,
            heading=_path_heading(out_xy, fallback=index.heading_at(out_lane[:1], out_s[:1])[0]),
            lane=out_lane,
            s=out_s,
            speed_limit=m.lane_speed[out_lane],
            in_junction=m.lane_internal[out_lane],
            option=opt[src],
            distance=out_d,
            path=_lane_path(pieces),
        )


def _lane_path(pieces: list[_Piece]) -> np.ndarray:
    lanes = [lane for p in pieces for lane in ((p.src, p.lane) if p.src >= 0 else (p.lane,))]
    return np.array([lane for i, lane in enumerate(lanes) if i == 0 or lane != lanes[i - 1]], np.int32)


def _path_heading(xy: np.ndarray, fallback: float) -> np.ndarray:
    """Heading of a polyline at its points from central differences (one-sided at the ends)."""
    if len(xy) < 2:
        return np.array([fallback])
    grad = np.gradient(xy, axis=0)
    return np.asarray(wrap_angle(np.arctan2(grad[:, 1], grad[:, 0])))


def densify(
    road_map: RoadMap, keypoints: np.ndarray, spacing: float = 1.0, max_length: float = math.inf
) -> Route:
    """Join sparse route keypoints (m, 2) with planned paths, like the leaderboard does for route files.

    Each keypoint is snapped to the driving lane nearest to it whose direction agrees with the chord from
    the previous keypoint (towards the next one for the first), so keypoints inside junctions, where
    internal lanes overlap, pick the lane the route actually travels.
    """
    keypoints = np.asarray(keypoints, np.float64).reshape(-1, 2)
    if len(keypoints) < 2:
        raise RouteError(f"a route needs at least 2 keypoints, got {len(keypoints)} (map {road_map.name!r})")
    planner = RoutePlanner(road_map)
    chords = np.diff(keypoints, axis=0)
    chord_heading = np.arctan2(chords[:, 1], chords[:, 0])
    headings = np.concatenate([[chord_heading[0]], chord_heading])
    positions = []
    for i, (point, heading) in enumerate(zip(keypoints, headings, strict=True)):
        try:
            positions.append(planner.snap(point, heading))
        except RouteError as exc:
            raise RouteError(f"keypoint {i}: {exc}") from None
    return planner.plan_through(positions, spacing, max_length)


def pick_far_apart(
    planner: RoutePlanner, rng: np.random.Generator, min_distance: float = 300.0, attempts: int = 200
) -> Route:
    """A route between two random normal driving lanes at least ``min_distance`` apart (straight line).

    Falls back to the longest route found when no pair is that far apart (small maps).
    """
    m = planner.map
    lanes = np.flatnonzero(m.driving & ~m.lane_internal & (m.lane_length > 5.0))
    if len(lanes) == 0:
        raise RouteError(f"map {m.name!r} has no driving lane to plan on")
    best: Route | None = None
    for _ in range(attempts):
        a, b = rng.choice(lanes, size=2)
        start = LanePos(int(a), float(0.5 * m.lane_length[a]))
        goal = LanePos(int(b), float(0.5 * m.lane_length[b]))
        xy = m.index.frenet_to_xy(np.array([a, b]), np.array([start.s, goal.s]))
        if np.linalg.norm(xy[0] - xy[1]) < min_distance and best is not None:
            continue
        try:
            route = planner.plan_lanes(start, goal)
        except RouteError:
            continue
        if np.linalg.norm(xy[0] - xy[1]) >= min_distance:
            return route
        if best is None or route.length > best.length:
            best = route
    if best is None:
        raise RouteError(f"found no connected pair of driving lanes in map {m.name!r} after {attempts} tries")
    return best
