"""Short-horizon hazard forecast: every CAV rolled along its planned path, every actor near it rolled with
a simple motion model, and the first future step at which the two (enlarged, oriented) boxes overlap.

This is the expert's collision check in the spirit of PDM-Lite (2.0 s ahead, oriented-box overlap per
future frame). It runs every tick for up to 16 CAVs among ~200 actors, so the work is one compiled loop
(numba) over (CAV, actor) pairs with two cheap rejections before any box test: a bounding circle over the
whole horizon (centres farther apart than both can travel plus both box radii: skip) and one per step.

Motion models (``t`` in steps of ``ForecastConfig.step`` from 0 to ``horizon``, both included)
- Ego (a CAV at ``cav_rows[i]``): moves along its path ``paths[i]`` (points ~1 m apart, starting near the
  CAV, padded by repeating the last point). The start is the CAV's position projected onto the first
  ``path_search`` metres of the path (before the first point: on the first segment extended backwards).
  Speed moves from ``speed[i]`` toward ``target_speed[i]`` at ``accel`` (up) or ``decel`` (down) and then
  stays; heading is the tangent of the path segment the ego is on. Past the path's end the ego goes on
  straight along the last segment (a conflict there is still reported: the caller owns the path's end).
- Vehicles (every kind except PEDESTRIAN, other CAVs included): constant speed (signed, as in the
  snapshot) and constant yaw rate, the rate estimated by :class:`Forecaster` from the previous snapshot
  and clipped to ``max_yaw_rate``; the box centre follows the arc. Props and stopped vehicles stay.
- Pedestrians: constant velocity along their heading; one moving faster than ``walker_moving`` walks at
  least ``walker_min_speed`` (PDM-Lite's 0.5 m/s), one slower stands; its box is at least
  ``walker_min_box`` long and wide (PDM-Lite's 1.5 m).

Boxes are enlarged before the test: the ego by ``ego_front_margin`` ahead of its front bumper and
``ego_side_margin`` on each side; other actors by ``other_long_margin`` at each end and
``other_side_margin`` on each side. Overlap is the SAT test of :mod:`cmudrive.sim.collisions`
(penetration above ``TOUCH_TOLERANCE``).

Who reaches the conflict first: at the first overlapping step the *conflict point* is the centroid of the
overlap region (as :func:`cmudrive.sim.collisions.detect_collisions` computes it). Each party's
*arrival* is the time at which the front of its enlarged box first reaches that point along its own
heading (0 if it is already past it; linear between steps), so always <= the conflict time.
``ego_first`` is ``ego_arrival < actor_arrival`` (a tie counts as the actor first: the ego yields).
Examples: a car stopped ahead is past the point from the start (arrival 0), the ego is not first; on a
crossing the one whose side is hit arrived first; a car closing in from behind arrives after the ego.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from cmudrive.maps.elevation import LEVEL_CLEARANCE
from cmudrive.sim.collisions import TOUCH_TOLERANCE, _box_overlap, _contact_point
from cmudrive.sim.snapshot import ActorKind, Snapshot

_DEGENERATE = 1e-6  # [m] path points closer than this to the previous kept one are padding
_STRAIGHT = 1e-6  # [rad/s] below this yaw rate an actor moves on a straight line


@dataclass(frozen=True)
class ForecastConfig:
    """Rollout horizon, motion limits and box margins."""

    horizon: float = 2.0  # [s] how far ahead actors are rolled (PDM-Lite: 2.0 s, 1.1 s near lane changes)
    step: float = 0.1  # [s] time between two tested frames
    radius: float = 50.0  # [m] actors whose centre is farther from the CAV are not rolled
    accel: float = 2.0  # [m/s^2] ego acceleration toward a higher target speed
    decel: float = 4.0  # [m/s^2] ego deceleration toward a lower target speed
    path_search: float = 10.0  # [m] the CAV is projected onto this first stretch of its path
    ego_front_margin: float = 1.0  # [m] added ahead of the ego's front bumper
    ego_side_margin: float = 0.2  # [m] added on each side of the ego
    other_long_margin: float = 0.25  # [m] added at the front and at the rear of other actors
    other_side_margin: float = 0.2  # [m] added on each side of other actors
    max_yaw_rate: float = 1.0  # [rad/s] estimated yaw rates are clipped to this
    walker_moving: float = 0.1  # [m/s] pedestrians slower than this stand still
    walker_min_speed: float = 0.5  # [m/s] moving pedestrians walk at least this fast
    walker_min_box: float = 1.5  # [m] pedestrian boxes are at least this long and wide (margins included)

    def __post_init__(self) -> None:
        if not (self.horizon >= 0.0 and self.step > 0.0 and self.accel > 0.0 and self.decel > 0.0):
            raise ValueError(f"need horizon >= 0 and step, accel, decel > 0: {self}")

    @property
    def num_steps(self) -> int:
        """Tested frames after now (t = step, 2 step, ..., horizon); frame 0 (now) is tested too."""
        return round(self.horizon / self.step)


@dataclass(frozen=True, eq=False)
class Forecast:
    """Conflicts of ``n`` CAVs with every actor of the snapshot. Column ``j`` of every (n, A) array is
    snapshot row ``j`` (A = ``snap.num_actors``); pairs that were not rolled (invalid rows, the CAV itself,
    actors beyond ``radius``) have no conflict."""

    cav_rows: np.ndarray  # (n,) int64 snapshot rows of the CAVs
    first_conflict: np.ndarray  # (n, A) float64 time of the first overlapping frame [s], inf: none
    ego_arrival: np.ndarray  # (n, A) float64 when the ego's front reaches the conflict point [s], inf: none
    actor_arrival: np.ndarray  # (n, A) float64 the same for the actor [s], inf: no conflict
    behind: np.ndarray  # (n, A) bool actor centre behind the ego's rear bumper along the ego heading (now)

    @property
    def actor_rows(self) -> np.ndarray:
        """(A,) int64 snapshot row of each column (the identity: columns are snapshot rows)."""
        return np.arange(self.first_conflict.shape[1], dtype=np.int64)

    @property
    def conflict(self) -> np.ndarray:
        """(n, A) bool: a conflict within the horizon."""
        return np.isfinite(self.first_conflict)

    @property
    def ego_first(self) -> np.ndarray:
        """(n, A) bool: the ego reaches the conflict point strictly before the actor (False: no conflict)."""
        return self.ego_arrival < self.actor_arrival

    def nearest(self, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Per CAV the snapshot row of the earliest conflict among the actors allowed by ``mask`` (n, A)
        bool (None: all) and its time: rows (n,) int64 (-1: none), times (n,) float64 [s] (inf: none).
        Ties go to the lowest row."""
        times = self.first_conflict if mask is None else np.where(mask, self.first_conflict, np.inf)
        n, a = times.shape
        if a == 0:
            return np.full(n, -1, np.int64), np.full(n, np.inf)
        rows = np.argmin(times, axis=1)
        best = times[np.arange(n), rows]
        return np.where(np.isfinite(best), rows, -1).astype(np.int64), best


class Forecaster:
    """Per-route state of the forecast: each actor's yaw rate, from its yaw in the previous snapshot.

    Call :meth:`update` with every snapshot (or at least with each one passed to :meth:`forecast`, which
    updates itself when given a snapshot it has not seen). Rows are matched by ``ids``; actors new in a
    snapshot get yaw rate 0."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._snap: Snapshot | None = None
        self._yaw_rate = np.zeros(0)

    @property
    def yaw_rate(self) -> np.ndarray:
        """(A,) float64 estimated yaw rate of each row of the last snapshot [rad/s], unclipped."""
        return self._yaw_rate

    def update(self, snap: Snapshot) -> None:
        prev = self._snap
        if snap is prev:
            return
        yaw = np.asarray(snap.yaw, np.float64)
        rate = np.zeros(yaw.shape[0])
        if prev is not None:
            match = _match_rows(prev.ids, snap.ids)
            seen = match >= 0
            dt = snap.time - prev.time
            if dt > 0.0:
                turn = yaw[seen] - np.asarray(prev.yaw, np.float64)[match[seen]]
                rate[seen] = (turn + math.pi) % (2.0 * math.pi) - math.pi
                rate[seen] /= dt
            else:  # the same instant again: keep the estimates
                rate[seen] = self._yaw_rate[match[seen]]
        self._snap, self._yaw_rate = snap, rate

    def forecast(
        self,
        snap: Snapshot,
        cav_rows: np.ndarray,
        paths: np.ndarray,
        speed: np.ndarray,
        target_speed: np.ndarray,
        config: ForecastConfig | None = None,
    ) -> Forecast:
        """:func:`forecast` with this forecaster's yaw rates (updated with ``snap`` first if needed)."""
        self.update(snap)
        return forecast(snap, self._yaw_rate, cav_rows, paths, speed, target_speed, config)


def _match_rows(prev_ids: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(A,) int64 row of each of ``ids`` in ``prev_ids``, -1 where absent."""
    if prev_ids is ids or (prev_ids.shape == ids.shape and np.array_equal(prev_ids, ids)):
        return np.arange(ids.shape[0], dtype=np.int64)  # the world shares ``ids`` while nobody comes or goes
    where = {actor_id: row for row, actor_id in enumerate(prev_ids.tolist())}
    return np.array([where.get(actor_id, -1) for actor_id in ids.tolist()], np.int64)


def forecast(
    snap: Snapshot,
    yaw_rate: np.ndarray,
    cav_rows: np.ndarray,
    paths: np.ndarray,
    speed: np.ndarray,
    target_speed: np.ndarray,
    config: ForecastConfig | None = None,
) -> Forecast:
    """Conflicts of the CAVs at snapshot rows ``cav_rows`` (n,) with every valid actor within
    ``config.radius``: ``paths`` (n, P, 2) float64 planned path of each CAV [m] (P >= 1), ``speed`` (n,)
    current and ``target_speed`` (n,) target speed [m/s], ``yaw_rate`` (A,) [rad/s] of every row."""
    cfg = config or ForecastConfig()
    rows = np.asarray(cav_rows, np.int64).reshape(-1)
    n, a = rows.shape[0], snap.num_actors
    paths = np.ascontiguousarray(paths, np.float64)
    speed = np.ascontiguousarray(speed, np.float64).reshape(-1)
    target_speed = np.ascontiguousarray(target_speed, np.float64).reshape(-1)
    if paths.ndim != 3 or paths.shape[0] != n or paths.shape[1] < 1 or paths.shape[2] != 2:
        raise ValueError(f"paths must have shape ({n}, P >= 1, 2), not {paths.shape}")
    if speed.shape != (n,) or target_speed.shape != (n,):
        raise ValueError(
            f"speed and target_speed must have shape ({n},): {speed.shape}, {target_speed.shape}"
        )
    yaw_rate = np.asarray(yaw_rate, np.float64)
    if yaw_rate.shape != (a,):
        raise ValueError(f"yaw_rate must have shape ({a},), not {yaw_rate.shape}")
    if n and (rows.min() < 0 or rows.max() >= a):
        raise ValueError(f"cav_rows out of range for {a} actors: {rows}")
    x, y, yaw, speed_now, length, width = (
        np.asarray(getattr(snap, f), np.float64) for f in ("x", "y", "yaw", "speed", "length", "width")
    )
    conflict, ego_arrival, actor_arrival, behind = _forecast(
        x,
        y,
        yaw,
        speed_now,
        length,
        width,
        np.asarray(snap.kind) == ActorKind.PEDESTRIAN,
        np.asarray(snap.valid, bool),
        np.asarray(snap.z, np.float64),
        yaw_rate,
        rows,
        paths,
        speed,
        target_speed,
        np.array(
            [
                cfg.step,
                cfg.radius,
                cfg.accel,
                cfg.decel,
                cfg.path_search,
                cfg.ego_front_margin,
                cfg.ego_side_margin,
                cfg.other_long_margin,
                cfg.other_side_margin,
                cfg.max_yaw_rate,
                cfg.walker_moving,
                cfg.walker_min_speed,
                cfg.walker_min_box,
            ]
        ),
        cfg.num_steps,
    )
    return Forecast(rows, conflict, ego_arrival, actor_arrival, behind)


# ---- compiled core ----------------------------------------------------------------------------------


@numba.njit(cache=True)
def _travel(v0: float, vt: float, accel: float, decel: float, t: float) -> float:
    """Distance [m] covered in ``t`` [s] from speed v0 moving toward vt at accel (up) / decel (down)."""
    a = accel if vt >= v0 else -decel
    t1 = (vt - v0) / a  # >= 0: time to reach the target speed
    if t <= t1:
        return v0 * t + 0.5 * a * t * t
    return v0 * t1 + 0.5 * a * t1 * t1 + vt * (t - t1)


@numba.njit(cache=True)
def _segments(path: np.ndarray, yaw: float) -> np.ndarray:
    """(S, 6) segments of a path without its repeated points: start x, y, unit direction x, y, length
    [m], arc length at the start [m]. A path of one distinct point gives one endless segment along yaw."""
    seg = np.empty((max(path.shape[0] - 1, 1), 6))
    sx, sy, arc, segs = path[0, 0], path[0, 1], 0.0, 0
    for q in range(1, path.shape[0]):
        length = math.hypot(path[q, 0] - sx, path[q, 1] - sy)
        if length > _DEGENERATE:
            dx, dy = (path[q, 0] - sx) / length, (path[q, 1] - sy) / length
            seg[segs, 0], seg[segs, 1], seg[segs, 2], seg[segs, 3] = sx, sy, dx, dy
            seg[segs, 4], seg[segs, 5] = length, arc
            sx, sy, arc, segs = path[q, 0], path[q, 1], arc + length, segs + 1
    if segs == 0:
        seg[0, 0], seg[0, 1], seg[0, 2], seg[0, 3] = sx, sy, math.cos(yaw), math.sin(yaw)
        seg[0, 4], seg[0, 5], segs = math.inf, 0.0, 1
    return seg[:segs]


@numba.njit(cache=True)
def _project(seg: np.ndarray, px: float, py: float, search: float) -> float:
    """Arc length [m] of the point of the segments nearest to (px, py) among those starting within
    ``search`` metres; the first segment extends backwards (negative arc length)."""
    best, s0 = math.inf, 0.0
    for q in range(seg.shape[0]):
        if q > 0 and seg[q, 5] > search:
            break
        along = (px - seg[q, 0]) * seg[q, 2] + (py - seg[q, 1]) * seg[q, 3]
        along = min(along if q == 0 else max(along, 0.0), seg[q, 4])
        d = math.hypot(seg[q, 0] + along * seg[q, 2] - px, seg[q, 1] + along * seg[q, 3] - py)
        if d < best:
            best, s0 = d, seg[q, 5] + along
    return s0


@numba.njit(cache=True)
def _ego_rollout(
    path: np.ndarray,
    px: float,
    py: float,
    yaw: float,
    v0: float,
    vt: float,
    accel: float,
    decel: float,
    step: float,
    search: float,
    out: np.ndarray,
) -> None:
    """Fill ``out`` (K+1, 4) with x, y, cos, sin of the ego's reference point (on the path) per frame."""
    seg = _segments(path, yaw)
    s0 = _project(seg, px, py, search)
    v0, vt = max(v0, 0.0), max(vt, 0.0)
    q = 0
    for k in range(out.shape[0]):
        s = s0 + _travel(v0, vt, accel, decel, k * step)
        while q + 1 < seg.shape[0] and s >= seg[q + 1, 5]:
            q += 1
        along = s - seg[q, 5]  # < 0 before the first point, > length past the last: straight on
        out[k, 0], out[k, 1] = seg[q, 0] + along * seg[q, 2], seg[q, 1] + along * seg[q, 3]
        out[k, 2], out[k, 3] = seg[q, 2], seg[q, 3]


@numba.njit(cache=True)
def _actor_rollout(
    x: float, y: float, yaw: float, v: float, w: float, step: float, out: np.ndarray
) -> None:  # fmt: skip
    """Fill ``out`` (K+1, 4) with x, y, cos, sin of a box centre moving at speed v, yaw rate w."""
    c0, s0 = math.cos(yaw), math.sin(yaw)
    cw, sw = math.cos(w * step), math.sin(w * step)
    c, s = c0, s0
    for k in range(out.shape[0]):
        if abs(w) > _STRAIGHT:
            out[k, 0], out[k, 1] = x + v / w * (s - s0), y - v / w * (c - c0)
        else:
            out[k, 0], out[k, 1] = x + v * k * step * c0, y + v * k * step * s0
        out[k, 2], out[k, 3] = c, s
        c, s = c * cw - s * sw, s * cw + c * sw


@numba.njit(cache=True)
def _arrival(
    roll: np.ndarray, shift: float, hl: float, px: float, py: float, last: int, step: float
) -> float:
    """Time [s] at which the front of a box (centre ``shift`` ahead of the rolled point, half length hl)
    first reaches (px, py) along its heading, searched over frames 0..last; linear between frames."""
    prev = 0.0
    for k in range(last + 1):
        c, s = roll[k, 2], roll[k, 3]
        ahead = (px - roll[k, 0] - shift * c) * c + (py - roll[k, 1] - shift * s) * s - hl
        if ahead <= 0.0:
            if k == 0:
                return 0.0
            return (k - 1 + prev / (prev - ahead)) * step
        prev = ahead
    return last * step  # the point lies in the box at frame ``last``: not reached only by rounding


@numba.njit(cache=True)
def _first_overlap(
    ego: np.ndarray, shift: float, ehl: float, ehw: float, other: np.ndarray, hl: float, hw: float
) -> int:
    """First frame at which the ego box (centre ``shift`` ahead of the rolled point, half extents ehl,
    ehw) overlaps the other box (rolled centre, half extents hl, hw); -1: none."""
    touch = (math.hypot(ehl, ehw) + math.hypot(hl, hw)) ** 2
    for k in range(ego.shape[0]):
        c, s = ego[k, 2], ego[k, 3]
        x, y = ego[k, 0] + shift * c, ego[k, 1] + shift * s
        if (other[k, 0] - x) ** 2 + (other[k, 1] - y) ** 2 > touch:
            continue
        o = other[k]
        if _box_overlap(x, y, c, s, ehl, ehw, o[0], o[1], o[2], o[3], hl, hw) > TOUCH_TOLERANCE:
            return k
    return -1


@numba.njit(cache=True)
def _overlap_centre(
    ego: np.ndarray, shift: float, ehl: float, ehw: float, other: np.ndarray, hl: float, hw: float
) -> tuple[float, float]:
    """Approximate centroid of the overlap of the ego box and the other box of one frame (x, y, cos, sin
    rows as in ``_first_overlap``), by the collision module's contact point."""
    x = np.array([ego[0] + shift * ego[2], other[0]])
    y = np.array([ego[1] + shift * ego[3], other[1]])
    c, s = np.array([ego[2], other[2]]), np.array([ego[3], other[3]])
    return _contact_point(x, y, c, s, np.array([ehl, hl]), np.array([ehw, hw]), 0, 1)


@numba.njit(cache=True)
def _forecast(
    x: np.ndarray,
    y: np.ndarray,
    yaw: np.ndarray,
    speed: np.ndarray,
    length: np.ndarray,
    width: np.ndarray,
    walker: np.ndarray,
    valid: np.ndarray,
    z: np.ndarray,
    yaw_rate: np.ndarray,
    cav_rows: np.ndarray,
    paths: np.ndarray,
    v0: np.ndarray,
    vt: np.ndarray,
    params: np.ndarray,
    num_steps: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    step, radius, accel, decel, search = params[0], params[1], params[2], params[3], params[4]
    front, ego_side, other_long, other_side = params[5], params[6], params[7], params[8]
    max_rate, walker_moving, walker_speed, walker_box = params[9], params[10], params[11], params[12]
    n, a, frames = cav_rows.shape[0], x.shape[0], num_steps + 1
    horizon = num_steps * step
    conflict = np.full((n, a), np.inf)
    ego_arrival = np.full((n, a), np.inf)
    actor_arrival = np.full((n, a), np.inf)
    behind = np.zeros((n, a), np.bool_)

    # other actors' models; their rollouts are computed when first needed
    v, w, hl, hw, reach = np.empty(a), np.empty(a), np.empty(a), np.empty(a), np.empty(a)
    for j in range(a):
        hl[j], hw[j] = 0.5 * length[j] + other_long, 0.5 * width[j] + other_side
        if walker[j]:
            v[j] = max(speed[j], walker_speed) if speed[j] > walker_moving else 0.0
            w[j] = 0.0
            hl[j], hw[j] = max(hl[j], 0.5 * walker_box), max(hw[j], 0.5 * walker_box)
        else:
            v[j] = speed[j]
            w[j] = min(max(yaw_rate[j], -max_rate), max_rate)
        reach[j] = abs(v[j]) * horizon + math.hypot(hl[j], hw[j])
    rolled = np.zeros(a, np.bool_)
    roll = np.empty((a, frames, 4))
    ego = np.empty((frames, 4))

    for i in range(n):
        r = cav_rows[i]
        _ego_rollout(paths[i], x[r], y[r], yaw[r], v0[i], vt[i], accel, decel, step, search, ego)
        shift = 0.5 * front  # the ego box centre lies this far ahead of the rolled point
        ehl, ehw = 0.5 * length[r] + shift, 0.5 * width[r] + ego_side
        e_radius = math.hypot(ehl, ehw)
        ex0, ey0 = ego[0, 0] + shift * ego[0, 2], ego[0, 1] + shift * ego[0, 3]
        e_reach = 0.0
        for k in range(frames):
            dx = ego[k, 0] + shift * ego[k, 2] - ex0
            dy = ego[k, 1] + shift * ego[k, 3] - ey0
            e_reach = max(e_reach, math.hypot(dx, dy))
        e_reach += e_radius
        cy, sy, rear = math.cos(yaw[r]), math.sin(yaw[r]), -0.5 * length[r]
        for j in range(a):
            if not valid[j] or j == r or abs(z[j] - z[r]) > LEVEL_CLEARANCE:
                continue  # (a bridge over the ego's road, or under it)
            dx, dy = x[j] - x[r], y[j] - y[r]
            behind[i, j] = dx * cy + dy * sy < rear
            if dx * dx + dy * dy > radius * radius:
                continue
            if math.hypot(x[j] - ex0, y[j] - ey0) > e_reach + reach[j]:
                continue  # cannot meet within the horizon
            if not rolled[j]:
                _actor_rollout(x[j], y[j], yaw[j], v[j], w[j], step, roll[j])
                rolled[j] = True
            rj = roll[j]
            k = _first_overlap(ego, shift, ehl, ehw, rj, hl[j], hw[j])
            if k < 0:
                continue
            conflict[i, j] = k * step
            px, py = _overlap_centre(ego[k], shift, ehl, ehw, rj[k], hl[j], hw[j])
            ego_arrival[i, j] = _arrival(ego, shift, ehl, px, py, k, step)
            actor_arrival[i, j] = _arrival(rj, 0.0, hl[j], px, py, k, step)
    return conflict, ego_arrival, actor_arrival, behind
