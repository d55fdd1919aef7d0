"""Vectorised lane queries: nearest lane, Frenet projection (s, d) and its inverse, heading, width.

The index samples every lane centreline at most ``SAMPLE_STEP`` apart and keeps the samples in a
``scipy.spatial.cKDTree``; a query takes the ``k`` nearest samples, projects the point exactly onto the
polyline segments they belong to, and keeps the best candidate. All queries take arrays of points and
return arrays, with no Python loop over points.

Sign convention: ``d`` is the signed lateral offset, positive to the *left* of the lane's direction
of travel; ``s`` is the arc length from the lane start [m].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from cmudrive.maps.model import NO_INDEX, LaneKind, RoadMap

SAMPLE_STEP = 1.0  # [m] maximum spacing of index samples along a centreline
DEFAULT_K = 12  # nearest samples examined per query point
RETRY_K = 96  # samples examined for points whose k nearest samples were all filtered out
ON_LANE_MARGIN = 0.0  # [m] extra half-width tolerance for "on a driving lane"


@dataclass(frozen=True)
class LaneProjection:
    """Result of a nearest-lane query over ``n`` points."""

    lane: np.ndarray  # (n,) int32 lane index, -1 where nothing matched
    s: np.ndarray  # (n,) float64 arc length along the lane [m]
    d: np.ndarray  # (n,) float64 signed lateral offset, + left [m]
    distance: np.ndarray  # (n,) float64 |d| clipped to the segment, i.e. distance to the centreline [m]
    heading: np.ndarray  # (n,) float64 lane heading at s [rad]


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


class LaneIndex:
    """Spatial index over the segments of every lane of a :class:`RoadMap`."""

    def __init__(self, road_map: RoadMap) -> None:
        self.map = road_map
        ptr = road_map.lane_pt_ptr
        xy = road_map.pt_xy
        n_pts = len(xy)
        # segment g runs from point g to g+1; it is valid unless g is the last point of its lane
        seg_valid = np.ones(max(n_pts - 1, 0), dtype=bool)
        seg_valid[ptr[1:-1] - 1] = False
        self.seg_lane = np.repeat(np.arange(road_map.num_lanes, dtype=np.int32), np.diff(ptr))[:-1]
        self.seg_start = xy[:-1]
        self.seg_vec = np.diff(xy, axis=0)
        self.seg_len = np.linalg.norm(self.seg_vec, axis=1)
        self.seg_heading = np.arctan2(self.seg_vec[:, 1], self.seg_vec[:, 0])
        # samples: every segment split into ceil(len / step) pieces, sample at each piece's midpoint
        seg_ids = np.flatnonzero(seg_valid)
        pieces = np.maximum(1, np.ceil(self.seg_len[seg_ids] / SAMPLE_STEP).astype(np.int64))
        sample_seg = np.repeat(seg_ids, pieces)
        first = np.repeat(np.cumsum(pieces) - pieces, pieces)
        frac = (np.arange(len(sample_seg)) - first + 0.5) / np.repeat(pieces, pieces)
        self.sample_seg = sample_seg
        self.sample_xy = self.seg_start[sample_seg] + frac[:, None] * self.seg_vec[sample_seg]
        self.tree = cKDTree(self.sample_xy)
        # a monotone key over all points (lane offset + s) lets searchsorted find the segment at (lane, s)
        self._key_offset = np.concatenate([[0.0], np.cumsum(road_map.lane_length + 1.0)])[:-1]
        lane_of_pt = np.repeat(np.arange(road_map.num_lanes), np.diff(ptr))
        self._key = self._key_offset[lane_of_pt] + road_map.pt_s
        self._kind_masks: dict[tuple[LaneKind, ...], np.ndarray] = {}

    # ------------------------------------------------------------------ projection core
    def _project_segments(self, xy: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Project points (n, 2) onto segments (n, k): returns s, d, distance, each (n, k)."""
        start = self.seg_start[seg]
        vec = self.seg_vec[seg]
        length = np.maximum(self.seg_len[seg], 1e-12)
        rel = xy[:, None, :] - start
        t = np.clip(np.einsum("nkc,nkc->nk", rel, vec) / length**2, 0.0, 1.0)
        foot = start + t[..., None] * vec
        distance = np.linalg.norm(xy[:, None, :] - foot, axis=-1)
        d = (vec[..., 0] * rel[..., 1] - vec[..., 1] * rel[..., 0]) / length
        s = self.map.pt_s[seg] + t * length
        return s, d, distance

    def nearest_lane(
        self,
        xy: np.ndarray,
        heading: np.ndarray | float | None = None,
        max_heading_diff: float = np.pi / 2,
        kinds: tuple[LaneKind, ...] | None = (LaneKind.DRIVING,),
        k: int = DEFAULT_K,
        max_distance: float = np.inf,
    ) -> LaneProjection:
        """Nearest lane (of the given ``kinds``; None = any) to each point, optionally heading-filtered.

        With ``heading`` (rad, scalar or per point) a lane only matches where its direction differs by
        at most ``max_heading_diff``. Points whose ``k`` nearest samples are all filtered out are searched
        again among ``RETRY_K`` samples; points still unmatched, or farther than ``max_distance``, get
        lane -1 and NaN s/d.
        """
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        result = self._nearest(xy, heading, max_heading_diff, kinds, k, max_distance)
        missed = np.flatnonzero(result.lane < 0)
        if len(missed) and (heading is not None or kinds is not None) and k < RETRY_K:
            # filters rejected every nearby sample: look wider for those points only
            h = (
                None
                if heading is None
                else np.broadcast_to(np.asarray(heading, np.float64), (len(xy),))[missed]
            )
            retry = self._nearest(xy[missed], h, max_heading_diff, kinds, RETRY_K, max_distance)
            for f in ("lane", "s", "d", "distance", "heading"):
                getattr(result, f)[missed] = getattr(retry, f)
        return result

    def _nearest(
        self,
        xy: np.ndarray,
        heading: np.ndarray | float | None,
        max_heading_diff: float,
        kinds: tuple[LaneKind, ...] | None,
        k: int,
        max_distance: float,
    ) -> LaneProjection:
        n = len(xy)
        k = min(k, len(self.sample_xy))
        _, nn = self.tree.query(xy, k=k)
        # a point so far away that its distances overflow gets the missing-neighbour index len(tree):
        # any real sample serves, the distance test below rejects it
        nn = np.minimum(nn.reshape(n, k), len(self.sample_xy) - 1)
        seg = self.sample_seg[nn]
        s, d, distance = self._project_segments(xy, seg)
        cost = distance.copy()
        lane = self.seg_lane[seg]
        if kinds is not None:
            cost[~self._kind_mask(kinds)[lane]] = np.inf
        if heading is not None:
            h = np.broadcast_to(np.asarray(heading, np.float64), (n,))
            diff = np.abs(wrap_angle(self.seg_heading[seg] - h[:, None]))
            cost[diff > max_heading_diff] = np.inf
            # among equally near lanes (overlapping internal lanes), prefer the better-aligned one
            cost = cost + 1e-3 * diff
        cost[distance > max_distance] = np.inf
        best = np.argmin(cost, axis=1)
        rows = np.arange(n)
        ok = np.isfinite(cost[rows, best])
        best_seg = seg[rows, best]
        return LaneProjection(
            lane=np.where(ok, lane[rows, best], NO_INDEX).astype(np.int32),
            s=np.where(ok, s[rows, best], np.nan),
            d=np.where(ok, d[rows, best], np.nan),
            distance=np.where(ok, distance[rows, best], np.nan),
            heading=np.where(ok, self.seg_heading[best_seg], np.nan),
        )

    def _kind_mask(self, kinds: tuple[LaneKind, ...]) -> np.ndarray:
        """(N,) bool mask of lanes of the given kinds, memoised per kinds tuple."""
        mask = self._kind_masks.get(kinds)
        if mask is None:
            mask = np.isin(self.map.lane_kind, np.asarray([int(kd) for kd in kinds], np.int8))
            self._kind_masks[kinds] = mask
        return mask

    def on_driving_lane(
        self, xy: np.ndarray, margin: float = ON_LANE_MARGIN, k: int = DEFAULT_K
    ) -> np.ndarray:
        """(n,) bool: the point lies within half the width (+ margin) of some driving lane's centreline."""
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        k = min(k, len(self.sample_xy))
        _, nn = self.tree.query(xy, k=k)
        seg = self.sample_seg[nn.reshape(len(xy), k)]
        _, _, distance = self._project_segments(xy, seg)
        lane = self.seg_lane[seg]
        inside = distance <= 0.5 * self.map.lane_width[lane] + margin
        return np.any(inside & (self.map.lane_kind[lane] == LaneKind.DRIVING), axis=1)

    # ------------------------------------------------------------------ per-lane queries
    def _segment_at(self, lane: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Global segment index containing arc length s on each lane (s clipped to the lane)."""
        ptr = self.map.lane_pt_ptr
        lo, hi = ptr[lane], ptr[lane + 1] - 1  # first point, last point
        q = self._key_offset[lane] + np.clip(s, 0.0, self.map.lane_length[lane])
        idx = np.searchsorted(self._key, q, side="right") - 1
        return np.clip(idx, lo, hi - 1)

    def frenet_to_xy(self, lane: np.ndarray, s: np.ndarray, d: np.ndarray | float = 0.0) -> np.ndarray:
        """(n, 2) world point at arc length ``s`` and lateral offset ``d`` (+ left) on each ``lane``."""
        lane = np.atleast_1d(np.asarray(lane, np.int64))
        s = np.broadcast_to(np.asarray(s, np.float64), lane.shape)
        d = np.broadcast_to(np.asarray(d, np.float64), lane.shape)
        seg = self._segment_at(lane, s)
        t = (np.clip(s, 0.0, self.map.lane_length[lane]) - self.map.pt_s[seg]) / np.maximum(
            self.seg_len[seg], 1e-12
        )
        base = self.seg_start[seg] + t[:, None] * self.seg_vec[seg]
        h = self.seg_heading[seg]
        return base + d[:, None] * np.stack([-np.sin(h), np.cos(h)], axis=1)

    def heading_at(self, lane: np.ndarray, s: np.ndarray) -> np.ndarray:
        """(n,) lane heading [rad] at arc length s."""
        lane = np.atleast_1d(np.asarray(lane, np.int64))
        s = np.broadcast_to(np.asarray(s, np.float64), lane.shape)
        return self.seg_heading[self._segment_at(lane, s)]

    def width_at(self, lane: np.ndarray, s: np.ndarray | None = None) -> np.ndarray:
        """(n,) lane width [m]; SUMO lanes have one width, so s is accepted for interface symmetry."""
        return self.map.lane_width[np.atleast_1d(np.asarray(lane, np.int64))]

    def project(self, xy: np.ndarray, lane: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Frenet (s, d) of each point on a *given* lane (n,), not the nearest one."""
        xy = np.atleast_2d(np.asarray(xy, np.float64))
        lane = np.broadcast_to(np.atleast_1d(np.asarray(lane, np.int64)), (len(xy),))
        s_out = np.empty(len(xy))
        d_out = np.empty(len(xy))
        ptr = self.map.lane_pt_ptr
        # group points by lane; each group is projected onto all segments of its lane at once
        order = np.argsort(lane, kind="stable")
        uniq, starts = np.unique(lane[order], return_index=True)
        bounds = np.append(starts, len(order))
        for u, a, b in zip(uniq.tolist(), bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):
            rows = order[a:b]
            segs = np.arange(ptr[u], ptr[u + 1] - 1)
            s, d, dist = self._project_segments(xy[rows], np.broadcast_to(segs, (len(rows), len(segs))))
            best = np.argmin(dist, axis=1)
            s_out[rows] = s[np.arange(len(rows)), best]
            d_out[rows] = d[np.arange(len(rows)), best]
        return s_out, d_out
