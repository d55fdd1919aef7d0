"""Elevation of actors from the lanes they are on, and which actors share a level.

Our collisions, corridors and forecasts are 2D. On the CARLA towns roads cross at two heights (Town04's
highway over its ring road, Town03's and Town05's bridges): an actor on the bridge and one on the road
below overlap in the ground plane without being anywhere near each other. The networks netconvert builds
from OpenDRIVE keep each lane point's z (flat lanes have none: 0 m), so an actor's elevation is the z of
its lane's centreline at the point nearest to it, interpolated along the segment. Actors off the network
(lane -1) get NaN: their level is unknown and they count as on every level.

A compiled loop over the actors and their lane's segments, because it runs every tick for every actor on
maps with elevation (a few hundred actors, lanes of a few to ~60 points: ~10 us).
"""

from __future__ import annotations

import numba
import numpy as np

from cmudrive.maps.model import RoadMap

LEVEL_CLEARANCE = 3.0  # [m] actors whose elevations differ by more than this are on different levels


def actor_elevation(road_map: RoadMap, lane: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(A,) float64 elevation [m] of actors at (x, y) on map lanes ``lane`` (A,), NaN for lane -1; zeros
    (and NaN off the network) on a map without elevation, without looking at the lanes."""
    lane = np.asarray(lane, np.int64)
    if not road_map.has_elevation:
        return np.where(lane >= 0, 0.0, np.nan)
    return _elevation(
        lane,
        np.asarray(x, np.float64),
        np.asarray(y, np.float64),
        road_map.lane_pt_ptr,
        road_map.pt_xy,
        road_map.pt_z,
    )


def other_level(z_a: np.ndarray | float, z_b: np.ndarray | float) -> np.ndarray:
    """Whether elevations ``z_a`` and ``z_b`` (broadcast) are on different levels; NaN (unknown) never is."""
    with np.errstate(invalid="ignore"):
        return np.abs(np.asarray(z_a) - np.asarray(z_b)) > LEVEL_CLEARANCE


@numba.njit(cache=True)
def _elevation(
    lane: np.ndarray, x: np.ndarray, y: np.ndarray, ptr: np.ndarray, pt_xy: np.ndarray, pt_z: np.ndarray
) -> np.ndarray:
    n = lane.shape[0]
    z = np.full(n, np.nan)
    for i in range(n):
        k = lane[i]
        if k < 0:
            continue
        a, b = ptr[k], ptr[k + 1]
        best, best_z = np.inf, pt_z[a]
        for p in range(a, b - 1):
            ex, ey = pt_xy[p + 1, 0] - pt_xy[p, 0], pt_xy[p + 1, 1] - pt_xy[p, 1]
            dx, dy = x[i] - pt_xy[p, 0], y[i] - pt_xy[p, 1]
            t = min(max((dx * ex + dy * ey) / max(ex * ex + ey * ey, 1e-12), 0.0), 1.0)
            d2 = (dx - t * ex) ** 2 + (dy - t * ey) ** 2
            if d2 < best:
                best, best_z = d2, pt_z[p] + t * (pt_z[p + 1] - pt_z[p])
        z[i] = best_z
    return z
