"""Where scenario actors go: points along lanes and beside them, in the map frame.

The reference (``reference/SCENARIOS.md``, "Conventions") places actors relative to T_wp, the ego-lane
point nearest the trigger, with three walks along the lane graph:

* ``next(d)``: d m downstream, through junctions (we take the branch CAV 0's route takes, else the first);
* ``fwd(d)``: the same walk, but it stops at the last point *before* a junction;
* ``back(d)``: upstream, also stopping before a junction.

A :class:`LanePoint` is (lane, s) on one lane; ``xy``, ``heading`` and ``offset`` turn it into world
poses. "Right" and "left" are relative to the lane's direction (SUMO's d axis points left).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmudrive.maps.model import NO_INDEX, LaneKind, RoadMap

SIDE_CLEARANCE = 1.5  # [m] outward of the outer lane's edge where a road has no sidewalk (reference: 1.5 m)


@dataclass(frozen=True)
class LanePoint:
    """A point on a lane centreline: lane index and arc length s [m]."""

    lane: int
    s: float


def point_xy(m: RoadMap, p: LanePoint, d: float = 0.0) -> np.ndarray:
    """(2,) world point at ``p`` shifted ``d`` m to the left of the lane (negative: right)."""
    return m.index.frenet_to_xy(np.array([p.lane]), np.array([p.s]), d)[0]


def heading(m: RoadMap, p: LanePoint) -> float:
    """Lane direction at ``p`` [rad]."""
    return float(m.index.heading_at(np.array([p.lane]), np.array([p.s]))[0])


def width(m: RoadMap, p: LanePoint) -> float:
    return float(m.lane_width[p.lane])


def side_sign(direction: str) -> float:
    """+1 for "left", -1 for "right": multiply a rightward/leftward distance by this to get SUMO's d."""
    return 1.0 if direction == "left" else -1.0


def walk(
    m: RoadMap,
    start: LanePoint,
    distance: float,
    *,
    through_junctions: bool,
    prefer: frozenset[int] = frozenset(),
) -> LanePoint:
    """The point ``distance`` m downstream of ``start`` (upstream for a negative distance).

    Downstream at a lane end the walk takes the successor in ``prefer`` (the route's lanes), else the
    first. Without ``through_junctions`` it stops at the end of the last lane before a junction (and
    upstream at the start of the first lane after one), like the reference's fwd/back."""
    lane, s = start.lane, start.s
    if distance < 0.0:
        return _walk_back(m, lane, s, -distance)
    left = distance
    for _ in range(10_000):  # lanes are >= ~0.1 m long; this bounds a walk of any sane length
        length = float(m.lane_length[lane])
        if s + left <= length:
            return LanePoint(lane, s + left)
        succ = [int(x) for x in m.successors(lane) if m.lane_kind[x] == LaneKind.DRIVING]
        if not succ or (not through_junctions and m.lane_internal[succ[0]]):
            return LanePoint(lane, length)
        left -= length - s
        nxt = next((x for x in succ if x in prefer), succ[0])
        lane, s = nxt, 0.0
    return LanePoint(lane, s)


def _walk_back(m: RoadMap, lane: int, s: float, distance: float) -> LanePoint:
    left = distance
    for _ in range(10_000):
        if s - left >= 0.0:
            return LanePoint(lane, s - left)
        pred = [int(x) for x in m.predecessors(lane) if m.lane_kind[x] == LaneKind.DRIVING]
        if not pred or m.lane_internal[pred[0]]:
            return LanePoint(lane, 0.0)
        left -= s
        lane = pred[0]
        s = float(m.lane_length[lane])
    return LanePoint(lane, s)


def neighbour(m: RoadMap, lane: int, side: str) -> int:
    """The same-direction driving lane on ``side`` ("left"/"right") of ``lane``, else -1."""
    other = int((m.lane_left if side == "left" else m.lane_right)[lane])
    if other == NO_INDEX or m.lane_kind[other] != LaneKind.DRIVING:
        return NO_INDEX
    return other


def roadside(m: RoadMap, p: LanePoint, side: str, push: float = 0.0) -> tuple[np.ndarray, bool]:
    """(2,) a point beside the road abreast ``p`` on ``side``, and whether it lies on a sidewalk.

    Right side: the centre of the outermost non-driving lane of the edge (sidewalk, shoulder, parking)
    pushed ``push`` m further out; without one, ``SIDE_CLEARANCE`` m outward of the outer driving lane's
    edge. Left side: beyond the leftmost lane of the edge (a one-way road's left kerb); for a two-way
    road that is the median, so callers use the right side there."""
    edge = m.lane_edge[p.lane]
    lanes = np.flatnonzero(m.lane_edge == edge)
    lanes = lanes[np.argsort(m.lane_index[lanes])]  # rightmost first
    outer = int(lanes[0] if side == "right" else lanes[-1])
    sign = side_sign(side)
    s_o, _ = m.index.project(point_xy(m, p)[None, :], np.array([outer]))
    q = LanePoint(outer, float(s_o[0]))
    if m.lane_kind[outer] != LaneKind.DRIVING:
        return point_xy(m, q, sign * push), bool(m.lane_kind[outer] == LaneKind.SIDEWALK)
    return point_xy(m, q, sign * (0.5 * m.lane_width[outer] + SIDE_CLEARANCE + push)), False


def has_sidewalk(m: RoadMap, lane: int, side: str = "right") -> bool:
    edge = m.lane_edge[lane]
    lanes = np.flatnonzero(m.lane_edge == edge)
    outer = (
        lanes[np.argmin(m.lane_index[lanes])] if side == "right" else lanes[np.argmax(m.lane_index[lanes])]
    )
    return bool(m.lane_kind[outer] == LaneKind.SIDEWALK)
