"""Per-route arrays the expert reads every tick: the CAVs' dense routes padded into one array, the speed
each route point allows (limit, curvature, junction cap), and the junction entries with their stop lines.

Routes are 1 m apart (``cmudrive.maps.Route``). Past its last point each route goes on straight for
``TAIL`` metres along its last heading, so that look-ahead windows near the end stay meaningful: a CAV is
finished (and leaves the world) once its centre is within 10 m of the last point with 99 % of the route
done, before it reaches the tail.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from cmudrive.maps import RoadMap, Route
from cmudrive.maps.model import NO_INDEX, JunctionKind, StopKind

TAIL = 120  # [m] straight extension past each route's last point


class EntryKind:
    """What controls a junction entry on a route (int codes in :attr:`RoutePlans.entry_kind`)."""

    FREE = 0  # a major link, nothing to stop for
    LIGHT = 1  # signalised
    STOP_SIGN = 2  # a stop sign: full stop, then yield
    ALLWAY_STOP = 3  # an all-way stop: full stop, then first come first served
    YIELD = 4  # a minor link of a priority or right-before-left junction: give way to the foes


@dataclass
class RoutePlans:
    """``n`` routes padded to ``P`` points (+ ``TAIL``); junction entries padded to ``E`` per route."""

    xy: np.ndarray  # (n, P, 2) [m]
    heading: np.ndarray  # (n, P) [rad]
    distance: np.ndarray  # (n, P) [m] along the route from its start
    allowed: np.ndarray  # (n, P) [m/s] the speed each point allows on its own (limit, curvature, junction)
    num_points: np.ndarray  # (n,) points of each route without the tail
    # junction entries along each route, in route order, padded with -1 / inf
    entry_distance: np.ndarray  # (n, E) [m] route distance of the stop line / junction border
    entry_link: np.ndarray  # (n, E) int64 the map link the route takes there
    entry_kind: np.ndarray  # (n, E) int8 EntryKind


def build_plans(
    road_map: RoadMap,
    routes: list[Route],
    speed_factor: float,
    max_speed: float,
    lateral_accel: float,
    junction_cap: float,
    junction_cap_distance: float,
) -> RoutePlans:
    n = len(routes)
    width = max(len(r) for r in routes) + TAIL
    xy = np.zeros((n, width, 2))
    heading = np.zeros((n, width))
    distance = np.zeros((n, width))
    allowed = np.zeros((n, width))
    entries = [_entries(road_map, r) for r in routes]
    e_width = max(1, max(len(e) for e in entries))
    entry_distance = np.full((n, e_width), np.inf)
    entry_link = np.full((n, e_width), NO_INDEX, np.int64)
    entry_kind = np.zeros((n, e_width), np.int8)
    for i, r in enumerate(routes):
        k = len(r)
        tail = np.arange(1, width - k + 1, dtype=float)
        direction = np.array([np.cos(r.heading[-1]), np.sin(r.heading[-1])])
        xy[i, :k], xy[i, k:] = r.xy, r.xy[-1] + tail[:, None] * direction
        heading[i, :k], heading[i, k:] = r.heading, r.heading[-1]
        distance[i, :k], distance[i, k:] = r.distance, r.distance[-1] + tail
        limit = np.minimum(speed_factor * r.speed_limit, max_speed)
        limit = np.minimum(limit, _curve_speed(r, lateral_accel))
        near_junction = _within_distance_of(r.distance, r.in_junction, junction_cap_distance)
        limit = np.where(near_junction, np.minimum(limit, junction_cap), limit)
        allowed[i, :k], allowed[i, k:] = limit, limit[-1]
        for j, (d, link, kind) in enumerate(entries[i]):
            entry_distance[i, j], entry_link[i, j], entry_kind[i, j] = d, link, kind
    return RoutePlans(
        xy=xy,
        heading=heading,
        distance=distance,
        allowed=allowed,
        num_points=np.array([len(r) for r in routes]),
        entry_distance=entry_distance,
        entry_link=entry_link,
        entry_kind=entry_kind,
    )


def _curve_speed(route: Route, lateral_accel: float, half_window: int = 3) -> np.ndarray:
    """[m/s] sqrt(a_lat / curvature), curvature from the heading change over +-``half_window`` metres."""
    if len(route) < 2:
        return np.full(len(route), np.inf)
    h = np.unwrap(route.heading)
    lo = np.maximum(np.arange(len(h)) - half_window, 0)
    hi = np.minimum(np.arange(len(h)) + half_window, len(h) - 1)
    span = np.maximum(route.distance[hi] - route.distance[lo], 1e-6)
    curvature = np.abs(h[hi] - h[lo]) / span
    return np.sqrt(lateral_accel / np.maximum(curvature, 1e-6))


def _within_distance_of(distance: np.ndarray, flag: np.ndarray, reach: float) -> np.ndarray:
    """(n,) points from which a flagged point lies at most ``reach`` metres ahead (or which are flagged)."""
    out = flag.copy()
    marks = distance[flag]
    if len(marks):
        nxt = np.searchsorted(marks, distance)
        has = nxt < len(marks)
        out[has] |= marks[nxt[has]] - distance[has] <= reach
    return out


def _entries(road_map: RoadMap, route: Route) -> list[tuple[float, int, int]]:
    """(distance, link, EntryKind) of every junction the route enters from a normal lane."""
    m = road_map
    out = []
    stop_of_lane = {int(lane): k for k, lane in enumerate(m.stop_lane)}
    path = route.path
    for a, b in itertools.pairwise(path):
        if m.lane_internal[a] or not m.lane_internal[b]:
            continue
        links = m.successor_links(int(a))[m.successors(int(a)) == b]
        if len(links) == 0:
            continue
        link = int(links[0])
        on_a = np.flatnonzero(route.lane == a)
        if len(on_a):  # the line lies at the end of lane a
            last = int(on_a[-1])
            d = float(route.distance[last] + max(m.lane_length[a] - route.s[last], 0.0))
        else:  # lane a is shorter than the point spacing: the first point past it
            nxt = np.flatnonzero(route.lane == b)
            if len(nxt) == 0:
                continue
            d = float(route.distance[int(nxt[0])])
        stop = stop_of_lane.get(int(a), NO_INDEX)
        out.append((d, link, _entry_kind(m, link, stop, int(m.link_junction[link]))))
    return out


def _entry_kind(m: RoadMap, link: int, stop: int, junction: int) -> int:
    if m.link_tls[link] >= 0:
        return EntryKind.LIGHT
    if stop >= 0 and m.stop_kind[stop] == StopKind.STOP_SIGN:
        return EntryKind.STOP_SIGN
    if stop >= 0 and m.stop_kind[stop] == StopKind.ALLWAY_STOP:
        return EntryKind.ALLWAY_STOP
    state = str(m.link_state[link])
    if state in ("s",):
        return EntryKind.STOP_SIGN
    if state in ("w",):
        return EntryKind.ALLWAY_STOP
    if state in ("m", "=") or (junction >= 0 and m.junction_kind[junction] == JunctionKind.RIGHT_BEFORE_LEFT):
        return EntryKind.YIELD if len(m.yields_to(link)) else EntryKind.FREE
    return EntryKind.FREE
