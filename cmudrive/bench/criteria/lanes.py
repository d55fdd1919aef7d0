"""Outside route lanes: where a CAV is off every driving or parking lane, or drives against its lane.

A CAV (its box centre) is *outside* when it is farther than half the lane width plus ``lane_margin`` from
the centreline of the nearest driving lane and of the nearest parking lane, and not inside a junction's
outline (SUMO's junction shape: the whole paved junction area, over which SUMO's internal lanes are only
thin paths, so a CAV cutting a turn by a few metres is still on the road). It drives the *wrong way*
when the nearest driving lane is a normal (not junction-internal) lane whose direction is at least
``wrong_direction_angle`` from the CAV's heading. The criterion accumulates the route distance the CAV
advances while outside or (where its wrong-direction check is on) driving the wrong way; see ``engine``.
"""

from __future__ import annotations

import numpy as np

from cmudrive.bench.criteria.config import CriteriaConfig
from cmudrive.maps.index import LaneProjection, wrap_angle
from cmudrive.maps.model import NO_INDEX, LaneKind, RoadMap


def lane_state(
    road_map: RoadMap, xy: np.ndarray, yaw: np.ndarray, driving: LaneProjection, config: CriteriaConfig
) -> tuple[np.ndarray, np.ndarray]:
    """(outside (m,), wrong_way (m,)) bool for CAV centres ``xy`` (m, 2) [m] with headings ``yaw`` (m,)
    [rad], given ``driving``, the nearest driving lanes of those centres."""
    lane = np.maximum(driving.lane, 0)
    found = driving.lane >= 0
    outside = ~(found & (driving.distance <= 0.5 * road_map.lane_width[lane] + config.lane_margin))
    if outside.any() and np.any(road_map.lane_kind == LaneKind.PARKING):
        park = road_map.index.nearest_lane(xy[outside], kinds=(LaneKind.PARKING,))
        park_lane = np.maximum(park.lane, 0)
        on_park = (park.lane >= 0) & (
            park.distance <= 0.5 * road_map.lane_width[park_lane] + config.lane_margin
        )
        outside[outside] = ~on_park
    for j in np.flatnonzero(outside & found).tolist():  # CAVs off every lane: rare, and at most 16
        outside[j] = not any(
            _inside(xy[j], road_map.junction_shape(k)) for k in _junctions_near(road_map, lane[j])
        )
    angle = np.abs(wrap_angle(yaw - driving.heading))
    wrong = found & ~road_map.lane_internal[lane] & (angle >= np.radians(config.wrong_direction_angle))
    return outside, wrong


def _junctions_near(road_map: RoadMap, lane: int) -> set[int]:
    """The junction a lane lies in, or the junctions at both ends of its edge."""
    edge = road_map.lane_edge[lane]
    near = {
        int(road_map.lane_junction[lane]),
        int(road_map.edge_from_junction[edge]),
        int(road_map.edge_to_junction[edge]),
    }
    return near - {NO_INDEX}


def _inside(point: np.ndarray, polygon: np.ndarray) -> bool:
    """Whether ``point`` (2,) lies inside ``polygon`` (q, 2) (even-odd rule; False for q < 3)."""
    if len(polygon) < 3:
        return False
    a, b = polygon, np.roll(polygon, -1, axis=0)
    straddles = (a[:, 1] > point[1]) != (b[:, 1] > point[1])
    dy = np.where(straddles, b[:, 1] - a[:, 1], 1.0)
    cross_x = a[:, 0] + (point[1] - a[:, 1]) * (b[:, 0] - a[:, 0]) / dy
    return bool(np.count_nonzero(straddles & (point[0] < cross_x)) % 2)
