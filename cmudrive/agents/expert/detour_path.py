"""Where a detour's path can go: the lanes beside each route and the shifts fitted to them.

:class:`RouteLanes` holds, per route point, what lies beside the route's lane (the lane on each side and
whether it is a same-direction or an oncoming lane, the paved edges, the distance to the next junction
entry) and puts actors into a route's frame (:meth:`RouteLanes.pairs`). A shift is a :class:`Segment` in
route distance: ramp up from s0 to p0, plateau to p1, ramp down to s1 (cosine profile); :func:`fit` keeps
it on the paved road and says which lane it borrows, :func:`merge` joins same-side segments that overlap.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cmudrive.agents.expert.detour_config import Borrow, DetourConfig, DetourReason
from cmudrive.agents.expert.detour_detect import Ego, Pairs, near_route_points
from cmudrive.maps import RoadMap, Route, other_level
from cmudrive.maps.model import NO_INDEX, LaneKind
from cmudrive.sim.snapshot import Snapshot


class RouteLanes:
    """Per-point arrays of every route the planner serves (padded to one length), route index first."""

    def __init__(self, road_map: RoadMap, routes: list[Route], horizon: int) -> None:
        """Arrays long enough to read ``horizon`` points past each route's end."""
        self.map = road_map
        n = len(routes)
        pad = max(len(r) for r in routes) + horizon + 2
        self.length = np.array([len(r) for r in routes], np.int64)
        self.xy = np.zeros((n, pad, 2))  # (n, P, 2) route points, the last one repeated [m]
        self.heading = np.zeros((n, pad))  # (n, P) [rad]
        self.dist = np.zeros((n, pad))  # (n, P) route distance, extended 1 m a point past the end [m]
        self.half = np.zeros((n, pad))  # (n, P) half the route lane's width [m]
        self.edge_left = np.zeros((n, pad))  # (n, P) paved edge on the left (own + borrowable lane) [m]
        self.edge_right = np.zeros((n, pad))  # (n, P) right edge of the driving lanes [m]
        self.paved_right = np.zeros((n, pad))  # (n, P) right edge incl. a parking lane or shoulder [m]
        self.left_kind = np.zeros((n, pad), np.int8)  # (n, P) Borrow on the left
        self.right_kind = np.zeros((n, pad), np.int8)  # (n, P) Borrow on the right (SAME or NONE)
        self.nb_left = np.zeros((n, pad))  # (n, P) width of the lane on the left (0 none) [m]
        self.nb_right = np.zeros((n, pad))  # (n, P) width of the same-direction lane on the right [m]
        self.to_junction = np.full((n, pad), np.inf)  # (n, P) route distance to the next junction entry [m]
        self.speed_limit = np.zeros((n, pad))  # (n, P) [m/s]
        for i, r in enumerate(routes):
            self._fill(i, r)

    # ------------------------------------------------------------------ per-route arrays
    def _fill(self, i: int, r: Route) -> None:
        m, k = self.map, len(r)
        self.xy[i, :k], self.xy[i, k:] = r.xy, r.xy[-1]
        self.heading[i, :k], self.heading[i, k:] = r.heading, r.heading[-1]
        self.dist[i, :k] = r.distance
        self.dist[i, k:] = r.distance[-1] + np.arange(1, self.xy.shape[1] - k + 1)
        self.speed_limit[i, :k], self.speed_limit[i, k:] = r.speed_limit, r.speed_limit[-1]
        lane = r.lane.astype(np.int64)
        half = 0.5 * m.lane_width[lane]
        left, right, opposite = m.lane_left[lane], m.lane_right[lane], m.lane_opposite[lane]
        driving = m.lane_kind == LaneKind.DRIVING
        same_left = (left != NO_INDEX) & driving[np.maximum(left, 0)]
        onc_left = ~same_left & (opposite != NO_INDEX)
        same_right = (right != NO_INDEX) & driving[np.maximum(right, 0)]
        nb_left = np.where(same_left, m.lane_width[np.maximum(left, 0)], 0.0)
        nb_left = np.where(onc_left, m.lane_width[np.maximum(opposite, 0)], nb_left)
        nb_right = np.where(same_right, m.lane_width[np.maximum(right, 0)], 0.0)
        inside = r.in_junction | m.lane_internal[lane]
        nb_left[inside], nb_right[inside] = 0.0, 0.0
        kind_left = np.where(same_left, Borrow.SAME, np.where(onc_left, Borrow.ONCOMING, Borrow.NONE))
        kind_left[inside] = Borrow.NONE
        kind_right = np.where(same_right & ~inside, Borrow.SAME, Borrow.NONE)
        self.half[i, :k], self.half[i, k:] = half, half[-1]
        self.nb_left[i, :k], self.nb_right[i, :k] = nb_left, nb_right
        self.left_kind[i, :k], self.right_kind[i, :k] = kind_left, kind_right
        self.edge_left[i, :k], self.edge_left[i, k:] = half + nb_left, half[-1]
        self.edge_right[i, :k], self.edge_right[i, k:] = half + nb_right, half[-1]
        side = self._side_lane_width(lane)
        self.paved_right[i, :k] = self.edge_right[i, :k] + np.where(same_right | inside, 0.0, side)
        self.paved_right[i, k:] = half[-1]
        entry = np.flatnonzero(r.in_junction[1:] & ~r.in_junction[:-1]) + 1  # first points in a junction
        if len(entry):
            nxt = np.searchsorted(entry, np.arange(k), side="left")
            ok = nxt < len(entry)
            self.to_junction[i, :k][ok] = r.distance[entry[nxt[ok]]] - r.distance[ok]

    def _side_lane_width(self, lane: np.ndarray) -> np.ndarray:
        """(k,) width of the parking lane or shoulder right of each lane (0 when none) [m]."""
        m = self.map
        out = np.zeros(len(lane))
        for u in np.unique(lane).tolist():
            same = np.flatnonzero((m.lane_edge == m.lane_edge[u]) & (m.lane_index == m.lane_index[u] - 1))
            if len(same) == 1 and m.lane_kind[same[0]] in (LaneKind.PARKING, LaneKind.SHOULDER):
                out[lane == u] = m.lane_width[same[0]]
        return out

    # ------------------------------------------------------------------ frames
    def along(self, cav_index: np.ndarray, k: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """(n,) route distance [m] of points near route indices k (projected on the tangent there)."""
        h = self.heading[cav_index, k]
        rel = xy - self.xy[cav_index, k]
        return self.dist[cav_index, k] + rel[:, 0] * np.cos(h) + rel[:, 1] * np.sin(h)

    def pairs(
        self,
        snap: Snapshot,
        cav_rows: np.ndarray,
        cav_index: np.ndarray,
        k_ego: np.ndarray,
        reach: np.ndarray,
        cfg: DetourConfig,
    ) -> Pairs:
        """Every (CAV, actor) pair within ``reach`` (n,) [m], with the actor in the CAV's route frame."""
        back = int(cfg.reach) + 10
        fwd = int(max(float(reach.max(initial=0.0)), cfg.reach)) + cfg.horizon
        cav, row, k = near_route_points(
            self.xy, cav_index, k_ego, cav_rows, snap.x, snap.y, snap.valid, reach, back, fwd
        )
        same = ~other_level(snap.z[cav_rows[cav]], snap.z[row])  # not on a bridge over it or a road under
        cav, row, k = cav[same], row[same], k[same]
        i = cav_index[cav]
        hd = self.heading[i, k]
        rel_x, rel_y = snap.x[row] - self.xy[i, k, 0], snap.y[row] - self.xy[i, k, 1]
        s = self.dist[i, k] + rel_x * np.cos(hd) + rel_y * np.sin(hd)
        d = -rel_x * np.sin(hd) + rel_y * np.cos(hd)
        dyaw = snap.yaw[row] - hd
        c, sn = np.abs(np.cos(dyaw)), np.abs(np.sin(dyaw))
        hl, hw = 0.5 * snap.length[row], 0.5 * snap.width[row]
        to_junction = self.to_junction[i, k] - (s - self.dist[i, k])
        return Pairs(
            cav, row, k, s, d, hw * c + hl * sn, hl * c + hw * sn, np.cos(dyaw), self.half[i, k], to_junction
        )


@dataclass
class Segment:
    """One shift in route distance [m]: ramp s0 -> p0, plateau p0 -> p1 at ``amp``, ramp p1 -> s1."""

    s0: float
    p0: float
    p1: float
    s1: float
    amp: float  # [m] + left
    reason: DetourReason
    borrow: Borrow = Borrow.NONE  # the traffic lane entered (needs a clear gap), NONE when it squeezes none
    committed: bool = False
    rows: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # snapshot rows it is for
    stop_at: float = -np.inf  # [m] where a CAV waiting for a clear lane stops (route distance)
    # actor ids of ``rows`` while the segment is held between ticks (rows change as actors come and go)
    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, str))

    def at(self, s: np.ndarray) -> np.ndarray:
        up = smooth((s - self.s0) / max(self.p0 - self.s0, 1e-6))
        down = smooth((self.s1 - s) / max(self.s1 - self.p1, 1e-6))
        return self.amp * np.minimum(up, down)


def smooth(x: np.ndarray) -> np.ndarray:
    """Cosine ramp 0 -> 1 over x in [0, 1] (zero slope at both ends)."""
    return 0.5 - 0.5 * np.cos(np.pi * np.clip(x, 0.0, 1.0))


def fit(lanes: RouteLanes, i: int, seg: Segment, ego: Ego, cfg: DetourConfig) -> Segment | None:
    """``seg`` if the road has room for it all along, else None; where the shifted CAV would come
    closer than ``traffic_clearance`` to a vehicle at the neighbour lane's centre it borrows that lane
    (and goes to its centre, for a same-direction lane with ``full_lane_change``)."""
    lo, hi = np.searchsorted(lanes.dist[i], [seg.s0, seg.s1])
    idx = np.arange(lo, max(hi, lo + 1))
    s, left = lanes.dist[i, idx], seg.amp > 0.0
    kind = (lanes.left_kind if left else lanes.right_kind)[i, idx]
    half, nb = lanes.half[i, idx], (lanes.nb_left if left else lanes.nb_right)[i, idx]
    neighbour_inner = np.where(kind == Borrow.NONE, np.inf, half + 0.5 * nb - cfg.nominal_half_width)
    squeeze = np.abs(seg.at(s)) + ego.half_width + cfg.traffic_clearance > neighbour_inner
    if squeeze.any():
        seg.borrow = Borrow.ONCOMING if (kind[squeeze] == Borrow.ONCOMING).any() else Borrow.SAME
        if seg.borrow == Borrow.ONCOMING:
            seg.reason = DetourReason.ONCOMING_LANE
        elif cfg.full_lane_change:
            centre = float(np.min(half[squeeze] + 0.5 * nb[squeeze]))
            seg.amp = float(np.sign(seg.amp)) * max(abs(seg.amp), centre)
    edge = (lanes.edge_left if left else lanes.edge_right)[i, idx]
    if np.any(np.abs(seg.at(s)) > edge - ego.half_width - cfg.edge_margin + 1e-6):
        return None
    return seg


def merge(segments: list[Segment]) -> list[Segment]:
    """Same-side segments whose spans overlap become one (the first ramp up, the last ramp down)."""
    out: list[Segment] = []
    for side in (1.0, -1.0):
        mine = sorted((g for g in segments if np.sign(g.amp) == side), key=lambda g: g.s0)
        for g in mine:
            last = out[-1] if out and np.sign(out[-1].amp) == side else None
            if last is not None and g.s0 < last.s1:
                if g.p1 > last.p1:
                    last.p1, last.s1 = g.p1, g.s1
                if abs(g.amp) > abs(last.amp):
                    last.amp = g.amp
                    last.reason = g.reason
                last.borrow = Borrow(max(last.borrow, g.borrow))
                last.committed |= g.committed
                last.rows = np.union1d(last.rows, g.rows)
                last.stop_at = min(last.stop_at, g.stop_at) if last.stop_at > -np.inf else g.stop_at
            else:
                out.append(
                    Segment(
                        g.s0,
                        g.p0,
                        g.p1,
                        g.s1,
                        g.amp,
                        g.reason,
                        g.borrow,
                        g.committed,
                        g.rows.copy(),
                        g.stop_at,
                    )
                )
    return out
