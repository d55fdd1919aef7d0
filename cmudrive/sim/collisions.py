"""Oriented-bounding-box collisions between every pair of actors of a snapshot, vectorised.

Why our own code: SUMO's collision check is lane based (gaps between leader and follower on a lane,
optionally junction foes); it neither sees actors that leave the lane geometry nor scores CAVs that we
move ourselves, and it reports no contact geometry. Polygon libraries (shapely) build one Python object
per box and test one pair at a time, which is far too slow for a check that runs on every tick of every
route. Rectangles need very little: a broad phase on box centres and a separating-axis test (SAT) with
the four face normals of the two boxes, both done on arrays over all candidate pairs at once.

Conventions
- Boxes are the snapshot's: centre (x, y) [m], yaw [rad] counter-clockwise from +x, length along the
  heading and width across it [m]. Every kind collides with every kind (props and pedestrians too);
  only rows with ``valid`` take part.
- A pair collides when its *penetration* exceeds ``TOUCH_TOLERANCE``. Penetration is the smallest, over
  the four SAT axes, of the push along that axis that separates the boxes (radius of a + radius of b -
  |centre offset . axis|): the overlap of the two projections when neither contains the other, and the
  depth of the minimum translation that separates the boxes (e.g. 1.5 m for a 0.5 m pedestrian standing
  at the centre line of a 2.5 m wide bus).
  Boxes that merely touch (penetration 0 within 1e-9 m, e.g. bumpers exactly in contact) do **not**
  collide, so that boxes placed flush against each other (parked cars, cones) are not a crash.
- ``point`` is the mean of the vertices of the overlap polygon (corners of each box that lie inside the
  other plus the crossings of their edges; a corner lying exactly on the other box's edge counts twice):
  an approximation of the centroid of the overlap region, exact for symmetric overlaps, always inside it.
- ``relative_speed`` is |v_a - v_b| with v = speed * (cos yaw, sin yaw) [m/s].
- Events are ordered by ``a`` then ``b`` with ``a < b`` (indices into the snapshot).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from cmudrive.sim.snapshot import Snapshot

TOUCH_TOLERANCE = 1e-9  # [m] penetration at or below this is contact without collision
_PARALLEL_EPS = 1e-12  # [m^2] |cross(r, s)| below this: edges parallel, no single crossing point
_CORNER_SIGNS = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, -1.0], [-1.0, 1.0]])  # (long, lat) FL FR RR RL


@dataclass(frozen=True, eq=False)
class CollisionEvents:
    """Overlapping actor pairs of one snapshot. All arrays have shape (E,) unless noted."""

    a: np.ndarray  # (E,) int64 index of the first actor in the snapshot, a < b
    b: np.ndarray  # (E,) int64 index of the second actor
    id_a: np.ndarray  # (E,) str actor ids
    id_b: np.ndarray  # (E,) str
    kind_a: np.ndarray  # (E,) int8 ActorKind
    kind_b: np.ndarray  # (E,) int8
    role_a: np.ndarray  # (E,) int8 Role
    role_b: np.ndarray  # (E,) int8
    relative_speed: np.ndarray  # (E,) float64 norm of the velocity difference [m/s]
    point: np.ndarray  # (E, 2) float64 approximate contact point in the map frame [m]
    penetration: np.ndarray  # (E,) float64 minimum overlap over the SAT axes [m], > TOUCH_TOLERANCE

    @property
    def num_events(self) -> int:
        return int(self.a.shape[0])

    def __len__(self) -> int:
        return self.num_events

    def select(self, keep: np.ndarray) -> CollisionEvents:
        """The events where ``keep`` (E,) is True, in the same order."""
        return CollisionEvents(**{name: getattr(self, name)[keep] for name in self.__dataclass_fields__})


# Columns of the per-call box table: one row per valid actor, gathered once so that each pair needs a
# single fancy-indexing gather instead of one per field.
_X, _Y, _COS, _SIN, _HALF_LEN, _HALF_WID, _VX, _VY = range(8)


def detect_collisions(snap: Snapshot, active: np.ndarray | None = None) -> CollisionEvents:
    """Every pair of valid actors whose boxes overlap; with ``active`` (A,) bool, only pairs in which at
    least one actor is active (e.g. pairs involving a CAV)."""
    if active is not None:
        active = np.asarray(active)
        if active.shape != (snap.num_actors,) or active.dtype != bool:
            raise ValueError(
                f"active must be bool of shape ({snap.num_actors},), not {active.dtype} {active.shape}"
            )
    rows, table = _box_table(snap)  # rows: (V,) increasing snapshot indices of the valid actors
    li, lj = _broad_phase(table, None if active is None else active[rows])  # (P,) rows of the table
    if li.shape[0] > 0:
        penetration = _sat_penetration(table[li], table[lj])
        hit = penetration > TOUCH_TOLERANCE
        li, lj, penetration = li[hit], lj[hit], penetration[hit]
    else:
        penetration = np.zeros(0)
    order = np.lexsort((lj, li))  # rows is increasing, so this also sorts by snapshot index
    li, lj, penetration = li[order], lj[order], penetration[order]
    a, b = rows[li], rows[lj]
    ta, tb = table[li], table[lj]
    return CollisionEvents(
        a=a,
        b=b,
        id_a=snap.ids[a],
        id_b=snap.ids[b],
        kind_a=snap.kind[a],
        kind_b=snap.kind[b],
        role_a=snap.role[a],
        role_b=snap.role[b],
        relative_speed=np.hypot(ta[:, _VX] - tb[:, _VX], ta[:, _VY] - tb[:, _VY]),
        point=_contact_point(ta, tb),
        penetration=penetration,
    )


def _box_table(snap: Snapshot) -> tuple[np.ndarray, np.ndarray]:
    """Snapshot indices (V,) of the valid actors and their box table (V, 8); rejects non-finite rows."""
    rows = np.flatnonzero(snap.valid)
    yaw, speed = snap.yaw[rows], snap.speed[rows]
    c, s = np.cos(yaw), np.sin(yaw)
    table = np.column_stack(
        [
            snap.x[rows],
            snap.y[rows],
            c,
            s,
            0.5 * snap.length[rows],
            0.5 * snap.width[rows],
            speed * c,
            speed * s,
        ]
    ).astype(np.float64, copy=False)
    bad = ~np.isfinite(table).all(axis=1)
    if np.any(bad):
        raise ValueError(f"non-finite pose, extent or speed for actors {snap.ids[rows[bad]][:5].tolist()}")
    return rows, table


def _broad_phase(table: np.ndarray, active: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Row pairs (i < j) of the box table whose bounding circles (radius = half-diagonal) intersect and,
    with ``active`` (V,) bool, of which at least one row is active."""
    empty = np.zeros(0, np.int64)
    if table.shape[0] < 2 or (active is not None and not np.any(active)):
        return empty, empty
    xy = table[:, :2]
    radius = np.hypot(table[:, _HALF_LEN], table[:, _HALF_WID])
    reach = float(np.sum(np.partition(radius, -2)[-2:]))  # largest sum of two half-diagonals [m]
    pairs = cKDTree(xy).query_pairs(reach, output_type="ndarray").astype(np.int64)  # (P, 2), i < j
    i, j = pairs[:, 0], pairs[:, 1]
    keep = np.sum((xy[i] - xy[j]) ** 2, axis=1) <= (radius[i] + radius[j]) ** 2
    if active is not None:
        keep &= active[i] | active[j]
    return i[keep], j[keep]


def _sat_penetration(ta: np.ndarray, tb: np.ndarray) -> np.ndarray:
    """(P,) minimum overlap over the 4 face normals of the box pairs (ta[p], tb[p]) [m]; <= 0: apart."""
    xa, ya, ca, sa, hla, hwa = ta[:, :6].T
    xb, yb, cb, sb, hlb, hwb = tb[:, :6].T
    dx, dy = xb - xa, yb - ya
    cos_rel = np.abs(ca * cb + sa * sb)  # |cos(yaw_b - yaw_a)|
    sin_rel = np.abs(sb * ca - cb * sa)  # |sin(yaw_b - yaw_a)|
    # axes: heading of a, left normal of a, heading of b, left normal of b;
    # overlap on an axis = radius of a + radius of b - |centre offset . axis|
    overlap = np.stack(
        [
            hla + hlb * cos_rel + hwb * sin_rel - np.abs(dx * ca + dy * sa),
            hwa + hlb * sin_rel + hwb * cos_rel - np.abs(dy * ca - dx * sa),
            hlb + hla * cos_rel + hwa * sin_rel - np.abs(dx * cb + dy * sb),
            hwb + hla * sin_rel + hwa * cos_rel - np.abs(dy * cb - dx * sb),
        ]
    )  # (4, P)
    return np.min(overlap, axis=0)


def _contact_point(ta: np.ndarray, tb: np.ndarray) -> np.ndarray:
    """(E, 2) mean of the overlap polygon's vertices: corners of each box inside the other, plus the
    crossings of their edges. Both directions (a in b, b in a) are stacked into one (2E, ...) batch."""
    e = ta.shape[0]
    if e == 0:
        return np.zeros((0, 2))
    boxes, others = np.concatenate([ta, tb]), np.concatenate([tb, ta])  # (2E, 8)
    corners = _corners(boxes)  # (2E, 4, 2)
    inside = _inside(corners, others)  # (2E, 4)
    corner_sum = np.einsum("nk,nkd->nd", inside.astype(np.float64), corners)  # (2E, 2)
    corner_count = inside.sum(axis=1)
    # edge k of a, p_k + t r_k, against edge m of b, q_m + u s_m: (E, 4, 4) arrays
    edges = np.roll(corners, -1, axis=1) - corners  # (2E, 4, 2)
    p, r = corners[:e, :, None, :], edges[:e, :, None, :]
    q, s = corners[e:, None, :, :], edges[e:, None, :, :]
    denom = _cross(r, s)
    parallel = np.abs(denom) <= _PARALLEL_EPS
    denom = np.where(parallel, 1.0, denom)
    t = _cross(q - p, s) / denom
    u = _cross(q - p, r) / denom
    crosses = ~parallel & (t >= 0.0) & (t <= 1.0) & (u >= 0.0) & (u <= 1.0)  # (E, 4, 4)
    crossing_sum = np.einsum("ekm,ekmd->ed", crosses.astype(np.float64), p + t[..., None] * r)
    total = corner_sum[:e] + corner_sum[e:] + crossing_sum
    count = corner_count[:e] + corner_count[e:] + crosses.sum(axis=(1, 2))
    midpoint = 0.5 * (ta[:, :2] + tb[:, :2])  # fallback, unreachable for penetration > 0
    return np.where(count[:, None] > 0, total / np.maximum(count, 1)[:, None], midpoint)


def _corners(t: np.ndarray) -> np.ndarray:
    """(N, 4, 2) corners of the boxes of table rows t (N, 8), ordered like ``Snapshot.corners``."""
    lon = _CORNER_SIGNS[:, 0] * t[:, _HALF_LEN, None]  # (N, 4)
    lat = _CORNER_SIGNS[:, 1] * t[:, _HALF_WID, None]
    c, s = t[:, _COS, None], t[:, _SIN, None]
    return np.stack([t[:, _X, None] + lon * c - lat * s, t[:, _Y, None] + lon * s + lat * c], axis=-1)


def _inside(points: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, 4) whether points (N, 4, 2) lie in the boxes t (N, 8), boundary included within tolerance."""
    d = points - t[:, None, :2]
    c, s = t[:, _COS, None], t[:, _SIN, None]
    lon = np.abs(d[..., 0] * c + d[..., 1] * s)
    lat = np.abs(d[..., 1] * c - d[..., 0] * s)
    return (lon <= t[:, _HALF_LEN, None] + TOUCH_TOLERANCE) & (lat <= t[:, _HALF_WID, None] + TOUCH_TOLERANCE)


def _cross(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """z component of the 2D cross product over the last axis."""
    return p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0]
