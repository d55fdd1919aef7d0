"""Lateral path shifts around obstacles for the expert (PDM-Lite's route shifts), batched over CAVs.

The expert steers along ``route.xy + offset * left normal`` and checks its corridor along that same path.
Every tick :meth:`DetourPlanner.update` returns, for each CAV, that offset at its next ``horizon`` route
points (1 m apart), whether the CAV must hold before the obstacle because the lane it has to borrow is not
clear, and which actors the shift is for. What is shifted for (the table below) is judged for all (CAV,
actor) pairs at once in :mod:`~cmudrive.agents.expert.detour_detect`; the shifts are fitted to the road in
:mod:`~cmudrive.agents.expert.detour_path` and the lane they borrow is checked in
:mod:`~cmudrive.agents.expert.detour_gap`; this module builds the shifts and holds them between ticks.

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
                    obstacle where the road has room, with ``transition`` m ramps (10.5 m around cones),
                    and wider where it would bring the CAV onto a prop beside the unshifted path (cones
                    along the lane edge: they join the obstacle);
                    a shift into traffic waits (at the start of its ramp, path unshifted) until that
                    lane is clear (oncoming: clear over the pass with ``clear_margin`` and
                    +``clear_extra_time``, at the vehicles' speeds; same direction: nothing
                    approaching from behind), and once the CAV's side has left its
                    lane it is kept until past the obstacle (before that, traffic that appears, such
                    as a flow car spawned ahead, still stops it); an oncoming vehicle close ahead once
                    the CAV's rear is past the obstacles cuts the way back to ``min_transition``
invading vehicle    an oncoming vehicle over the centre line (InvadingTurn): right, within the CAV's lane
                    and a parking lane or shoulder beside it, to keep ``invading_margin``
emergency vehicle   a siren in the CAV's lane behind it (YieldToEmergencyVehicle): into a same-direction
                    neighbour lane (left first) once clear, else toward the right edge, until it passed
==================  =====================================================================================

The path never leaves the paved road: the shifted CAV keeps ``edge_margin`` inside the outer edge of its
lane plus the neighbour lane it borrows (same direction, else oncoming); where that is too narrow for an
obstacle there is no shift and the CAV is reported ``BLOCKED`` (the caller waits behind the obstacle).
Nothing is shifted inside junctions (internal lanes have no neighbours): a CAV that finds an obstacle
late while inside a junction (cyclists stopped just past its exit) ramps from the first point whose road
has room.

A shift is a :class:`~cmudrive.agents.expert.detour_path.Segment` in route distance: ramp up from s0 to
p0, plateau to p1, ramp down to s1 (cosine profile). Segments of one side that overlap merge; a segment
the CAV has entered with a clear lane is *committed* and held until the CAV passed its end, whatever the
detection says later (a shift into traffic is checked again until the CAV's side has left its lane).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmudrive.agents.expert.detour_config import Borrow, DetourConfig, DetourReason
from cmudrive.agents.expert.detour_detect import (
    PAIR_FIELDS,
    Ego,
    Egos,
    Pairs,
    invaders,
    obstacles,
    props_ahead,
    sirens,
)
from cmudrive.agents.expert.detour_gap import busy_traffic
from cmudrive.agents.expert.detour_path import RouteLanes, Segment, fit, merge
from cmudrive.maps import RoadMap, Route
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot

__all__ = ["Borrow", "Detour", "DetourConfig", "DetourPlanner", "DetourReason"]


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


class DetourPlanner:
    """Plans every CAV's lateral shift, one call per tick (keeps committed shifts between calls)."""

    def __init__(self, road_map: RoadMap, routes: list[Route], config: DetourConfig | None = None) -> None:
        self.routes = routes
        self.cfg = config or DetourConfig()
        self.lanes = RouteLanes(road_map, routes, self.cfg.horizon)
        self.held: list[list[Segment]] = [[] for _ in routes]
        self._standing_since: dict[str, float] = {}

    # ------------------------------------------------------------------ the tick
    def update(
        self, snap: Snapshot, cav_rows: np.ndarray, cav_index: np.ndarray, progress: np.ndarray
    ) -> Detour:
        """Shifts of the CAVs at snapshot rows ``cav_rows``, which drive routes ``cav_index``; ``progress``
        (n,) is each one's current index into its route."""
        cfg = self.cfg
        cav_rows = np.asarray(cav_rows, np.int64)
        cav_index = np.asarray(cav_index, np.int64)
        k_ego = np.minimum(np.asarray(progress, np.int64), self.lanes.length[cav_index] - 1)
        n, h = len(cav_rows), cfg.horizon
        ego_xy = np.stack([snap.x[cav_rows], snap.y[cav_rows]], axis=1)
        s_ego = self.lanes.along(cav_index, k_ego, ego_xy)
        pairs = self.lanes.pairs(snap, cav_rows, cav_index, k_ego, np.full(n, cfg.reach), cfg)
        pairs = pairs.subset(pairs.row != cav_rows[pairs.cav])
        self._update_standing(snap, pairs)
        ego = Egos(
            s_ego[pairs.cav], 0.5 * snap.length[cav_rows][pairs.cav], 0.5 * snap.width[cav_rows][pairs.cav]
        )
        obstacle = obstacles(snap, pairs, ego, cfg, self._standing_since)
        beside = props_ahead(snap, pairs, ego, cfg) & ~obstacle
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
            masks = (obstacle[mine], invading[mine], siren[mine], beside[mine])
            plan = self._plan_cav(snap, p, masks, int(cav_rows[c]), i, int(k_ego[c]), float(s_ego[c]))
            s_pts = self.lanes.dist[i, k_ego[c] : k_ego[c] + h]
            left, right = np.zeros(h), np.zeros(h)
            for seg in plan.segments:
                v = seg.at(s_pts)
                left, right = np.maximum(left, v), np.minimum(right, v)
            offset[c] = left + right
            reason[c] = plan.reason
            actors[c], traffic[c] = plan.rows, plan.busy
            if plan.stop_s is not None:
                waiting[c] = True
                stop_index[c] = max(int(np.searchsorted(self.lanes.dist[i], plan.stop_s)), int(k_ego[c]))
                stop_distance[c] = max(plan.stop_s - float(s_ego[c]), 0.0)
        return Detour(offset, waiting, stop_index, stop_distance, reason, tuple(actors), tuple(traffic))

    def reset(self) -> None:
        """Forget committed shifts and standing times (a new route with the same planner)."""
        self.held = [[] for _ in self.routes]
        self._standing_since.clear()

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
        masks: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        me: int,
        i: int,
        k_ego: int,
        s_ego: float,
    ) -> _Plan:
        """Fresh segments + held ones, merged; gap checks for those that enter a traffic lane."""
        obstacle, invading, siren, beside = masks
        ego = Ego(s_ego, 0.5 * float(snap.length[me]), 0.5 * float(snap.width[me]))
        v_e = max(float(snap.speed[me]), 0.0)
        fresh: list[Segment] = []
        blocked = False
        for held in self.held[i]:  # held rows refer to an older snapshot: find their actors again
            held.rows = np.flatnonzero(np.isin(snap.ids, held.ids)).astype(np.int64)
        if obstacle.any():
            fresh_obstacles, blocked = self._obstacle_segments(
                snap, p.subset(obstacle), p.subset(beside), i, ego
            )
            fresh += fresh_obstacles
        if invading.any():
            fresh += self._invading_segment(p.subset(invading), i, ego)
        if siren.any():
            fresh += self._yield_segment(p.subset(siren), i, k_ego, ego, v_e)
        stop_s: float | None = None
        busy: list[np.ndarray] = []
        keep: list[Segment] = []
        waiting: list[Segment] = []
        for seg in merge(self.held[i] + fresh):
            # a shift begun is kept once the CAV's side left its lane; until then traffic can still stop it
            in_lane = abs(float(seg.at(np.array([s_ego]))[0])) + ego.half_width < self.lanes.half[i, k_ego]
            if seg.borrow != Borrow.NONE and (not seg.committed or in_lane):
                rows = busy_traffic(self.lanes, snap, seg, me, i, k_ego, ego, v_e, self.cfg)
                if len(rows):
                    busy.append(rows)
                    seg.committed = False
                    waiting.append(seg)  # the path stays in lane: the CAV waits straight behind it
                    if seg.reason != DetourReason.EMERGENCY:  # no gap to yield into: drive on in lane
                        stop_s = seg.stop_at if stop_s is None else min(stop_s, seg.stop_at)
                    continue
            seg.committed |= s_ego >= seg.s0
            if seg.committed and seg.borrow == Borrow.ONCOMING:
                self._hurry_back(snap, p, seg, ego, v_e)
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

    def _hurry_back(self, snap: Snapshot, p: Pairs, seg: Segment, ego: Ego, v_e: float) -> None:
        """Past the obstacles in the oncoming lane with an oncoming vehicle close ahead (one that came
        after the CAV pulled out, such as a flow car spawned ahead): back into its lane over the shortest
        ramp (``min_transition``) from here, instead of the full ramp toward the vehicle, which stops
        facing the CAV (the two would stand nose to nose for good)."""
        cfg = self.cfg
        if not seg.p1 - cfg.buffer <= ego.s <= seg.p1 + _HURRY_LATE or seg.s1 <= ego.s + cfg.min_transition:
            return  # beside an obstacle (its rear not past them), or already on the way back
        vehicle = ~np.isin(snap.kind[p.row], [ActorKind.PEDESTRIAN, ActorKind.PROP]) & (
            snap.role[p.row] != Role.PROP
        )
        speed = np.abs(snap.speed[p.row])
        gap = p.s - p.half_lon - (ego.s + ego.half_len)
        near = np.maximum(cfg.hurry_distance, cfg.hurry_time * (speed + v_e))
        side = (np.sign(p.d) == np.sign(seg.amp)) & (np.abs(p.d) > p.half_w)
        if np.any(vehicle & (p.cos < -0.5) & side & (gap > -p.half_lon) & (gap < near)):
            seg.p1, seg.s1 = ego.s, ego.s + cfg.min_transition

    def _obstacle_segments(
        self, snap: Snapshot, p: Pairs, beside: Pairs, i: int, ego: Ego
    ) -> tuple[list[Segment], bool]:
        """One segment per group of obstacles whose shifts overlap; True when a group cannot be passed.
        ``beside``: props off the unshifted path; one that a group's shift would bring the CAV onto
        joins that group (and the shift is fitted again, at most ``_WIDEN`` times)."""
        cfg = self.cfg
        n_obstacles = len(p.row)
        groups: list[list[int]] = []
        for a in np.argsort(p.s).tolist():
            if groups and p.s[a] - p.half_lon[a] - max(p.s[b] + p.half_lon[b] for b in groups[-1]) < (
                2.0 * cfg.transition_construction
            ):
                groups[-1].append(a)
            else:
                groups.append([a])
        p = _concat(p, beside)  # rows past n_obstacles: the props beside the path
        cone = (snap.kind[p.row] == ActorKind.PROP) & (snap.length[p.row] < 0.6) & (snap.width[p.row] < 0.6)
        out: list[Segment] = []
        blocked = False
        for g in groups:
            ga = np.array(g)
            seg = self._group_segment(p, ga, cone, i, ego)
            for _ in range(_WIDEN):
                if seg is None:
                    break
                extra = np.arange(n_obstacles, len(p.row))
                extra = extra[~np.isin(extra, ga)]
                near = p.s[extra] - p.half_lon[extra] < seg.s1
                near &= p.s[extra] + p.half_lon[extra] > seg.s0
                path_d = seg.at(p.s[extra])
                near &= np.abs(p.d[extra] - path_d) < p.half_lat[extra] + ego.half_width + cfg.block_margin
                if not near.any():
                    break
                ga = np.concatenate([ga, extra[near]])
                seg = self._group_segment(p, ga, cone, i, ego)
            if seg is None:
                blocked = True
                continue
            out.append(seg)
        return out, blocked

    def _group_segment(self, p: Pairs, ga: np.ndarray, cone: np.ndarray, i: int, ego: Ego) -> Segment | None:
        """The shift around the obstacles ``ga`` (indices into ``p``), None when the road has no room."""
        cfg = self.cfg
        trans = cfg.transition_construction if cone[ga].any() else cfg.transition
        p0 = float(np.min(p.s[ga] - p.half_lon[ga])) - ego.half_len - cfg.buffer
        p1 = float(np.max(p.s[ga] + p.half_lon[ga])) + ego.half_len + cfg.buffer
        s0 = p0 - trans
        stop_at = s0 - cfg.stop_before_start
        late = s0 < ego.s
        if late:  # found late, or the CAV waited at the ramp: ramp from where the CAV is
            s0, p0 = ego.s, max(p0, ego.s + cfg.min_transition)
        need_left = float(np.max(p.d[ga] + p.half_lat[ga])) + ego.half_width + cfg.margin
        need_right = float(np.min(p.d[ga] - p.half_lat[ga])) - ego.half_width - cfg.margin
        first_left = float(np.mean(p.d[ga])) <= 0.0
        seg = None
        for left in (first_left, not first_left):
            amp = need_left if left else need_right
            if (amp > 0.0) == left:  # else no shift is needed that way
                seg = fit(
                    self.lanes, i, Segment(s0, p0, p1, p1 + trans, amp, DetourReason.OBSTACLE), ego, cfg
                )
                if seg is None and late:  # the CAV stands where the road has no room (a junction exit)
                    start = self._room_from(i, s0, p1, amp, ego)
                    if start is not None:
                        q0 = max(p0, start + cfg.min_transition)
                        q1 = max(p1, q0)
                        seg = fit(
                            self.lanes,
                            i,
                            Segment(start, q0, q1, q1 + trans, amp, DetourReason.OBSTACLE),
                            ego,
                            cfg,
                        )
            if seg is not None:
                break
        if seg is not None:
            seg.rows, seg.stop_at = p.row[ga], stop_at
        return seg

    def _room_from(self, i: int, s0: float, p1: float, amp: float, ego: Ego) -> float | None:
        """[m] the first route distance in [s0, p1) from which the road is wide enough for a shift of
        ``amp`` up to ``p1`` (None: nowhere): a late shift whose ramp would start inside a junction, where
        the route's lane has no neighbour, ramps from the junction's exit instead."""
        lo, hi = np.searchsorted(self.lanes.dist[i], [s0, p1])
        if hi <= lo:
            return None
        edge = (self.lanes.edge_left if amp > 0.0 else self.lanes.edge_right)[i, lo:hi]
        ok = edge - ego.half_width - self.cfg.edge_margin >= abs(amp)
        if not ok[-1]:
            return None
        bad = np.flatnonzero(~ok)
        return float(self.lanes.dist[i, lo + (bad[-1] + 1 if len(bad) else 0)])

    def _invading_segment(self, p: Pairs, i: int, ego: Ego) -> list[Segment]:
        """Right, within the CAV's lane and a parking lane or shoulder, away from the invading vehicles."""
        cfg = self.cfg
        amp = float(np.min(p.d - p.half_lat)) - ego.half_width - cfg.invading_margin  # < 0: to the right
        s0, p0 = ego.s, ego.s + cfg.transition
        p1 = max(float(np.max(p.s + p.half_lon)) + ego.half_len + cfg.buffer, p0)
        lo, hi = np.searchsorted(self.lanes.dist[i], [s0, p1 + cfg.transition])
        room = (
            float(np.min(self.lanes.paved_right[i, lo : max(hi, lo + 1)])) - ego.half_width - cfg.edge_margin
        )
        if amp >= 0.0 or room <= 0.0:
            return []
        seg = Segment(s0, p0, p1, p1 + cfg.transition, max(amp, -room), DetourReason.INVADING)
        seg.rows = p.row
        return [seg]

    def _yield_segment(self, p: Pairs, i: int, k_ego: int, ego: Ego, v_e: float) -> list[Segment]:
        """Into a same-direction neighbour lane (left first), else toward the right edge, for a siren."""
        cfg = self.cfg
        trans = max(cfg.transition, cfg.yield_transition_time * v_e)
        s0, p0 = ego.s, ego.s + trans
        p1 = p0 + cfg.yield_hold
        lo, hi = np.searchsorted(self.lanes.dist[i], [s0, p1 + trans])
        idx = np.arange(lo, max(hi, lo + 1))
        half = self.lanes.half[i, idx]
        if np.all(self.lanes.left_kind[i, idx] == Borrow.SAME):
            amp, borrow = float(np.min(half + 0.5 * self.lanes.nb_left[i, idx])), Borrow.SAME
        elif np.all(self.lanes.right_kind[i, idx] == Borrow.SAME):
            amp, borrow = -float(np.min(half + 0.5 * self.lanes.nb_right[i, idx])), Borrow.SAME
        else:
            room = float(np.min(self.lanes.paved_right[i, idx])) - ego.half_width - cfg.edge_margin
            if room <= 0.0:
                return []
            amp, borrow = -room, Borrow.NONE
        seg = Segment(s0, p0, p1, p1 + trans, amp, DetourReason.EMERGENCY, borrow)
        seg.rows = p.row
        return [seg]


@dataclass(frozen=True)
class _Plan:
    segments: list[Segment]  # the shifts the path follows now
    reason: DetourReason
    rows: np.ndarray  # snapshot rows the segments are for
    stop_s: float | None  # [m] route distance to stop at, None when not waiting
    busy: np.ndarray  # snapshot rows that keep a borrowed lane busy


_NO_ROWS = np.zeros(0, np.int64)
_WIDEN = 3  # a shift is widened for props beside the path at most this many times
_HURRY_LATE = 2.0  # [m] past the plateau's end a CAV is on its way back: its ramp is not cut short


def _concat(a: Pairs, b: Pairs) -> Pairs:
    return Pairs(*(np.concatenate([getattr(a, f), getattr(b, f)]) for f in PAIR_FIELDS))
