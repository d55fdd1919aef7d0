"""Lateral path shifts around obstacles for the expert (PDM-Lite's route shifts), batched over CAVs.

The expert steers along ``route.xy + offset * left normal`` and checks its corridor along that same path.
Every tick :meth:`DetourPlanner.update` returns, for each CAV, that offset at its next ``horizon`` route
points (1 m apart), whether the CAV must hold before the obstacle because the lane it has to borrow is not
clear, and which actors the shift is for. What is shifted for (the table below) is judged for all (CAV,
actor) pairs at once in :mod:`~cmudrive.agents.expert.detour_detect`; this module fits the shifts and
checks the lane they borrow.

What is shifted for (``reference/MODEL_AND_EXPERT.md``, PDM-Lite; the obstacle types of
``reference/SCENARIOS.md``), all judged in the route's Frenet frame (s along the route, d + left):

==================  =====================================================================================
obstacle            within ``look_ahead`` m ahead and reaching into the CAV's corridor (half its width +
                    ``block_margin``): a prop (kind or role PROP: cones, signs, the opened car door), a
                    scenario vehicle standing for ``min_standing`` s away from the lane centre (parked,
                    crashed, police car) that is not queued behind a moving vehicle nor standing at the
                    route's next junction entry, or a slow scenario bicycle riding the CAV's way. The path
                    moves just enough to pass with ``margin`` (to the lane centre when it would squeeze a
                    same-direction neighbour lane's traffic, ``full_lane_change``), on the side away from the
                    obstacle where the road has room, with ``transition`` m ramps (10.5 m around cones);
                    a shift into traffic waits (at the start of its ramp, path unshifted) until that
                    lane is clear (oncoming: clear over the pass with ``clear_margin`` and
                    +``clear_extra_time``, at the vehicles' speeds; same direction: nothing
                    approaching from behind), and once the CAV's side has left its
                    lane it is kept until past the obstacle (before that, traffic that appears, such
                    as a flow car spawned ahead, still stops it)
invading vehicle    an oncoming vehicle over the centre line (InvadingTurn): right, within the CAV's lane
                    and a parking lane or shoulder beside it, to keep ``invading_margin``
emergency vehicle   a siren in the CAV's lane behind it (YieldToEmergencyVehicle): into a same-direction
                    neighbour lane (left first) once clear, else toward the right edge, until it passed
==================  =====================================================================================

The path never leaves the paved road: the shifted CAV keeps ``edge_margin`` inside the outer edge of its
lane plus the neighbour lane it borrows (same direction, else oncoming); where that is too narrow for an
obstacle there is no shift and the CAV is reported ``BLOCKED`` (the caller waits behind the obstacle).
Nothing is shifted inside junctions (internal lanes have no neighbours).

A shift is a :class:`_Segment` in route distance: ramp up from s0 to p0, plateau to p1, ramp down to s1
(cosine profile). Segments of one side that overlap merge; a segment the CAV has entered with a clear lane
is *committed* and held until the CAV passed its end, whatever the detection says later (a shift into
traffic is checked again until the CAV's side has left its lane).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from cmudrive.agents.expert.detour_detect import (
    Ego,
    Egos,
    Pairs,
    invaders,
    near_route_points,
    obstacles,
    sirens,
)
from cmudrive.maps import RoadMap, Route, other_level
from cmudrive.maps.model import NO_INDEX, LaneKind
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot


class DetourReason(IntEnum):
    """Why a CAV's path is shifted (or not)."""

    NONE = 0
    OBSTACLE = 1  # around an obstacle within the CAV's lane or a same-direction lane
    ONCOMING_LANE = 2  # around an obstacle through the oncoming lane (the *TwoWays types)
    INVADING = 3  # right, away from oncoming vehicles over the centre line (InvadingTurn)
    EMERGENCY = 4  # aside for an emergency vehicle coming from behind (YieldToEmergencyVehicle)
    BLOCKED = 5  # an obstacle blocks the lane and the road has no room to pass it: no shift


class Borrow(IntEnum):
    """The lane beside the CAV's lane that a shift moves into."""

    NONE = 0  # none there (road edge)
    SAME = 1  # a same-direction driving lane
    ONCOMING = 2  # the oncoming lane of a two-way road


@dataclass(frozen=True)
class DetourConfig:
    horizon: int = 80  # [route points = m] offsets returned for this many points from the CAV's progress
    look_ahead: float = 50.0  # [m] obstacles this far ahead along the route are gone around
    reach: float = 60.0  # [m] actors farther than this from a CAV are not looked at (except for a gap)
    traffic_reach: float = 200.0  # [m] at most this far for traffic when a borrowed lane must be clear
    margin: float = 0.6  # [m] lateral clearance the shifted CAV keeps to an obstacle
    block_margin: float = 0.3  # [m] an obstacle this close to the CAV's side of the unshifted path blocks
    invading_margin: float = 0.5  # [m] clearance kept to an oncoming vehicle over the centre line
    edge_margin: float = 0.2  # [m] the CAV's side stays this far inside the paved road's edge
    transition: float = 8.0  # [m] ramp length before and after an obstacle
    transition_construction: float = 10.5  # [m] ramp length around cones (ConstructionObstacle)
    min_transition: float = 4.0  # [m] shortest ramp when an obstacle is found late
    buffer: float = 1.0  # [m] full shift from this far before the obstacle to this far past it (bumpers)
    full_lane_change: bool = True  # a shift that squeezes same-direction traffic goes to that lane's centre
    nominal_half_width: float = 0.95  # [m] half width of a vehicle assumed at a neighbour lane's centre
    traffic_clearance: float = 0.3  # [m] a shift coming closer than this to that vehicle borrows its lane
    min_standing: float = 1.0  # [s] a scenario vehicle standing this long may be an obstacle
    standing_speed: float = 0.1  # [m/s] slower counts as standing
    moving_speed: float = 0.5  # [m/s] faster counts as moving (queue leaders, invading cars)
    side_fraction: float = 0.15  # [lane widths] a standing vehicle this far off the lane centre is parked
    queue_gap: float = 10.0  # [m] a standing vehicle this close behind a moving one is queued
    stop_line_gap: float = 10.0  # [m] a standing vehicle this close before a junction entry is waiting
    bicycle_speed: float = 4.5  # [m/s] scenario bicycles slower than this are passed
    clear_margin: float = 10.0  # [m] oncoming traffic must stay this far past the end of the pass
    clear_extra_time: float = 0.2  # [s] added to the pass time
    overtake_speed: float = 50.0 / 3.6  # [m/s] assumed pass speed (PDM-Lite overtakes at <= 50 km/h)
    pass_accel: float = 3.0  # [m/s^2] assumed acceleration to the pass speed (the caller must keep up)
    rear_gap: float = 5.0  # [m] a same-direction vehicle behind must be this far back ...
    rear_time: float = 2.0  # [s] ... plus its closing speed times this
    yield_distance: float = 80.0  # [m] an emergency vehicle this close behind is yielded to
    yield_transition_time: float = 1.5  # [s] ramp length when yielding = max(transition, this x speed)
    yield_hold: float = 15.0  # [m] full shift at least this far ahead while the vehicle is behind
    stop_before_start: float = 0.0  # [m] a waiting CAV's centre stops this far before the ramp starts

    def __post_init__(self) -> None:
        if self.horizon < 2 or self.transition <= 0.0 or self.min_transition <= 0.0:
            raise ValueError(f"DetourConfig: horizon >= 2 and positive transitions needed, got {self}")


@dataclass(frozen=True, eq=False)
class Detour:
    """The shift of ``n`` CAVs (in the order of ``cav_index`` given to :meth:`DetourPlanner.update`)."""

    offset: np.ndarray  # (n, H) float64 lateral offset [m, + left] at route points progress + 0..H-1
    # (n,) bool: hold before the obstacle, the lane to borrow is not clear; the offset then leaves that
    # shift out (the CAV waits straight in its lane, not angled into the traffic it waits for)
    waiting: np.ndarray
    stop_index: np.ndarray  # (n,) int64 route index where the CAV's centre should stop when waiting, else -1
    stop_distance: np.ndarray  # (n,) float64 [m] route distance from the CAV's centre to it, inf when none
    reason: np.ndarray  # (n,) int8 DetourReason of the strongest shift (or BLOCKED)
    actors: tuple[np.ndarray, ...]  # n x (k,) int64 snapshot rows the shift goes around / yields to
    traffic: tuple[np.ndarray, ...]  # n x (k,) int64 snapshot rows that keep the borrowed lane busy


@dataclass
class _Segment:
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
        up = _smooth((s - self.s0) / max(self.p0 - self.s0, 1e-6))
        down = _smooth((self.s1 - s) / max(self.s1 - self.p1, 1e-6))
        return self.amp * np.minimum(up, down)


def _smooth(x: np.ndarray) -> np.ndarray:
    """Cosine ramp 0 -> 1 over x in [0, 1] (zero slope at both ends)."""
    return 0.5 - 0.5 * np.cos(np.pi * np.clip(x, 0.0, 1.0))


class DetourPlanner:
    """Plans every CAV's lateral shift, one call per tick (keeps committed shifts between calls)."""

    def __init__(self, road_map: RoadMap, routes: list[Route], config: DetourConfig | None = None) -> None:
        self.map, self.routes = road_map, routes
        self.cfg = config or DetourConfig()
        n = len(routes)
        pad = max(len(r) for r in routes) + self.cfg.horizon + 2
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
        self.held: list[list[_Segment]] = [[] for _ in range(n)]
        self._standing_since: dict[str, float] = {}

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

    # ------------------------------------------------------------------ the tick
    def update(
        self, snap: Snapshot, cav_rows: np.ndarray, cav_index: np.ndarray, progress: np.ndarray
    ) -> Detour:
        """Shifts of the CAVs at snapshot rows ``cav_rows``, which drive routes ``cav_index``; ``progress``
        (n,) is each one's current index into its route."""
        cfg = self.cfg
        cav_rows = np.asarray(cav_rows, np.int64)
        cav_index = np.asarray(cav_index, np.int64)
        k_ego = np.minimum(np.asarray(progress, np.int64), self.length[cav_index] - 1)
        n, h = len(cav_rows), cfg.horizon
        ego_xy = np.stack([snap.x[cav_rows], snap.y[cav_rows]], axis=1)
        s_ego = self._along(cav_index, k_ego, ego_xy)
        pairs = self._pairs(snap, cav_rows, cav_index, k_ego, np.full(n, cfg.reach))
        pairs = pairs.subset(pairs.row != cav_rows[pairs.cav])
        self._update_standing(snap, pairs)
        ego = Egos(
            s_ego[pairs.cav], 0.5 * snap.length[cav_rows][pairs.cav], 0.5 * snap.width[cav_rows][pairs.cav]
        )
        obstacle = obstacles(snap, pairs, ego, cfg, self._standing_since)
        invading = invaders(snap, pairs, ego, cfg)
        siren = sirens(snap, pairs, ego, cfg)
        offset = np.zeros((n, h))
        waiting = np.zeros(n, bool)
        stop_index = np.full(n, -1, np.int64)
        stop_distance = np.full(n, np.inf)
        reason = np.zeros(n, np.int8)
        actors = [np.zeros(0, np.int64)] * n
        traffic = [np.zeros(0, np.int64)] * n
        todo = np.zeros(n, bool)
        todo[pairs.cav[obstacle | invading | siren]] = True
        todo |= np.array([bool(self.held[i]) for i in cav_index.tolist()], bool)
        for c in np.flatnonzero(todo).tolist():
            i, mine = int(cav_index[c]), pairs.cav == c
            p = pairs.subset(mine)
            masks = (obstacle[mine], invading[mine], siren[mine])
            plan = self._plan_cav(snap, p, masks, int(cav_rows[c]), i, int(k_ego[c]), float(s_ego[c]))
            s_pts = self.dist[i, k_ego[c] : k_ego[c] + h]
            left, right = np.zeros(h), np.zeros(h)
            for seg in plan.segments:
                v = seg.at(s_pts)
                left, right = np.maximum(left, v), np.minimum(right, v)
            offset[c] = left + right
            reason[c] = plan.reason
            actors[c], traffic[c] = plan.rows, plan.busy
            if plan.stop_s is not None:
                waiting[c] = True
                stop_index[c] = max(int(np.searchsorted(self.dist[i], plan.stop_s)), int(k_ego[c]))
                stop_distance[c] = max(plan.stop_s - float(s_ego[c]), 0.0)
        return Detour(offset, waiting, stop_index, stop_distance, reason, tuple(actors), tuple(traffic))

    def reset(self) -> None:
        """Forget committed shifts and standing times (a new route with the same planner)."""
        self.held = [[] for _ in self.routes]
        self._standing_since.clear()

    # ------------------------------------------------------------------ geometry
    def _along(self, cav_index: np.ndarray, k: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """(n,) route distance [m] of points near route indices k (projected on the tangent there)."""
        h = self.heading[cav_index, k]
        rel = xy - self.xy[cav_index, k]
        return self.dist[cav_index, k] + rel[:, 0] * np.cos(h) + rel[:, 1] * np.sin(h)

    def _pairs(
        self,
        snap: Snapshot,
        cav_rows: np.ndarray,
        cav_index: np.ndarray,
        k_ego: np.ndarray,
        reach: np.ndarray,
    ) -> Pairs:
        """Every (CAV, actor) pair within ``reach`` (n,) [m], with the actor in the CAV's route frame."""
        back = int(self.cfg.reach) + 10
        fwd = int(max(float(reach.max(initial=0.0)), self.cfg.reach)) + self.cfg.horizon
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

    def _update_standing(self, snap: Snapshot, pairs: Pairs) -> None:
        """How long each scenario vehicle near a CAV has been standing (kept only while it stands)."""
        rows = np.unique(pairs.row)
        rows = rows[(snap.role[rows] == Role.SCENARIO) & (snap.kind[rows] != ActorKind.PROP)]
        rows = rows[np.abs(snap.speed[rows]) < self.cfg.standing_speed]
        old = self._standing_since
        self._standing_since = {str(a): old.get(str(a), snap.time) for a in snap.ids[rows]}

    # ------------------------------------------------------------------ one CAV
    def _plan_cav(
        self,
        snap: Snapshot,
        p: Pairs,
        masks: tuple[np.ndarray, np.ndarray, np.ndarray],
        me: int,
        i: int,
        k_ego: int,
        s_ego: float,
    ) -> _Plan:
        """Fresh segments + held ones, merged; gap checks for those that enter a traffic lane."""
        obstacle, invading, siren = masks
        ego = Ego(s_ego, 0.5 * float(snap.length[me]), 0.5 * float(snap.width[me]))
        v_e = max(float(snap.speed[me]), 0.0)
        fresh: list[_Segment] = []
        blocked = False
        for held in self.held[i]:  # held rows refer to an older snapshot: find their actors again
            held.rows = np.flatnonzero(np.isin(snap.ids, held.ids)).astype(np.int64)
        if obstacle.any():
            fresh_obstacles, blocked = self._obstacle_segments(snap, p.subset(obstacle), i, ego)
            fresh += fresh_obstacles
        if invading.any():
            fresh += self._invading_segment(p.subset(invading), i, ego)
        if siren.any():
            fresh += self._yield_segment(p.subset(siren), i, k_ego, ego, v_e)
        stop_s: float | None = None
        busy: list[np.ndarray] = []
        keep: list[_Segment] = []
        waiting: list[_Segment] = []
        for seg in _merge(self.held[i] + fresh):
            # a shift begun is kept once the CAV's side left its lane; until then traffic can still stop it
            in_lane = abs(float(seg.at(np.array([s_ego]))[0])) + ego.half_width < self.half[i, k_ego]
            if seg.borrow != Borrow.NONE and (not seg.committed or in_lane):
                rows = self._traffic(snap, seg, me, i, k_ego, ego, v_e)
                if len(rows):
                    busy.append(rows)
                    seg.committed = False
                    waiting.append(seg)  # the path stays in lane: the CAV waits straight behind it
                    if seg.reason != DetourReason.EMERGENCY:  # no gap to yield into: drive on in lane
                        stop_s = seg.stop_at if stop_s is None else min(stop_s, seg.stop_at)
                    continue
            seg.committed |= s_ego >= seg.s0
            keep.append(seg)
        self.held[i] = [g for g in keep if g.committed and g.s1 > s_ego]
        for g in self.held[i]:
            g.ids = snap.ids[g.rows]
        rows = np.unique(np.concatenate([g.rows for g in keep + waiting] or [_NO_ROWS]))
        reason = max((g.reason for g in keep + waiting), key=int, default=DetourReason.NONE)
        if blocked:
            reason = DetourReason.BLOCKED
        busy_rows = np.unique(np.concatenate(busy or [_NO_ROWS]))
        return _Plan(keep, reason, rows, stop_s, busy_rows)

    def _obstacle_segments(self, snap: Snapshot, p: Pairs, i: int, ego: Ego) -> tuple[list[_Segment], bool]:
        """One segment per group of obstacles whose shifts overlap; True when a group cannot be passed."""
        cfg = self.cfg
        cone = (snap.kind[p.row] == ActorKind.PROP) & (snap.length[p.row] < 0.6) & (snap.width[p.row] < 0.6)
        groups: list[list[int]] = []
        for a in np.argsort(p.s).tolist():
            if groups and p.s[a] - p.half_lon[a] - max(p.s[b] + p.half_lon[b] for b in groups[-1]) < (
                2.0 * cfg.transition_construction
            ):
                groups[-1].append(a)
            else:
                groups.append([a])
        out: list[_Segment] = []
        blocked = False
        for g in groups:
            ga = np.array(g)
            trans = cfg.transition_construction if cone[ga].any() else cfg.transition
            p0 = float(np.min(p.s[ga] - p.half_lon[ga])) - ego.half_len - cfg.buffer
            p1 = float(np.max(p.s[ga] + p.half_lon[ga])) + ego.half_len + cfg.buffer
            s0 = p0 - trans
            stop_at = s0 - cfg.stop_before_start
            if s0 < ego.s:  # found late, or the CAV waited at the ramp: ramp from where the CAV is
                s0, p0 = ego.s, max(p0, ego.s + cfg.min_transition)
            need_left = float(np.max(p.d[ga] + p.half_lat[ga])) + ego.half_width + cfg.margin
            need_right = float(np.min(p.d[ga] - p.half_lat[ga])) - ego.half_width - cfg.margin
            first_left = float(np.mean(p.d[ga])) <= 0.0
            seg = None
            for left in (first_left, not first_left):
                amp = need_left if left else need_right
                if (amp > 0.0) == left:  # else no shift is needed that way
                    seg = self._fit(i, _Segment(s0, p0, p1, p1 + trans, amp, DetourReason.OBSTACLE), ego)
                if seg is not None:
                    break
            if seg is None:
                blocked = True
                continue
            seg.rows, seg.stop_at = p.row[ga], stop_at
            out.append(seg)
        return out, blocked

    def _fit(self, i: int, seg: _Segment, ego: Ego) -> _Segment | None:
        """``seg`` if the road has room for it all along, else None; where the shifted CAV would come
        closer than ``traffic_clearance`` to a vehicle at the neighbour lane's centre it borrows that lane
        (and goes to its centre, for a same-direction lane with ``full_lane_change``)."""
        cfg = self.cfg
        lo, hi = np.searchsorted(self.dist[i], [seg.s0, seg.s1])
        idx = np.arange(lo, max(hi, lo + 1))
        s, left = self.dist[i, idx], seg.amp > 0.0
        kind = (self.left_kind if left else self.right_kind)[i, idx]
        half, nb = self.half[i, idx], (self.nb_left if left else self.nb_right)[i, idx]
        neighbour_inner = np.where(kind == Borrow.NONE, np.inf, half + 0.5 * nb - cfg.nominal_half_width)
        squeeze = np.abs(seg.at(s)) + ego.half_width + cfg.traffic_clearance > neighbour_inner
        if squeeze.any():
            seg.borrow = Borrow.ONCOMING if (kind[squeeze] == Borrow.ONCOMING).any() else Borrow.SAME
            if seg.borrow == Borrow.ONCOMING:
                seg.reason = DetourReason.ONCOMING_LANE
            elif cfg.full_lane_change:
                centre = float(np.min(half[squeeze] + 0.5 * nb[squeeze]))
                seg.amp = float(np.sign(seg.amp)) * max(abs(seg.amp), centre)
        edge = (self.edge_left if left else self.edge_right)[i, idx]
        if np.any(np.abs(seg.at(s)) > edge - ego.half_width - cfg.edge_margin + 1e-6):
            return None
        return seg

    def _invading_segment(self, p: Pairs, i: int, ego: Ego) -> list[_Segment]:
        """Right, within the CAV's lane and a parking lane or shoulder, away from the invading vehicles."""
        cfg = self.cfg
        amp = float(np.min(p.d - p.half_lat)) - ego.half_width - cfg.invading_margin  # < 0: to the right
        s0, p0 = ego.s, ego.s + cfg.transition
        p1 = max(float(np.max(p.s + p.half_lon)) + ego.half_len + cfg.buffer, p0)
        lo, hi = np.searchsorted(self.dist[i], [s0, p1 + cfg.transition])
        room = float(np.min(self.paved_right[i, lo : max(hi, lo + 1)])) - ego.half_width - cfg.edge_margin
        if amp >= 0.0 or room <= 0.0:
            return []
        seg = _Segment(s0, p0, p1, p1 + cfg.transition, max(amp, -room), DetourReason.INVADING)
        seg.rows = p.row
        return [seg]

    def _yield_segment(self, p: Pairs, i: int, k_ego: int, ego: Ego, v_e: float) -> list[_Segment]:
        """Into a same-direction neighbour lane (left first), else toward the right edge, for a siren."""
        cfg = self.cfg
        trans = max(cfg.transition, cfg.yield_transition_time * v_e)
        s0, p0 = ego.s, ego.s + trans
        p1 = p0 + cfg.yield_hold
        lo, hi = np.searchsorted(self.dist[i], [s0, p1 + trans])
        idx = np.arange(lo, max(hi, lo + 1))
        half = self.half[i, idx]
        if np.all(self.left_kind[i, idx] == Borrow.SAME):
            amp, borrow = float(np.min(half + 0.5 * self.nb_left[i, idx])), Borrow.SAME
        elif np.all(self.right_kind[i, idx] == Borrow.SAME):
            amp, borrow = -float(np.min(half + 0.5 * self.nb_right[i, idx])), Borrow.SAME
        else:
            room = float(np.min(self.paved_right[i, idx])) - ego.half_width - cfg.edge_margin
            if room <= 0.0:
                return []
            amp, borrow = -room, Borrow.NONE
        seg = _Segment(s0, p0, p1, p1 + trans, amp, DetourReason.EMERGENCY, borrow)
        seg.rows = p.row
        return [seg]

    def _traffic(
        self, snap: Snapshot, seg: _Segment, me: int, i: int, k_ego: int, ego: Ego, v_e: float
    ) -> np.ndarray:
        """Snapshot rows of vehicles that keep the lane ``seg`` borrows busy (empty: clear to go).

        Oncoming: not yet passed the CAV and, at its speed, closer than ``clear_margin`` past the point
        where the CAV is back in its lane (halfway down the ramp) by the time the CAV gets there (pass
        speed ``overtake_speed`` or the limit, reached at ``pass_accel``; + ``clear_extra_time``).
        Same direction: beside the CAV, or behind it closer than ``rear_gap`` + closing speed x
        ``rear_time``."""
        cfg = self.cfg
        v_pass = max(min(cfg.overtake_speed, float(self.speed_limit[i, k_ego])), 1.0)
        back = 0.5 * (seg.p1 + seg.s1)  # [m] the CAV is back in its lane about here
        dist = max(back - ego.s, 0.0)
        t_pass = _travel_time(dist, v_e, v_pass, cfg.pass_accel) + cfg.clear_extra_time
        reach = min(cfg.traffic_reach, max(dist + v_pass * t_pass + cfg.clear_margin, cfg.reach))
        p = self._pairs(snap, np.array([me]), np.array([i]), np.array([k_ego]), np.array([reach]))
        p = p.subset(p.row != me)
        kind, role = snap.kind[p.row], snap.role[p.row]
        mobile = ~np.isin(kind, [ActorKind.PROP, ActorKind.PEDESTRIAN]) & (role != Role.PROP)
        mobile &= ~np.isin(p.row, seg.rows)
        d = p.d if seg.amp > 0.0 else -p.d
        band = (d > p.half_w) & (d - p.half_lat < abs(seg.amp) + ego.half_width + cfg.traffic_clearance)
        speed = np.abs(snap.speed[p.row])
        not_passed = p.s + p.half_lon > ego.s - ego.half_len
        arrives = p.s - p.half_lon - speed * t_pass < back + cfg.clear_margin
        oncoming = (p.cos < -0.5) & not_passed & arrives
        rear = ego.s - ego.half_len - cfg.rear_gap - np.maximum(speed - v_e, 0.0) * cfg.rear_time
        same = (p.cos > 0.5) & (p.s + p.half_lon > rear) & (p.s - p.half_lon < ego.s + ego.half_len + 2.0)
        return p.row[mobile & band & (oncoming | same)]


def _travel_time(dist: float, v0: float, v1: float, accel: float) -> float:
    """[s] to drive ``dist`` m from speed v0, accelerating at ``accel`` up to v1 (or holding v0 >= v1)."""
    if v0 >= v1:
        return dist / v1
    d_acc = (v1 * v1 - v0 * v0) / (2.0 * accel)
    if dist <= d_acc:
        return (np.sqrt(v0 * v0 + 2.0 * accel * dist) - v0) / accel
    return (v1 - v0) / accel + (dist - d_acc) / v1


def _merge(segments: list[_Segment]) -> list[_Segment]:
    """Same-side segments whose spans overlap become one (the first ramp up, the last ramp down)."""
    out: list[_Segment] = []
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
                    _Segment(
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


@dataclass(frozen=True)
class _Plan:
    segments: list[_Segment]  # the shifts the path follows now
    reason: DetourReason
    rows: np.ndarray  # snapshot rows the segments are for
    stop_s: float | None  # [m] route distance to stop at, None when not waiting
    busy: np.ndarray  # snapshot rows that keep a borrowed lane busy


_NO_ROWS = np.zeros(0, np.int64)
