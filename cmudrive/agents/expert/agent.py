"""The privileged expert: one rule-based planner for every CAV of a route, batched over CAVs.

Each tick, for every active CAV (``reference/MODEL_AND_EXPERT.md``, PDM-Lite):

1. progress along its dense route; the path ahead (shifted sideways around obstacles by
   :mod:`~cmudrive.agents.expert.detour` when one is in the way);
2. the speed the road allows: ``0.72 x`` the speed limit (at most 20 m/s), a curvature cap
   (``sqrt(a_lat / curvature)``), 17.8 m/s within 30 m of a junction, approached with a comfortable
   deceleration;
3. IDM toward the first actor in the path corridor (vehicles, bicycles, pedestrians, obstacles), a red or
   yellow light at the next junction entry, a stop sign (until it has stood still at the line), and a
   junction where it must give way to vehicles with priority;
4. a ~2 s forecast of itself and nearby actors (:mod:`~cmudrive.agents.expert.forecast`): a predicted
   collision with anything but the leading object stops it;
5. anti-blocking: after ``unblock_after`` ticks standing for a forecast or a give-way, those two rules are
   ignored for ``unblock_for`` ticks;
6. SimLingo's lateral controller on the path; a speed controller that tracks the commanded acceleration
   (the expert knows the vehicle model: it is privileged).

Each rule of 2-4 (cruise, corridor, detour wait, junction, forecast) returns a candidate (acceleration term,
reason, object, distance, allowed speed; :mod:`~cmudrive.agents.expert.candidates`) and ``run_step`` folds
them in that order: the lowest acceleration sets the reason, object and distance (a later rule only where
its term is strictly lower), and the desired speed is the lowest allowed speed of all.

Each tick's decisions are kept in :attr:`ExpertAgent.decision` (:class:`ExpertDecision`): why each CAV
slowed down (rule, object, distance), its target speed and its planned path; the dataset turns them into
labels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from cmudrive.agents.base import Agent, AgentSetupError, Observation, Observations, RouteSetup
from cmudrive.agents.control import (
    STEER_GAINS,
    WindowedPid,
    heading_error,
    lookahead_distance,
    nearest_ahead,
)
from cmudrive.agents.corridor import first_in_corridor
from cmudrive.agents.expert.candidates import Candidate, Verdict
from cmudrive.agents.expert.detour import Detour, DetourPlanner, DetourReason
from cmudrive.agents.expert.forecast import Forecaster
from cmudrive.agents.expert.plan import EntryKind, RoutePlans, build_plans
from cmudrive.agents.expert.rules import GAPS, IdmConfig, Reason, allowed_speed, idm, reason_of_kind
from cmudrive.maps import RoadMap
from cmudrive.sim.dynamics import Controls, VehicleParams
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot
from cmudrive.sim.traffic_lights import link_state
from cmudrive.sim.weather import get_weather

HORIZON = 80  # [route points = m] the path ahead that is planned and checked
PATH_OUT = 40  # [points] of the planned path kept in the decision record
PROGRESS_WINDOW = 6  # [route points = m] searched ahead each tick (a CAV moves < 2 m per tick)
RED_LIGHT_POINT = 0.8  # the red-light criterion's point lies this many half lengths behind the centre
RED_LIGHT_TAIL = 1.0  # [m] and its segment ends this far behind the rear bumper
LOST = 3.0  # [m] a CAV this far from every route point of its search window is looked for on the whole route


@dataclass(frozen=True)
class ExpertConfig:
    speed_factor: float = 0.72  # target speed = this x the speed limit (PDM-Lite)
    max_speed: float = 20.0  # [m/s]
    junction_cap: float = 17.8  # [m/s] within junction_cap_distance of a junction
    junction_cap_distance: float = 30.0  # [m]
    lateral_accel: float = 3.0  # [m/s^2] curvature speed cap
    approach_decel: float = 2.5  # [m/s^2] to slow down for a lower allowed speed ahead
    corridor_margin: float = 0.4  # [m] added to half the CAV's width for the corridor check
    idm: IdmConfig = field(default_factory=IdmConfig)
    speed_time_constant: float = 0.5  # [s] the speed controller closes a speed error in about this time
    hold_speed: float = 0.3  # [m/s] commanded below this at low speed: hold the brake
    stop_sign_area: float = 4.0  # [m] a stop counts with the front bumper this close to the line
    stop_sign_ticks: int = 25  # ticks standing at the line before a stop sign is cleared
    stop_reached: float = 1.0  # [m] within s0 + this of a stop line, a stop term commands a standstill
    yield_reach: float = 25.0  # [m] junction give-way checked from this far before the entry
    yield_margin: float = 3.0  # [s] a priority vehicle arriving sooner than the CAV + this: give way
    yield_horizon: float = 7.0  # [s] priority vehicles farther than this in time are ignored
    light_reach: float = 80.0  # [m]
    overtake_speed: float = 50.0 / 3.6  # [m/s] at most while passing through the oncoming lane
    yellow_decel: float = 4.0  # [m/s^2] a yellow light is run when stopping would need more than this
    unblock_after: int = 170  # ticks standing for a forecast / give-way before ignoring them
    unblock_for: int = 40  # ticks they stay ignored
    standing_speed: float = 0.1  # [m/s]
    # a green light is not entered while a corridor object standing or crawling (below this) past the line
    # would leave the CAV stopped across it: a red coming meanwhile is charged (the criterion's segment
    # reaches 1 m behind the rear bumper), and the CAV blocks the junction
    clear_box_speed: float = 2.0  # [m/s]


@dataclass(frozen=True)
class ExpertDecision:
    """What the expert decided at one tick, for the ``n`` active CAVs in ``cav_index`` order."""

    tick: int
    cav_index: np.ndarray  # (n,)
    target_speed: np.ndarray  # (n,) [m/s] the speed it aims at over the next ~0.5 s
    # (n,) [m/s] the lowest speed its rules allow now (road, objects, stop lines, forecast; rules.
    # allowed_speed), before its own acceleration limits: what a learned model's speed query predicts
    desired_speed: np.ndarray
    accel: np.ndarray  # (n,) [m/s^2] commanded acceleration
    reason: np.ndarray  # (n,) int8 Reason that set it
    object_row: np.ndarray  # (n,) snapshot row of the object behind the reason, -1 none
    object_id: np.ndarray  # (n,) str actor id, "" none
    object_kind: np.ndarray  # (n,) int8 ActorKind, -1 none (lights, signs, road)
    distance: np.ndarray  # (n,) [m] bumper to the object / stop line, inf none
    path: np.ndarray  # (n, PATH_OUT, 2) the planned path ahead, map frame [m], 1 m apart
    route_index: np.ndarray  # (n,) progress along the dense route
    # (n,) int8 DetourReason of the path shift (or of the shift it waits to start), NONE when the path
    # is not shifted; (n,) snapshot row of the actor it is shifted around or yields to (the nearest of
    # them to the CAV), -1 none. The language labels name the obstacle from these.
    detour_reason: np.ndarray
    detour_row: np.ndarray


class ExpertAgent(Agent):
    """PDM-Lite-like privileged expert for all CAVs of a route (see the module docstring)."""

    observations: ClassVar[frozenset[Observation]] = frozenset({Observation.PRIVILEGED})

    def __init__(self, config: ExpertConfig | None = None, params: VehicleParams | None = None) -> None:
        self.config = config or ExpertConfig()
        self.params = params or VehicleParams()
        self.decision: ExpertDecision | None = None

    def setup(self, route: RouteSetup) -> None:
        if route.road_map is None or any(c.dense_route is None for c in route.cavs):
            raise AgentSetupError("ExpertAgent needs the privileged set-up (map and dense routes)")
        c = self.config
        self.road_map: RoadMap = route.road_map
        routes = [cav.dense_route for cav in route.cavs]
        self.plans: RoutePlans = build_plans(
            self.road_map,
            routes,  # type: ignore[arg-type]
            c.speed_factor,
            c.max_speed,
            c.lateral_accel,
            c.junction_cap,
            c.junction_cap_distance,
        )
        n = len(routes)
        self.friction = get_weather(route.weather).friction
        self.progress = np.zeros(n, np.int64)
        self.steer_pid = WindowedPid(n, *STEER_GAINS)
        self.stop_cleared = np.full(n, -1, np.int64)  # the last entry index whose stop sign was served
        self.stop_ticks = np.zeros(n, np.int64)  # ticks standing at the current stop line
        self.blocked_ticks = np.zeros(n, np.int64)
        self.unblock_until = np.full(n, -1, np.int64)
        self.forecaster = Forecaster()
        self.detour = DetourPlanner(self.road_map, routes)  # type: ignore[arg-type]

    # ------------------------------------------------------------------ tick
    def run_step(self, obs: Observations) -> Controls:
        snap = obs.snapshot
        if snap is None:
            raise AgentSetupError("ExpertAgent needs the snapshot (privileged observations)")
        rows = self._rows(snap, obs.cav_index)
        i = obs.cav_index
        c, p = self.config, self.plans
        pos = np.stack([obs.x, obs.y], axis=1)
        v = np.maximum(obs.speed, 0.0)
        half_len = snap.length[rows] * 0.5
        frac = self._advance(pos, i)
        ahead = self.progress[i][:, None] + np.arange(HORIZON)[None, :]
        ahead = np.minimum(ahead, p.xy.shape[1] - 1)
        det = self.detour.update(snap, rows, i, self.progress[i])
        h = p.heading[i[:, None], ahead]
        normal = np.stack([-np.sin(h), np.cos(h)], axis=-1)
        path = p.xy[i[:, None], ahead] + det.offset[..., None] * normal  # (n, H, 2) shifted around obstacles
        ego_s = p.distance[i, self.progress[i]] + frac  # [m] along the route
        unblocking = obs.tick < self.unblock_until[i]

        # the rules in order; a later one sets accel/reason/object only where its term is strictly lower
        cruise, first = self._cruise(i, v, frac, ahead, det)
        verdict = Verdict.start(first)
        corridor, followed = self._corridor(snap, rows, v, frac, half_len, path, cruise)
        verdict.take(corridor)
        verdict.take(self._detour_wait(det, v, cruise))
        verdict.take(self._junction_terms(snap, i, v, ego_s, half_len, cruise, unblocking, corridor))
        around = [np.concatenate([a, t]) for a, t in zip(det.actors, det.traffic, strict=True)]
        verdict.take(self._forecast_term(snap, rows, i, v, path, verdict.accel, followed, around, unblocking))

        # anti-blocking: standing for a forecast or a give-way too long -> ignore them for a while
        standing = v < c.standing_speed
        waiting = standing & np.isin(verdict.reason, [Reason.FORECAST, Reason.YIELD])
        self.blocked_ticks[i] = np.where(waiting, self.blocked_ticks[i] + 1, 0)
        start = self.blocked_ticks[i] >= c.unblock_after
        self.unblock_until[i[start]] = obs.tick + c.unblock_for
        self.blocked_ticks[i[start]] = 0

        controls = self._controls(obs, pos, v, path, frac, verdict.accel)
        self._record(snap, obs.tick, i, v, verdict, path, _detour_record(snap, rows, det))
        return controls

    # ------------------------------------------------------------------ rules
    def _cruise(
        self, i: np.ndarray, v: np.ndarray, frac: np.ndarray, ahead: np.ndarray, det: Detour
    ) -> tuple[np.ndarray, Candidate]:
        """The speed the road allows, approached comfortably (capped while passing in the oncoming lane):
        (n,) [m/s] the cruise speed, and the rule's candidate."""
        c, p = self.config, self.plans
        along = np.maximum(np.arange(HORIZON)[None, :] - frac[:, None], 0.0)
        allowed = p.allowed[i[:, None], ahead]
        cruise = np.sqrt(allowed**2 + 2.0 * c.approach_decel * along).min(axis=1)
        passing = (det.reason == DetourReason.ONCOMING_LANE) & (np.abs(det.offset).max(axis=1) > 0.1)
        cruise = np.where(passing, np.minimum(cruise, c.overtake_speed), cruise)
        accel = np.clip((cruise - v) / c.speed_time_constant, -c.idm.comfort_decel, c.idm.max_accel)
        reason = np.where(cruise < allowed[:, 0] - 0.5, Reason.ROAD, Reason.NONE).astype(np.int8)
        reason = np.where(v > cruise + 0.5, Reason.ROAD, reason).astype(np.int8)
        return cruise, Candidate(accel, reason, None, np.full(len(i), np.inf), cruise)

    def _corridor(
        self,
        snap: Snapshot,
        rows: np.ndarray,
        v: np.ndarray,
        frac: np.ndarray,
        half_len: np.ndarray,
        path: np.ndarray,
        cruise: np.ndarray,
    ) -> tuple[Candidate | None, np.ndarray]:
        """IDM toward the first actor in the path corridor; (n,) its snapshot row, -1 none."""
        c = self.config
        n = len(rows)
        skip = snap.other_level(rows)  # bridges over the CAV's road and roads under its bridge
        skip[:, ~snap.valid] = True
        hit, hit_row = first_in_corridor(
            path,
            rows,
            0.5 * snap.width[rows] + c.corridor_margin,
            snap.x,
            snap.y,
            snap.yaw,
            snap.length,
            snap.width,
            skip,
            HORIZON + 10.0,
        )
        has = hit_row >= 0
        if not has.any():
            return None, hit_row
        k = np.flatnonzero(has)
        r = hit_row[k]
        gap = hit[k] - frac[k] - half_len[k]
        seg = path[k, np.minimum(hit[k] + 1, HORIZON - 1)] - path[k, np.maximum(hit[k] - 1, 0)]
        path_yaw = np.arctan2(seg[:, 1], seg[:, 0])
        v_lead = np.maximum(snap.speed[r] * np.cos(snap.yaw[r] - path_yaw), 0.0)
        why = reason_of_kind(snap.kind[r], snap.role[r] == Role.PROP)
        v_lead = np.where(why == Reason.PEDESTRIAN, 0.0, v_lead)  # walkers are treated as standing
        term = np.full(n, np.inf)
        allow = np.full(n, np.inf)
        whys = np.zeros(n, np.int8)
        for w in np.unique(why):
            sel = why == w
            g = GAPS[Reason(int(w))]
            term[k[sel]] = idm(v[k[sel]], cruise[k[sel]], gap[sel], v_lead[sel], g.s0, g.headway, c.idm)
            allow[k[sel]] = allowed_speed(gap[sel], v_lead[sel], g.s0, g.headway, c.approach_decel)
        whys[k] = why
        rows_full = np.full(n, -1, np.int64)
        rows_full[k] = r
        dist_full = np.full(n, np.inf)
        dist_full[k] = gap
        return Candidate(term, whys, rows_full, dist_full, allow), hit_row

    def _detour_wait(self, det: Detour, v: np.ndarray, cruise: np.ndarray) -> Candidate | None:
        """Waiting for a gap before going around an obstacle: stop the centre at the detour's stop point."""
        if not det.waiting.any():
            return None
        c, n = self.config, len(v)
        g = GAPS[Reason.DETOUR_WAIT]
        gap = det.stop_distance + g.s0
        term = np.where(det.waiting, idm(v, cruise, gap, np.zeros(n), g.s0, g.headway, c.idm), np.inf)
        term = np.where(det.waiting & (det.stop_distance < c.stop_reached), -c.idm.max_accel, term)
        allow = allowed_speed(gap, np.zeros(n), g.s0, 0.0, c.approach_decel)
        allow = np.where(det.stop_distance < c.stop_reached, 0.0, allow)
        why = np.full(n, Reason.DETOUR_WAIT, np.int8)
        return Candidate(term, why, None, det.stop_distance, np.where(det.waiting, allow, np.inf))

    # ------------------------------------------------------------------ parts
    @staticmethod
    def _rows(snap: Snapshot, cav_index: np.ndarray) -> np.ndarray:
        rows, index = snap.cav_rows()
        row_of = dict(zip(index.tolist(), rows.tolist(), strict=True))
        return np.array([row_of[int(k)] for k in cav_index], np.int64)

    def _advance(self, pos: np.ndarray, i: np.ndarray) -> np.ndarray:
        """Move each CAV's progress to its nearest route point in a short window ahead (a route that comes
        back close to itself, as round a roundabout, must not pull the progress onto its later part);
        (n,) [m] of the CAV past that point along the route (its projection, clipped to [-0.5, 1])."""
        p = self.plans
        # (the last point is left out so that every progress has a next point)
        self.progress[i], d = nearest_ahead(p.xy[:, :-1], self.progress, i, pos, PROGRESS_WINDOW)
        for a in np.flatnonzero(d > LOST):  # far from the window: search the rest of the route
            k = int(i[a])
            rest = np.linalg.norm(p.xy[k, self.progress[k] : p.num_points[k]] - pos[a], axis=1)
            if len(rest) and rest.min() <= LOST:
                self.progress[k] += int(np.argmin(rest))
            else:
                self.progress[k] = int(np.argmin(np.linalg.norm(p.xy[k, : p.num_points[k]] - pos[a], axis=1)))
        here = p.xy[i, self.progress[i]]
        nxt = p.xy[i, self.progress[i] + 1]
        seg = nxt - here
        seg_len2 = np.maximum((seg**2).sum(axis=1), 1e-9)
        return np.clip(((pos - here) * seg).sum(axis=1) / np.sqrt(seg_len2), -0.5, 1.0)

    def _junction_terms(
        self,
        snap: Snapshot,
        i: np.ndarray,
        v: np.ndarray,
        ego_s: np.ndarray,
        half_len: np.ndarray,
        cruise: np.ndarray,
        unblocking: np.ndarray,
        corridor: Candidate | None = None,
    ) -> Candidate:
        """Junction entries ahead: lights, stop signs, give way (the nearest entry that asks for a stop).
        A green light whose line the CAV would stop across, behind the ``corridor`` object standing past
        it (a vehicle, a pedestrian on the crossing), holds the CAV at the line too (reason: that object)."""
        c, p = self.config, self.plans
        n = len(i)
        # [m] how far past a light's line the corridor object leaves room: the CAV's length, the red-light
        # segment's 1 m behind the rear bumper, and the gap it keeps to a standing leader
        box = 2.0 * half_len + RED_LIGHT_TAIL + GAPS[Reason.LEADING_VEHICLE].s0
        lead_row = np.full(n, -1, np.int64) if corridor is None or corridor.row is None else corridor.row
        lead_gap = np.full(n, np.inf) if corridor is None else corridor.distance
        lead_why = np.zeros(n, np.int8) if corridor is None else np.broadcast_to(corridor.reason, (n,))
        slow_lead = (lead_row >= 0) & (np.abs(snap.speed[np.maximum(lead_row, 0)]) < c.clear_box_speed)
        gap_all = p.entry_distance[i] - ego_s[:, None] - half_len[:, None]  # (n, E) bumper to line
        # the red-light criterion watches a point 0.8 half lengths behind the centre: until it has crossed
        # a light's line, a red still applies (a CAV that stood with its nose over the line, say for a
        # pedestrian, ran the red that came meanwhile); other entries are passed with the front bumper
        rear_all = p.entry_distance[i] - (ego_s - RED_LIGHT_POINT * half_len)[:, None]
        upcoming = np.where(p.entry_kind[i] == EntryKind.LIGHT, rear_all > 0.0, gap_all > -0.5)
        hard = self.params.max_brake * self.friction
        terms = np.full(n, np.inf)
        allows = np.full(n, np.inf)
        whys = np.zeros(n, np.int8)
        dists = np.full(n, np.inf)
        rows = np.full(n, -1, np.int64)
        for a in range(n):
            cav = int(i[a])
            for e in np.flatnonzero(upcoming[a]):
                gap = float(gap_all[a, e])
                if gap > c.light_reach:
                    break
                line_gap = gap if gap > 0.0 else float(rear_all[a, e])  # what is left to stop in
                kind = int(p.entry_kind[cav, e])
                term, why, box_row = np.inf, Reason.NONE, -1
                # a minor green ('g') or a light switched off on a minor link ('o'): go, but give way to
                # the links with priority
                permissive = False
                if kind == EntryKind.LIGHT:
                    state = link_state(self.road_map, snap.tls_state, int(p.entry_link[cav, e]))
                    permissive = state in ("g", "o")
                    if state in ("r", "u") and (gap > 0.0 or v[a] ** 2 / (2.0 * line_gap) < 0.9 * hard):
                        why = Reason.RED_LIGHT  # (past the line and too fast to stop in time: go on)
                    elif state == "y" and v[a] ** 2 / (2.0 * c.yellow_decel) < gap:
                        why = Reason.YELLOW_LIGHT
                    elif (
                        slow_lead[a]
                        and lead_gap[a] < gap + box[a]
                        and v[a] ** 2 / (2.0 * c.yellow_decel) < gap  # (as for a yellow: no hard stop)
                    ):
                        why = Reason(int(lead_why[a]))  # keep the box clear: wait at the line
                        box_row = int(lead_row[a])
                elif kind in (EntryKind.STOP_SIGN, EntryKind.ALLWAY_STOP) and self.stop_cleared[cav] < e:
                    why = Reason.STOP_SIGN
                    if v[a] < c.standing_speed and gap < c.stop_sign_area:
                        self.stop_ticks[cav] += 1
                        if self.stop_ticks[cav] >= c.stop_sign_ticks:
                            self.stop_cleared[cav] = e
                            self.stop_ticks[cav] = 0
                            why = Reason.NONE
                    else:
                        self.stop_ticks[cav] = 0
                if (
                    why == Reason.NONE
                    and (permissive or kind in (EntryKind.YIELD, EntryKind.STOP_SIGN, EntryKind.ALLWAY_STOP))
                    and gap < c.yield_reach
                    and not unblocking[a]
                    and self._must_yield(snap, int(p.entry_link[cav, e]), gap, v[a])
                ):
                    why = Reason.YIELD
                if why != Reason.NONE:
                    g = GAPS[why]
                    allow = 0.0
                    if gap <= g.s0 + c.stop_reached:  # at the line: stop there, as hard as that takes
                        needed = v[a] ** 2 / (2.0 * max(line_gap, 0.1))
                        term = -max(needed, c.idm.comfort_decel) if v[a] > c.hold_speed else -c.idm.max_accel
                    else:
                        allow = float(np.sqrt(2.0 * c.approach_decel * (gap - g.s0)))
                        term = float(
                            idm(
                                v[a : a + 1],
                                cruise[a : a + 1],
                                np.array([gap]),
                                np.zeros(1),
                                g.s0,
                                g.headway,
                                c.idm,
                            )[0]
                        )
                    terms[a], whys[a], dists[a], allows[a] = term, why, gap, allow
                    rows[a] = box_row
                    break  # the nearest entry that asks for a stop decides
        return Candidate(terms, whys, rows, dists, allows)

    def _forecast_term(
        self,
        snap: Snapshot,
        rows: np.ndarray,
        i: np.ndarray,
        v: np.ndarray,
        path: np.ndarray,
        accel: np.ndarray,
        followed: np.ndarray,
        around: list[np.ndarray],
        unblocking: np.ndarray,
    ) -> Candidate:
        """Roll every CAV along its path at the speed the other rules leave it (so a CAV stopping for a
        light does not see the crossing traffic it will never meet) and stop it for the first predicted
        conflict with a moving actor that is not behind it and not the object it already follows. Between
        two CAVs only one yields: the one that sees the conflict when the other does not, else the one
        whose own rollout reaches the conflict point later (ties: the higher CAV index). Both CAVs judge
        the pair from the same two numbers, so they never both wait (or both go)."""
        c = self.config
        n = len(i)
        target = np.maximum(v + accel * c.speed_time_constant, 0.0)
        fc = self.forecaster.forecast(snap, rows, path, v, target)
        moving = np.abs(snap.speed) >= c.standing_speed
        mask = ~fc.behind & moving[None, :] & snap.valid[None, :]
        mask &= (snap.kind != ActorKind.PROP)[None, :] & (snap.role != Role.PROP)[None, :]
        mask[np.arange(n), rows] = False
        has_followed = followed >= 0
        mask[np.flatnonzero(has_followed), followed[has_followed]] = False
        for a, rows_around in enumerate(around):  # what the detour goes around or waited for
            mask[a, rows_around] = False
        mask[unblocking] = False
        if n > 1:  # CAV-CAV pairs: exactly one of the two yields (the same rule seen from both sides)
            sees = mask[:, rows] & fc.conflict[:, rows]  # (n, n) [a, b]: a sees a conflict with b
            arrival = fc.ego_arrival[:, rows]  # [a, b]: when a reaches its conflict point with b
            b_first = (arrival.T < arrival) | ((arrival.T == arrival) & (i[None, :] < i[:, None]))
            mask[:, rows] = sees & (~sees.T | b_first)
        row, when = fc.nearest(mask)
        term = np.where(row >= 0, -v / np.maximum(when, c.speed_time_constant), np.inf)
        term = np.where((row >= 0) & (v < c.hold_speed), -c.idm.max_accel, term)
        gap = np.full(n, np.inf)
        hit = row >= 0
        gap[hit] = np.hypot(snap.x[row[hit]] - snap.x[rows[hit]], snap.y[row[hit]] - snap.y[rows[hit]])
        # allowed: the speed that still stops within the distance braking to rest by the conflict takes
        allow = np.sqrt(c.approach_decel * v * np.where(hit, np.maximum(when, 0.0), 0.0))
        allow = np.where(hit, np.where(v < c.hold_speed, 0.0, allow), np.inf)
        return Candidate(term, np.full(n, Reason.FORECAST, np.int8), row, gap, allow)

    def _must_yield(self, snap: Snapshot, link: int, gap: float, v: float) -> bool:
        """A vehicle with priority over ``link`` is in the junction on a conflicting path, or will reach it
        before the CAV has crossed (its arrival time < the CAV's + yield_margin)."""
        c, m = self.config, self.road_map
        foes = m.yields_to(link)
        if len(foes) == 0:
            return False
        vehicles = (snap.kind != ActorKind.PEDESTRIAN) & (snap.kind != ActorKind.PROP) & snap.valid
        ego_time = max(gap, 0.0) / max(v, 2.0)
        for f in foes:
            via = int(m.link_via[f])
            if via >= 0 and np.any(vehicles & (snap.lane == via)):
                return True
            src = int(m.link_from[f])
            on = np.flatnonzero(vehicles & (snap.lane == src))
            if len(on) == 0:
                continue
            end = m.pt_xy[m.lane_pt_ptr[src + 1] - 1]
            d = np.hypot(snap.x[on] - end[0], snap.y[on] - end[1]) - 0.5 * snap.length[on]
            t = d / np.maximum(snap.speed[on], 0.1)
            moving = snap.speed[on] > 1.0
            if np.any(moving & (t < min(ego_time + c.yield_margin, c.yield_horizon))):
                return True
        return False

    def _controls(
        self, obs: Observations, pos: np.ndarray, v: np.ndarray, path: np.ndarray, frac: np.ndarray, accel
    ) -> Controls:
        c, prm = self.config, self.params
        i = obs.cav_index
        # lateral: SimLingo's PID on the heading error to the look-ahead point (path interpolated)
        at = np.clip(frac + lookahead_distance(v), 0.0, HORIZON - 1.001)
        k = at.astype(np.int64)
        t = (at - k)[:, None]
        rows = np.arange(len(i))
        target = (1.0 - t) * path[rows, k] + t * path[rows, k + 1]
        steer = np.clip(self.steer_pid(i, heading_error(pos, obs.yaw, target)), -1.0, 1.0)
        # longitudinal: the commanded acceleration through the vehicle model
        hold = (v + accel * c.speed_time_constant < c.hold_speed) & (v < 1.0)
        resist = prm.rolling + prm.drag * v**2
        fade = np.maximum(1.0 - (v / prm.max_speed) ** 2, 0.05)
        throttle = np.clip((accel + resist) / (prm.max_accel * fade), 0.0, 1.0)
        brake = np.clip(-(accel + resist) / (prm.max_brake * self.friction), 0.0, 1.0)
        throttle = np.where(accel + resist > 0.0, throttle, 0.0)
        brake = np.where(accel + resist > 0.0, 0.0, brake)
        brake = np.where(hold, 1.0, brake)
        throttle = np.where(hold, 0.0, throttle)
        return Controls(steer=steer, throttle=throttle, brake=brake)

    def _record(
        self,
        snap: Snapshot,
        tick: int,
        i: np.ndarray,
        v: np.ndarray,
        verdict: Verdict,
        path: np.ndarray,
        detour: dict[str, np.ndarray],
    ) -> None:
        accel, obj_row = verdict.accel, verdict.row
        has = obj_row >= 0
        ids = np.full(len(i), "", dtype=object)
        ids[has] = snap.ids[obj_row[has]]
        kind = np.full(len(i), -1, np.int8)
        kind[has] = snap.kind[obj_row[has]]
        self.decision = ExpertDecision(
            tick=tick,
            cav_index=i.copy(),
            target_speed=np.maximum(v + accel * self.config.speed_time_constant, 0.0),
            desired_speed=verdict.desired,
            accel=accel,
            reason=verdict.reason,
            object_row=obj_row,
            object_id=ids.astype(str),
            object_kind=kind,
            distance=verdict.distance,
            path=path[:, :PATH_OUT].copy(),
            route_index=self.progress[i].copy(),
            **detour,
        )


def _detour_record(snap: Snapshot, rows: np.ndarray, det: Detour) -> dict[str, np.ndarray]:
    """The decision's ``detour_reason`` and ``detour_row``: set where the path is shifted (more than
    0.1 m anywhere ahead) or the CAV waits to start a shift; the row is the actor of the shift nearest to
    the CAV."""
    n = len(rows)
    active = (np.abs(det.offset).max(axis=1, initial=0.0) > 0.1) | det.waiting
    reason = np.where(active, det.reason, DetourReason.NONE).astype(np.int8)
    row = np.full(n, -1, np.int64)
    for a in np.flatnonzero(active & (reason != DetourReason.BLOCKED)).tolist():
        r = det.actors[a]
        if len(r):
            d2 = (snap.x[r] - snap.x[rows[a]]) ** 2 + (snap.y[r] - snap.y[rows[a]]) ** 2
            row[a] = r[int(np.argmin(d2))]
    return {"detour_reason": reason, "detour_row": row}
