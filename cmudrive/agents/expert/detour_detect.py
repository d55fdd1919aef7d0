"""What the detour planner shifts for, judged for every (CAV, actor) pair at once in the CAV's route
frame: obstacles in the corridor ahead (props, parked scenario vehicles that are not queued, slow scenario
bicycles), oncoming vehicles over the centre line, and emergency vehicles with sirens behind (the table in
:mod:`cmudrive.agents.expert.detour`). Also the pair frame itself (:class:`Pairs`) and the compiled search
for the actors near each CAV's route.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numba
import numpy as np

from cmudrive.sim.snapshot import ActorKind, Role, Snapshot

if TYPE_CHECKING:
    from cmudrive.agents.expert.detour_config import DetourConfig

PAIR_FIELDS = ("cav", "row", "k", "s", "d", "half_lat", "half_lon", "cos", "half_w", "to_junction")


@dataclass(frozen=True)
class Pairs:
    """(CAV, actor) pairs near each other, the actor in the CAV's route frame; arrays of shape (k,)."""

    cav: np.ndarray  # position of the CAV in the update's arrays
    row: np.ndarray  # the actor's snapshot row
    k: np.ndarray  # nearest route point of the CAV's route
    s: np.ndarray  # [m] route distance of the actor's centre
    d: np.ndarray  # [m] lateral offset of its centre, + left
    half_lat: np.ndarray  # [m] half its extent across the route
    half_lon: np.ndarray  # [m] half its extent along the route
    cos: np.ndarray  # cosine of its heading relative to the route (-1: oncoming)
    half_w: np.ndarray  # [m] half the width of the route's lane there
    to_junction: np.ndarray  # [m] from the actor to the route's next junction entry (inf: none)

    def subset(self, sel: np.ndarray) -> Pairs:
        return Pairs(*(getattr(self, f)[sel] for f in PAIR_FIELDS))


@dataclass(frozen=True)
class Ego:
    """One CAV in its own route frame."""

    s: float  # [m] route distance of its centre
    half_len: float  # [m]
    half_width: float  # [m]


@dataclass(frozen=True)
class Egos:
    """The CAV of each pair in its route frame, (k,) arrays."""

    s: np.ndarray  # [m] route distance of its centre
    half_len: np.ndarray  # [m]
    half_width: np.ndarray  # [m]


def obstacles(
    snap: Snapshot, p: Pairs, ego: Egos, cfg: DetourConfig, standing_since: dict[str, float]
) -> np.ndarray:
    """(k,) bool: the pair's actor is an obstacle in the CAV's corridor ahead, to go around."""
    kind, role, speed = snap.kind[p.row], snap.role[p.row], np.abs(snap.speed[p.row])
    static = (kind == ActorKind.PROP) | (role == Role.PROP)
    vehicle = ~np.isin(kind, [ActorKind.PEDESTRIAN, ActorKind.BICYCLE, ActorKind.PROP])
    scenario = role == Role.SCENARIO
    ahead = (p.s + p.half_lon > ego.s - ego.half_len) & (p.s - p.half_lon - ego.s < cfg.look_ahead)
    reach = ego.half_width + cfg.block_margin
    inside = (p.d - p.half_lat < reach) & (p.d + p.half_lat > -reach) & (role != Role.CAV)
    parked = scenario & vehicle & ahead & inside & (np.abs(p.d) >= cfg.side_fraction * 2.0 * p.half_w)
    if parked.any():
        since = np.array([standing_since.get(str(a), np.inf) for a in snap.ids[p.row[parked]]])
        parked[parked] = snap.time - since >= cfg.min_standing
        parked &= p.to_junction > cfg.stop_line_gap + p.half_lon
        parked &= ~_queued(snap, p, parked, cfg)
    bike = scenario & (kind == ActorKind.BICYCLE) & (p.cos > 0.8) & (speed < cfg.bicycle_speed)
    return (static | parked | bike) & ahead & inside


def props_ahead(snap: Snapshot, p: Pairs, ego: Egos, cfg: DetourConfig) -> np.ndarray:
    """(k,) bool: a static prop ahead within ``look_ahead``, wherever it stands across the road. Those
    beside the CAV's path are no obstacle until a shift moves the path onto them (a line of cones along
    the lane edge, a sign on the shoulder): the planner widens a shift that would hit one."""
    static = (snap.kind[p.row] == ActorKind.PROP) | (snap.role[p.row] == Role.PROP)
    ahead = (p.s + p.half_lon > ego.s - ego.half_len) & (p.s - p.half_lon - ego.s < cfg.look_ahead)
    return static & ahead


def _queued(snap: Snapshot, p: Pairs, cand: np.ndarray, cfg: DetourConfig) -> np.ndarray:
    """(k,) bool: a moving vehicle is in front of the candidate within ``queue_gap``, in its band."""
    moving = (np.abs(snap.speed[p.row]) > cfg.moving_speed) & (snap.kind[p.row] != ActorKind.PEDESTRIAN)
    c, q = np.flatnonzero(cand), np.flatnonzero(moving & (p.cos > 0.5))
    out = np.zeros(len(p.row), bool)
    if len(q) == 0:
        return out
    gap = (p.s[q] - p.half_lon[q])[None, :] - (p.s[c] + p.half_lon[c])[:, None]  # (m, q) [m]
    band = np.abs(p.d[q][None, :] - p.d[c][:, None]) < p.half_lat[q][None, :] + p.half_lat[c][:, None]
    same = p.cav[q][None, :] == p.cav[c][:, None]
    out[c] = np.any(same & band & (gap > -0.5) & (gap < cfg.queue_gap), axis=1)
    return out


def invaders(snap: Snapshot, p: Pairs, ego: Egos, cfg: DetourConfig) -> np.ndarray:
    """(k,) bool: an oncoming vehicle ahead whose side comes within ``invading_margin`` of the CAV's."""
    kind = snap.kind[p.row]
    oncoming = (p.cos < -0.7) & (np.abs(snap.speed[p.row]) > cfg.moving_speed)
    oncoming &= ~np.isin(kind, [ActorKind.PEDESTRIAN, ActorKind.PROP]) & (snap.role[p.row] != Role.PROP)
    near = (p.s + p.half_lon > ego.s - ego.half_len) & (p.s - p.half_lon - ego.s < cfg.look_ahead)
    inner = p.d - p.half_lat
    return oncoming & near & (p.d > 0.0) & (inner < ego.half_width + cfg.invading_margin)


def sirens(snap: Snapshot, p: Pairs, ego: Egos, cfg: DetourConfig) -> np.ndarray:
    """(k,) bool: an emergency vehicle with its siren on behind the CAV in the CAV's lane."""
    behind = (p.s < ego.s) & (p.s > ego.s - cfg.yield_distance)
    return snap.siren[p.row] & (p.cos > 0.7) & behind & (np.abs(p.d) < p.half_w + 0.5)


@numba.njit(cache=True)
def near_route_points(
    route_xy: np.ndarray,  # (R, P, 2) padded route points
    cav_index: np.ndarray,  # (n,) route of each CAV
    k_ego: np.ndarray,  # (n,) each CAV's route index
    cav_rows: np.ndarray,  # (n,) each CAV's snapshot row
    x: np.ndarray,  # (A,) actor centres [m]
    y: np.ndarray,
    valid: np.ndarray,  # (A,) bool
    reach: np.ndarray,  # (n,) [m] actors farther than this from the CAV are skipped
    back: int,  # [route points] searched behind the CAV's index
    fwd: int,  # [route points] searched ahead of it
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(CAV position, actor row, nearest route point) of every actor within reach of a CAV: a coarse scan
    every 4th point of the window, then the 4 points either side of the best."""
    n, a = cav_index.shape[0], x.shape[0]
    last = route_xy.shape[1] - 1
    out_c = np.empty(n * a, np.int64)
    out_r = np.empty(n * a, np.int64)
    out_k = np.empty(n * a, np.int64)
    m = 0
    for c in range(n):
        r, me = cav_index[c], cav_rows[c]
        lo, hi = max(k_ego[c] - back, 0), min(k_ego[c] + fwd, last)
        for j in range(a):
            if not valid[j]:
                continue
            dx, dy = x[j] - x[me], y[j] - y[me]
            if dx * dx + dy * dy > reach[c] * reach[c]:
                continue
            best, best_d = lo, np.inf
            for k in range(lo, hi + 1, 4):
                ex, ey = route_xy[r, k, 0] - x[j], route_xy[r, k, 1] - y[j]
                dd = ex * ex + ey * ey
                if dd < best_d:
                    best, best_d = k, dd
            for k in range(max(best - 4, lo), min(best + 4, hi) + 1):
                ex, ey = route_xy[r, k, 0] - x[j], route_xy[r, k, 1] - y[j]
                dd = ex * ex + ey * ey
                if dd < best_d:
                    best, best_d = k, dd
            out_c[m], out_r[m], out_k[m] = c, j, best
            m += 1
    return out_c[:m], out_r[:m], out_k[:m]
