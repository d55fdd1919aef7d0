"""Stop lines of the map as arrays for the red-light and stop-sign checks.

``RoadMap`` stores one stop line per incoming lane controlled by a light or a sign, at the end of the lane,
as its two end points (right end first). Here each line gets its centre, the direction of travel across
it, and its end points stretched to ``width_factor`` lane widths (CARLA's red-light test uses a line 1.2
lane widths long centred on the lane), plus a lane -> stop line lookup.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmudrive.maps.model import NO_INDEX, RoadMap, StopKind


@dataclass(frozen=True)
class StopLineTable:
    """``K`` stop lines."""

    lane: np.ndarray  # (K,) int32 approach lane; the line lies at its end
    kind: np.ndarray  # (K,) int8 StopKind
    mid: np.ndarray  # (K, 2) float64 centre of the line [m]
    forward: np.ndarray  # (K, 2) float64 unit direction of travel across the line
    ends: np.ndarray  # (K, 2, 2) float64 end points of the stretched line [m]
    width: np.ndarray  # (K,) float64 lane width [m]
    of_lane: np.ndarray  # (N,) int64 stop line at the end of each lane, -1 for none
    is_light: np.ndarray  # (K + 1,) bool the line is a traffic light's; the extra last entry (index -1) False
    is_sign: np.ndarray  # (K + 1,) bool the line is a stop sign's or an all-way stop's; last entry False

    @staticmethod
    def build(road_map: RoadMap, width_factor: float) -> StopLineTable:
        right, left = road_map.stop_xy[:, 0], road_map.stop_xy[:, 1]
        across = left - right  # points to the left of the direction of travel
        width = np.linalg.norm(across, axis=1)
        unit = across / np.maximum(width, 1e-9)[:, None]
        forward = np.stack([unit[:, 1], -unit[:, 0]], axis=1)  # the left vector turned clockwise
        mid = 0.5 * (right + left)
        half = (0.5 * width_factor * width)[:, None]
        ends = np.stack([mid - half * unit, mid + half * unit], axis=1)
        of_lane = np.full(road_map.num_lanes, NO_INDEX, np.int64)
        of_lane[road_map.stop_lane] = np.arange(len(road_map.stop_lane))
        kind = road_map.stop_kind
        is_light = np.append(kind == StopKind.TRAFFIC_LIGHT, False)
        is_sign = np.append((kind == StopKind.STOP_SIGN) | (kind == StopKind.ALLWAY_STOP), False)
        return StopLineTable(road_map.stop_lane, kind, mid, forward, ends, width, of_lane, is_light, is_sign)

    def at(self, lane: np.ndarray, of_kind: np.ndarray) -> np.ndarray:
        """(m,) stop line at the end of each lane (-1 for none, or for lane -1) among the lines where
        ``of_kind`` (``is_light`` or ``is_sign``) holds."""
        k = np.where(lane >= 0, self.of_lane[lane], NO_INDEX)
        has = k >= 0
        has[has] = of_kind[k[has]]  # (a map may have no stop line at all: of_kind is then empty)
        return np.where(has, k, NO_INDEX)

    def frame(self, k: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(along, across) [m] of points ``xy`` (m, 2) relative to the centres of lines ``k`` (m,): along
        the direction of travel (positive past the line) and to its left."""
        rel = xy - self.mid[k]
        fwd = self.forward[k]
        return np.einsum("mc,mc->m", rel, fwd), fwd[:, 0] * rel[:, 1] - fwd[:, 1] * rel[:, 0]


def segments_cross(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """(m,) whether segments p0-p1 and q0-q1 (each (m, 2)) intersect (touching counts)."""

    def side(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:  # sign of c relative to line a->b
        return np.sign((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))

    return (side(q0, q1, p0) * side(q0, q1, p1) <= 0) & (side(p0, p1, q0) * side(p0, p1, q1) <= 0)
