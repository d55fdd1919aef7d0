"""Behaviours the scenario types share (``reference/SCENARIOS.md``, "Shared behaviours").

* triggers: "a CAV is within d m of a point" and the time-to-arrival trigger TTA(t, d, P);
* "ahead of a point along a heading" (the obstacle family's end test);
* :class:`PathMotion`: drive a layer actor along a polyline at a speed ("drive this path");
* :func:`lane_path`: the polyline along the lane graph, shifted sideways, that such a path follows.

Triggers look at the scenario's ego, CAV 0, alone (as upstream's look at the one ego): another CAV that
drives into the area first meets the actors where they stand but does not release them.
"""

from __future__ import annotations

import numpy as np

from cmudrive.bench.scenarios.base import EGO, RouteProgress
from cmudrive.bench.scenarios.placement import LanePoint, point_xy, walk
from cmudrive.maps import RoadMap

PATH_STEP = 1.0  # [m] spacing of lane paths


def within(progress: RouteProgress, point: np.ndarray, distance: float) -> bool:
    """CAV 0 is in the world and closer than ``distance`` [m] to ``point`` (straight line)."""
    gap = float(np.linalg.norm(progress.xy[EGO] - point))
    return bool(progress.present[EGO]) and gap < distance


def time_to_arrival(progress: RouteProgress, point: np.ndarray, seconds: float, distance: float) -> bool:
    """TTA(t, d, P): CAV 0's straight-line distance to P over its speed is below ``seconds`` [s], or the
    distance itself below ``distance`` [m] (a standing CAV 0 fires only the distance half)."""
    if not progress.present[EGO]:
        return False
    gap, speed = float(np.linalg.norm(progress.xy[EGO] - point)), float(progress.speed[EGO])
    return gap < distance or (speed > 0.1 and gap / speed < seconds)


def ahead_of(xy: np.ndarray, point: np.ndarray, heading: float) -> np.ndarray:
    """(n,) bool: positions (n, 2) lie beyond ``point`` along ``heading`` [rad]."""
    return (xy - point) @ np.array([np.cos(heading), np.sin(heading)]) > 0.0


def lane_path(
    m: RoadMap,
    start: LanePoint,
    length: float,
    offset: float = 0.0,
    prefer: frozenset[int] = frozenset(),
    through_junctions: bool = True,
) -> np.ndarray:
    """(n, 2) points every PATH_STEP m along the lane graph from ``start`` for ``length`` m, shifted
    ``offset`` m to the left of each lane (negative: right)."""
    n = max(int(np.ceil(length / PATH_STEP)), 1) + 1
    points = [
        walk(m, start, min(i * PATH_STEP, length), through_junctions=through_junctions, prefer=prefer)
        for i in range(n)
    ]
    return np.array([point_xy(m, p, offset) for p in points])


class PathMotion:
    """A pose moving along a polyline at a speed [m/s]; ``s`` [m] is the distance covered."""

    def __init__(self, path: np.ndarray, speed: float) -> None:
        if len(path) < 2:
            raise ValueError("a path needs at least two points")
        self.path = np.asarray(path, np.float64)
        seg = np.diff(self.path, axis=0)
        self.cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=1))])
        self.speed = float(speed)
        self.s = 0.0

    @property
    def length(self) -> float:
        return float(self.cum[-1])

    @property
    def done(self) -> bool:
        return self.s >= self.length

    def advance(self, dt: float) -> None:
        self.s = min(self.s + self.speed * dt, self.length)

    def pose(self) -> tuple[np.ndarray, float]:
        """((2,) position [m], heading [rad]) at the distance covered."""
        i = int(np.clip(np.searchsorted(self.cum, self.s, side="right") - 1, 0, len(self.path) - 2))
        a, b = self.path[i], self.path[i + 1]
        seg_len = max(self.cum[i + 1] - self.cum[i], 1e-9)
        t = (self.s - self.cum[i]) / seg_len
        d = b - a
        return a + t * d, float(np.arctan2(d[1], d[0]))

    @property
    def current_speed(self) -> float:
        return 0.0 if self.done else self.speed


def lane_change_path(
    m: RoadMap,
    start: LanePoint,
    from_offset: float,
    change: float,
    after: float,
    prefer: frozenset[int] = frozenset(),
) -> np.ndarray:
    """(n, 2) a lane change onto the lane of ``start``: it begins ``from_offset`` m beside that lane (+
    left), reaches the centre after ``change`` m (a smoothstep in the lateral offset) and follows the
    lane ``after`` m more. Points every PATH_STEP m; the lane walk goes through junctions."""
    total = change + after
    n = max(int(np.ceil(total / PATH_STEP)), 1) + 1
    along = np.minimum(np.arange(n) * PATH_STEP, total)
    u = np.clip(along / max(change, 1e-9), 0.0, 1.0)
    offset = from_offset * (1.0 - u * u * (3.0 - 2.0 * u))
    points = [walk(m, start, float(a), through_junctions=True, prefer=prefer) for a in along]
    return np.array([point_xy(m, p, float(d)) for p, d in zip(points, offset, strict=True)])
