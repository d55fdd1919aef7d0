"""Road surfaces and markings as plain geometry [m], shared by the BEV pictures and the front camera.

Lanes are their centrelines offset by half their width to each side (mitre-free vertex normals);
crossings are zebra stripes; junctions are their outlines; markings follow :func:`marking_lines`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from cmudrive.maps.model import LaneKind, RoadMap

ZEBRA_PERIOD = 1.0  # [m] stripe + gap along a crossing


def offset_polyline(xy: np.ndarray, offset: float) -> np.ndarray:
    """Offset a polyline (n, 2) sideways by ``offset`` (+ left) using per-vertex mitre-free normals."""
    seg = np.diff(xy, axis=0)
    seg /= np.maximum(np.linalg.norm(seg, axis=1, keepdims=True), 1e-12)
    normals = np.stack([-seg[:, 1], seg[:, 0]], axis=1)
    vertex = np.vstack([normals[:1], normals[:-1] + normals[1:], normals[-1:]])
    vertex /= np.maximum(np.linalg.norm(vertex, axis=1, keepdims=True), 1e-12)
    return xy + offset * vertex


def lane_polygon(m: RoadMap, lane: int) -> np.ndarray:
    """The surface of a lane (n, 2) [m]: its centreline offset by half its width to each side."""
    xy = m.polyline(lane)
    half = 0.5 * float(m.lane_width[lane])
    return np.vstack([offset_polyline(xy, half), offset_polyline(xy, -half)[::-1]])


def zebra_stripes(m: RoadMap, lane: int) -> list[np.ndarray]:
    """The stripes (4, 2) [m] of a crossing lane: 0.5 m painted, 0.5 m gap along it."""
    xy, s = m.polyline(lane), m.polyline_s(lane)
    half = 0.5 * float(m.lane_width[lane])
    stripes = []
    for s0 in np.arange(0.25, s[-1] - 0.5, ZEBRA_PERIOD):
        a = np.array([np.interp(s0, s, xy[:, 0]), np.interp(s0, s, xy[:, 1])])
        b = np.array([np.interp(s0 + 0.5, s, xy[:, 0]), np.interp(s0 + 0.5, s, xy[:, 1])])
        direction = (b - a) / max(np.linalg.norm(b - a), 1e-9)
        n = np.array([-direction[1], direction[0]]) * half
        stripes.append(np.array([a - n, b - n, b + n, a + n]))
    return stripes


def junction_polygons(m: RoadMap) -> list[np.ndarray]:
    """Outline polygons (n, 2) [m] of the junctions that have one."""
    return [m.junction_shape(j) for j in range(len(m.junction_ids)) if len(m.junction_shape(j)) >= 3]


class Markings(NamedTuple):
    """Road markings as polylines (n, 2) [m]."""

    solid: list[np.ndarray]  # white road edges
    dashed: list[np.ndarray]  # white lines between same-direction lanes
    centre: list[np.ndarray]  # yellow line between opposite directions
    stop: list[np.ndarray]  # (2, 2) stop lines, right end first


def marking_lines(m: RoadMap) -> Markings:
    """The markings of the normal driving lanes: a yellow centre line where an opposite lane lies directly
    to the left, a dashed white line between same-direction driving lanes, a solid white line at the
    road edges; and the stop lines."""
    solid: list[np.ndarray] = []
    dashed: list[np.ndarray] = []
    centre: list[np.ndarray] = []
    normal_driving = np.flatnonzero((m.lane_kind == LaneKind.DRIVING) & ~m.lane_internal)
    for lane in normal_driving.tolist():
        xy = m.polyline(lane)
        half = 0.5 * float(m.lane_width[lane])
        left, right = m.lane_left[lane], m.lane_right[lane]
        if m.lane_opposite[lane] >= 0:
            centre.append(offset_polyline(xy, half))
        elif left >= 0 and m.lane_kind[left] == LaneKind.DRIVING:
            dashed.append(offset_polyline(xy, half))
        else:
            solid.append(offset_polyline(xy, half))
        if right < 0 or m.lane_kind[right] != LaneKind.DRIVING:
            solid.append(offset_polyline(xy, -half))
    return Markings(solid, dashed, centre, list(m.stop_xy))
