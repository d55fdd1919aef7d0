"""Progress along the dense routes of all CAVs at once: route completion, deviation and the time budget.

The routes of a route's CAVs differ in length; :class:`RouteTable` pads them to one length by repeating the
last point, so every per-tick query gathers a small window of points for all CAVs with one fancy index.
One route index per CAV (the furthest route point it has passed) drives route completion, the distance
counted for route deviation and outside-lanes, the minimum-speed checkpoint and the route timeout budget.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmudrive.maps.routing import Route

_MIN_LIMIT = 0.1  # [m/s] floor on a route point's speed limit when computing the time budget


@dataclass(frozen=True)
class RouteTable:
    """The dense routes of ``n`` CAVs padded to ``P`` points (the last point repeated)."""

    xy: np.ndarray  # (n, P, 2) float64 route points [m]
    forward: np.ndarray  # (n, P, 2) float64 unit direction of travel at each point
    distance: np.ndarray  # (n, P) float64 distance along the route from its start [m]
    budget: np.ndarray  # (n, P) float64 extra time budget earned by reaching each point [s]
    length: np.ndarray  # (n,) float64 route length [m]
    last: np.ndarray  # (n,) int64 index of the last real point

    @staticmethod
    def build(routes: list[Route], speed_fraction: float) -> RouteTable:
        n = len(routes)
        width = max(len(r) for r in routes)
        xy = np.zeros((n, width, 2))
        heading = np.zeros((n, width))
        distance = np.zeros((n, width))
        budget = np.zeros((n, width))
        for i, r in enumerate(routes):  # once per route, at setup
            m = len(r)
            xy[i, :m], xy[i, m:] = r.xy, r.xy[-1]
            heading[i, :m], heading[i, m:] = r.heading, r.heading[-1]
            distance[i, :m], distance[i, m:] = r.distance, r.distance[-1]
            # reaching point j earns the time to drive the metres before it at a fraction of their limit
            step = np.diff(r.distance) / (speed_fraction * np.maximum(r.speed_limit[:-1], _MIN_LIMIT))
            budget[i, 1:m] = np.cumsum(step)
            budget[i, m:] = budget[i, m - 1]
        forward = np.stack([np.cos(heading), np.sin(heading)], axis=-1)
        last = np.array([len(r) - 1 for r in routes], np.int64)
        return RouteTable(xy, forward, distance, budget, distance[np.arange(n), last], last)

    def window(self, cav: np.ndarray, start: np.ndarray, size: int) -> np.ndarray:
        """(m, size) route indices start, start + 1, ... of CAVs ``cav`` (m,), clipped to each route's end."""
        return np.minimum(start[:, None] + np.arange(size), self.last[cav][:, None])

    def completion(self, cav: np.ndarray, index: np.ndarray) -> np.ndarray:
        """(m,) route completion [%] of CAVs ``cav`` at route indices ``index``."""
        return 100.0 * self.distance[cav, index] / np.maximum(self.length[cav], 1e-9)


def advance(table: RouteTable, cav: np.ndarray, index: np.ndarray, xy: np.ndarray, window: int) -> np.ndarray:
    """(m,) new route index: the furthest of the current and the next ``window`` points whose forward
    direction the position ``xy`` (m, 2) has passed, ``(xy - point) . forward(point) > 0``."""
    cand = table.window(cav, index, window + 1)  # (m, w + 1)
    rows = cav[:, None]
    ahead = np.einsum("mwc,mwc->mw", xy[:, None, :] - table.xy[rows, cand], table.forward[rows, cand])
    return np.max(np.where(ahead > 0.0, cand, index[:, None]), axis=1)


def distance_to_route(
    table: RouteTable, cav: np.ndarray, index: np.ndarray, xy: np.ndarray, window: int
) -> np.ndarray:
    """(m,) distance [m] from ``xy`` (m, 2) to the nearest of ``window`` route points, current one first."""
    cand = table.window(cav, index, window)
    return np.min(np.linalg.norm(xy[:, None, :] - table.xy[cav[:, None], cand], axis=-1), axis=1)
