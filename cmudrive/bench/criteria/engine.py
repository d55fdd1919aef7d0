"""The per-route criteria engine: every criterion for every CAV of a route, one tick at a time.

:class:`RouteCriteria` holds per-CAV state as arrays over the route's ``n`` CAVs and updates all running
CAVs at once from the tick's snapshot and collision events; each criterion lives in its own module of this
package. The rules, and where they differ from CARLA's, are tabled in the package docstring.
"""

from __future__ import annotations

import numpy as np

from cmudrive.bench.criteria.collisions import LAYOUT_KEY, CollisionMemory, cav_contacts, collision_key
from cmudrive.bench.criteria.config import CriteriaConfig
from cmudrive.bench.criteria.lanes import lane_state
from cmudrive.bench.criteria.layout import SceneryIndex, box_table, scenery_contacts
from cmudrive.bench.criteria.min_speed import MinSpeedMonitor, background_vehicles
from cmudrive.bench.criteria.progress import RouteTable, advance, distance_to_route
from cmudrive.bench.criteria.red_lights import RedLightCheck
from cmudrive.bench.criteria.stop_lines import StopLineTable
from cmudrive.bench.criteria.stop_signs import StopSignCheck
from cmudrive.bench.records import (
    INFRACTION_KEYS,
    PENALTIES,
    STATUS_BLOCKED,
    STATUS_COMPLETED,
    STATUS_DEVIATED,
    STATUS_PERFECT,
    STATUS_RUNNING,
    STATUS_TIMEOUT,
    CavResult,
    Infraction,
)
from cmudrive.maps.index import LaneProjection
from cmudrive.maps.model import RoadMap
from cmudrive.maps.routing import Route
from cmudrive.maps.scenery import StaticScenery
from cmudrive.sim.collisions import CollisionEvents
from cmudrive.sim.snapshot import Role, Snapshot

RECORDED_ONLY = frozenset({"min_speed_infractions"})  # keys that do not spoil a "Perfect"
_COMPLETED = "completed"  # internal outcome; the status (Perfect/Completed) is decided in results()


_PERCENT_EPS = 1e-6  # [%] a minimum-speed part this close to 100 % is not "too slow"


class RouteCriteria:
    """Criteria of all CAVs of one route.

    ``routes[i]`` is the dense route of the CAV with snapshot id ``cav_ids[i]``; ``dt`` [s] is the tick
    length, the clock of the blocked and route-timeout tests. ``scenery`` holds the static objects a CAV
    can hit (layout collisions); by default the map's own (:func:`cmudrive.maps.load_scenery`, built once
    per map and cached), ``StaticScenery.empty()`` for none. Call :meth:`update` once per tick after the
    snapshot and collisions, remove :meth:`newly_finished` CAVs from the world, and :meth:`end_route` when
    the route stops early (tick cap, crash); :meth:`results` gives the scores at any point.
    """

    def __init__(
        self,
        road_map: RoadMap,
        routes: list[Route],
        cav_ids: list[str],
        config: CriteriaConfig = CriteriaConfig(),  # noqa: B008 (frozen, so sharing the default is safe)
        dt: float = 0.05,
        scenery: StaticScenery | None = None,
    ) -> None:
        if len(routes) != len(cav_ids) or not routes:
            raise ValueError(f"need one route per CAV and at least one CAV: {len(routes)} routes, {cav_ids}")
        if len(set(cav_ids)) != len(cav_ids):
            raise ValueError(f"CAV ids must be unique: {cav_ids}")
        if any(len(r) == 0 for r in routes):
            raise ValueError(f"empty route for CAV {cav_ids[[len(r) for r in routes].index(0)]}")
        if not dt > 0:
            raise ValueError(f"dt must be positive, got {dt}")
        self.map, self.routes, self.cav_ids = road_map, routes, list(cav_ids)
        self.config, self.dt = config, dt
        n = len(routes)
        self._index_of = {c: i for i, c in enumerate(cav_ids)}
        self._table = RouteTable.build(routes, config.route_timeout_speed_fraction)
        stops = StopLineTable.build(road_map, config.stop_line_width_factor)
        self._collisions = CollisionMemory(n, config)
        if scenery is None:
            from cmudrive.maps.cache import load_scenery

            scenery = load_scenery(road_map)
        self._scenery = SceneryIndex.build(scenery)
        self._red_lights = RedLightCheck(road_map, stops, routes, config)
        self._stop_signs = StopSignCheck(stops, n, config)
        self._min_speed = MinSpeedMonitor(self._table.length, config)
        # per-CAV state
        self._outcome: list[str] = [STATUS_RUNNING] * n  # STATUS_RUNNING, _COMPLETED or a failure status
        self._running = np.ones(n, bool)
        self._newly = np.zeros(n, bool)
        self._route_index = np.zeros(n, np.int64)  # furthest route point passed
        self._ticks = np.zeros(n, np.int64)  # ticks evaluated
        self._still_ticks = np.zeros(n, np.int64)  # consecutive ticks slower than blocked_speed
        self._outside_m = np.zeros(n)  # [m] route progress made outside route lanes
        self._offroute_m = np.zeros(n)  # [m] route progress made farther than offroute_distance from it
        self._wrong_direction_check = np.ones(n, bool)
        self._blocked_suspended = np.zeros(n, bool)
        self._xy = np.array([r.xy[0] for r in routes], np.float64)  # (n, 2) last known centre [m]
        self._infractions: list[dict[str, list[Infraction]]] = [
            {k: [] for k in INFRACTION_KEYS} for _ in range(n)
        ]
        self._updates = 0  # ticks of the route so far
        self._tick, self._time = 0, 0.0  # of the last update

    # ------------------------------------------------------------------ the tick
    def update(self, snap: Snapshot, collisions: CollisionEvents) -> None:
        """One tick: ``snap`` holds the CAVs still in the world (finished ones have left it)."""
        self._newly[:] = False
        self._updates += 1
        self._tick, self._time = int(snap.step), float(snap.time)
        rows, cav = self._running_rows(snap)
        if len(cav) == 0:
            return
        xy, yaw = np.column_stack([snap.x[rows], snap.y[rows]]), snap.yaw[rows]
        speed, half = np.abs(snap.speed[rows]), 0.5 * snap.length[rows]
        forward = np.column_stack([np.cos(yaw), np.sin(yaw)])
        self._xy[cav] = xy
        self._ticks[cav] += 1

        self._collisions.forget_far(cav, xy)
        self._count_collisions(snap, collisions, rows, cav)
        self._count_layout(snap, rows, cav)
        nearest, centre_lane, tail_lane = self._lanes_under(xy, yaw, forward, half)
        self._check_signals(cav, xy, forward, half, speed, centre_lane, tail_lane, snap.tls_state)
        off_route = self._progress(cav, xy, yaw, speed, nearest, snap)
        still = (speed < self.config.blocked_speed) & ~self._blocked_suspended[cav]
        self._still_ticks[cav] = np.where(still, self._still_ticks[cav] + 1, 0)
        self._end_conditions(cav, xy, off_route)

    def _check_signals(
        self,
        cav: np.ndarray,
        xy: np.ndarray,
        forward: np.ndarray,
        half: np.ndarray,
        speed: np.ndarray,
        centre_lane: np.ndarray,
        tail_lane: np.ndarray,
        tls_state: np.ndarray,
    ) -> None:
        """Red lights and stop signs."""
        ran, stop = self._red_lights.update(
            cav, xy, forward, half, tail_lane, self._route_index[cav], tls_state
        )
        for i, k in zip(ran.tolist(), stop.tolist(), strict=True):
            tls, (x, y) = self.map.tls_ids[self.map.stop_tls[k]], self._xy[i]
            self._record(i, "red_light", f"Agent ran the red light {tls} at (x={x:.1f}, y={y:.1f})")
        ran, stop = self._stop_signs.update(cav, xy, half, speed, centre_lane)
        for i, k in zip(ran.tolist(), stop.tolist(), strict=True):
            lane = self.map.lane_ids[self.map.stop_lane[k]]
            self._record(i, "stop_infraction", f"Agent ran the stop sign at the end of lane {lane}")

    def _progress(
        self,
        cav: np.ndarray,
        xy: np.ndarray,
        yaw: np.ndarray,
        speed: np.ndarray,
        nearest: LaneProjection,
        snap: Snapshot,
    ) -> np.ndarray:
        """Advance the route index and measure along it: distance outside route lanes, distance off the
        route, minimum speed. Returns the distance [m] (m,) to the nearest of the next route points."""
        cfg, table = self.config, self._table
        old = self._route_index[cav]
        new = advance(table, cav, old, xy, cfg.completion_window)
        self._route_index[cav] = new
        progress = table.distance[cav, new]
        step = progress - table.distance[cav, old]  # [m] route distance advanced this tick
        outside, wrong = lane_state(self.map, xy, yaw, nearest, cfg)
        self._outside_m[cav] += np.where(outside | (wrong & self._wrong_direction_check[cav]), step, 0.0)
        off_route = distance_to_route(table, cav, new, xy, cfg.deviation_window)
        self._offroute_m[cav] += np.where(off_route > cfg.offroute_distance, step, 0.0)
        traffic = background_vehicles(snap)
        traffic_xy = np.column_stack([snap.x[traffic], snap.y[traffic]])
        self._min_speed.update(self._tick, cav, xy, speed, progress, traffic_xy, snap.speed[traffic])
        return off_route

    def _running_rows(self, snap: Snapshot) -> tuple[np.ndarray, np.ndarray]:
        """Snapshot rows of the running CAVs and their CAV indices."""
        rows = np.flatnonzero((snap.role == Role.CAV) & snap.valid)
        cav = np.array([self._index_of.get(str(a), -1) for a in snap.ids[rows]], np.int64)  # <= 16 CAVs
        keep = cav >= 0
        keep[keep] = self._running[cav[keep]]
        return rows[keep], cav[keep]

    def _lanes_under(
        self, xy: np.ndarray, yaw: np.ndarray, forward: np.ndarray, half: np.ndarray
    ) -> tuple[LaneProjection, np.ndarray, np.ndarray]:
        """Nearest driving lanes of the CAV centres (m,), and the lanes (m,) each CAV drives along at its
        centre and at the far end of its rear segment: the nearest driving lane where it lies within 90
        degrees of the CAV's heading and within half a lane width plus the margin, else -1.

        One query for both points: unfiltered by heading (so that driving against a lane finds that lane),
        with ties between overlapping junction lanes going to the better-aligned one."""
        m = len(xy)
        tail = xy - forward * (half + self.config.red_light_tail_extra)[:, None]
        both = np.concatenate([yaw, yaw])
        proj = self.map.index.nearest_lane(np.concatenate([xy, tail]), heading=both, max_heading_diff=np.pi)
        lane = np.maximum(proj.lane, 0)
        along = (proj.lane >= 0) & (
            np.abs(proj.d) <= 0.5 * self.map.lane_width[lane] + self.config.lane_margin
        )
        along &= np.cos(both - proj.heading) > 0.0
        lanes = np.where(along, proj.lane, -1)
        centre = LaneProjection(*(getattr(proj, f)[:m] for f in ("lane", "s", "d", "distance", "heading")))
        return centre, lanes[:m], lanes[m:]

    def _count_collisions(
        self, snap: Snapshot, events: CollisionEvents, rows: np.ndarray, cav: np.ndarray
    ) -> None:
        if len(events) == 0:
            return
        cav_of_row = np.full(snap.num_actors, -1, np.int64)
        cav_of_row[rows] = cav
        who, row, other = cav_contacts(events, cav_of_row)
        if len(who) == 0:
            return
        cav_xy = np.column_stack([snap.x[row], snap.y[row]])
        counted = self._collisions.count(who, snap.ids[other], cav_xy, snap.speed[row], self._time)
        for i, o in zip(who[counted].tolist(), other[counted].tolist(), strict=True):
            key = collision_key(int(snap.kind[o]))
            kind_name = key.removeprefix("collisions_")
            x, y = self._xy[i]
            message = f"Agent collided against {kind_name} {snap.ids[o]} at (x={x:.1f}, y={y:.1f})"
            self._record(i, key, message, actor=str(snap.ids[o]))

    def _count_layout(self, snap: Snapshot, rows: np.ndarray, cav: np.ndarray) -> None:
        """Contacts of the running CAVs with static scenery: ``collisions_layout``."""
        boxes = box_table(snap.x[rows], snap.y[rows], snap.yaw[rows], snap.length[rows], snap.width[rows])
        hit, obj = scenery_contacts(boxes, self._scenery)
        if len(hit) == 0:
            return
        who, row = cav[hit], rows[hit]
        names = np.array([self._scenery.name(j) for j in obj.tolist()])  # a handful of contacts at most
        cav_xy = np.column_stack([snap.x[row], snap.y[row]])
        counted = self._collisions.count(who, names, cav_xy, snap.speed[row], self._time)
        for i, name in zip(who[counted].tolist(), names[counted].tolist(), strict=True):
            x, y = self._xy[i]
            kind = name.split(":")[1]
            message = f"Agent collided against the static {kind} {name} at (x={x:.1f}, y={y:.1f})"
            self._record(i, LAYOUT_KEY, message, actor=name)

    def _end_conditions(self, cav: np.ndarray, xy: np.ndarray, off_route: np.ndarray) -> None:
        cfg, table = self.config, self._table
        index = self._route_index[cav]
        rc = table.completion(cav, index)
        to_end = np.linalg.norm(xy - table.xy[cav, table.last[cav]], axis=1)
        done = (rc > cfg.completion_threshold) & (to_end <= cfg.completion_distance)
        deviated = ~done & (
            (off_route >= cfg.deviation_distance)
            | (self._offroute_m[cav] > cfg.offroute_max_fraction * table.length[cav])
        )
        blocked = ~done & ~deviated & (self._still_ticks[cav] * self.dt > cfg.blocked_time)
        budget = cfg.route_timeout_base + table.budget[cav, index]
        timed_out = ~done & ~deviated & ~blocked & (self._updates * self.dt > budget)
        for i in cav[done].tolist():
            self._finish(i, _COMPLETED)
        for i in cav[deviated].tolist():
            x, y = self._xy[i]
            self._record(i, "route_dev", f"Agent deviated from the route at (x={x:.1f}, y={y:.1f})")
            self._finish(i, STATUS_DEVIATED)
        for i in cav[blocked].tolist():
            x, y = self._xy[i]
            self._record(i, "vehicle_blocked", f"Agent got blocked at (x={x:.1f}, y={y:.1f})")
            self._finish(i, STATUS_BLOCKED)
        for i in cav[timed_out].tolist():
            self._record(i, "route_timeout", f"Route timeout after {self._updates * self.dt:.1f} s")
            self._finish(i, STATUS_TIMEOUT)

    # ------------------------------------------------------------------ ending
    def _finish(self, i: int, outcome: str) -> None:
        self._outcome[i] = outcome
        self._running[i] = False
        self._newly[i] = True
        outside = self._outside_infraction(i)
        if outside is not None:
            self._infractions[i]["outside_route_lanes"].append(outside)

    def end_route(self, status: str) -> None:
        """The route stops (tick cap, crash): every CAV still running ends with the failure ``status``."""
        if not status.startswith("Failed"):
            raise ValueError(f"end_route needs a failure status ('Failed - ...'), got {status!r}")
        self._newly[:] = False
        for i in np.flatnonzero(self._running).tolist():
            self._finish(i, status)

    def finished(self) -> np.ndarray:
        """(n,) bool: the CAV's evaluation has ended (completed or failed)."""
        return ~self._running

    def newly_finished(self) -> np.ndarray:
        """(n,) bool: ended during the last :meth:`update` (or :meth:`end_route`)."""
        return self._newly.copy()

    # ------------------------------------------------------------------ hooks for scenarios
    def set_wrong_direction_check(self, cav: int, enabled: bool) -> None:
        """Switch the wrong-direction half of the outside-route-lanes test (the *TwoWays scenarios)."""
        self._wrong_direction_check[self._valid(cav)] = enabled

    def suspend_blocked(self, cav: int, suspended: bool) -> None:
        """Suspend the blocked test while a scenario's own timeout runs; it restarts from zero."""
        i = self._valid(cav)
        self._blocked_suspended[i] = suspended
        self._still_ticks[i] = 0

    def record_scenario_timeout(self, cav: int, tick: int, message: str) -> None:
        """A scenario's own timeout expired for this CAV: the 0.7 ``scenario_timeouts`` penalty."""
        i = self._valid(cav)
        if self._running[i]:
            self._record(i, "scenario_timeouts", message, tick=tick)

    def record_yield_to_emergency_vehicle(
        self, cav: int, ev_xy: np.ndarray | tuple[float, float], ev_heading: float, actor: str | None = None
    ) -> bool:
        """At the end of a yield-to-emergency-vehicle scenario: the CAV fails to yield when it is still
        ahead of the emergency vehicle (``ev_xy`` [m], ``ev_heading`` [rad]) along the vehicle's heading.
        Records the 0.7 penalty then and returns whether it did."""
        i = self._valid(cav)
        ahead = float(
            np.dot(self._xy[i] - np.asarray(ev_xy, np.float64), [np.cos(ev_heading), np.sin(ev_heading)])
        )
        if not self._running[i] or ahead <= 0.0:
            return False
        name = actor or "the emergency vehicle"
        self._record(
            i, "yield_emergency_vehicle_infractions", f"Agent failed to yield to {name}", actor=actor
        )
        return True

    def _valid(self, cav: int) -> int:
        if not 0 <= cav < len(self.routes):
            raise IndexError(f"CAV index {cav} out of range for a route with {len(self.routes)} CAVs")
        return int(cav)

    # ------------------------------------------------------------------ records
    def _record(
        self, i: int, key: str, message: str, actor: str | None = None, tick: int | None = None
    ) -> None:
        factor = PENALTIES[key]
        t = self._tick if tick is None else tick
        time = self._time if tick is None else tick * self.dt
        x, y = self._xy[i]
        self._infractions[i][key].append(
            Infraction(key, t, time, float(x), float(y), message, 1.0 if factor is None else factor, actor)
        )

    def _outside_infraction(self, i: int) -> Infraction | None:
        """The outside-route-lanes record of CAV i so far (None when it never was outside)."""
        driven = float(self._table.distance[i, self._route_index[i]])
        if self._outside_m[i] <= 0.0 or driven <= 0.0:
            return None
        pct = 100.0 * min(float(self._outside_m[i]) / driven, 1.0)
        message = (
            f"Agent went outside its route lanes for about {self._outside_m[i]:.1f} m "
            f"({pct:.2f}% of the completed route)"
        )
        x, y = self._xy[i]
        return Infraction(
            "outside_route_lanes", self._tick, self._time, float(x), float(y), message, 1.0 - pct / 100.0
        )

    def _min_speed_infractions(self, i: int) -> tuple[list[float], list[Infraction]]:
        values, records = [], []
        for part, pct in self._min_speed.checkpoints(i, self._route_completion(i)):
            values.append(pct)
            if pct < 100.0 - _PERCENT_EPS:  # summed in floating point: equal speeds give 99.9999...
                tick, x, y = self._min_speed.where[i, part]
                message = f"Average speed is {pct:.1f}% of the surrounding traffic's in route part {part + 1}"
                at = (int(tick), float(tick * self.dt), float(x), float(y))
                records.append(Infraction("min_speed_infractions", *at, message))
        return values, records

    def _route_completion(self, i: int) -> float:
        """RC_i [%]: 100 once completed, else the share of the route up to the furthest point passed."""
        if self._outcome[i] == _COMPLETED:
            return 100.0
        return float(self._table.completion(np.array([i]), self._route_index[[i]])[0])

    def results(self) -> list[CavResult]:
        """Scores of every CAV so far (a running CAV's outside-lanes share is counted up to now)."""
        out = []
        for i, cav_id in enumerate(self.cav_ids):
            infractions = {k: list(v) for k, v in self._infractions[i].items()}
            if self._running[i] and (outside := self._outside_infraction(i)) is not None:
                infractions["outside_route_lanes"].append(outside)
            checkpoints, infractions["min_speed_infractions"] = self._min_speed_infractions(i)
            score = float(np.prod([r.factor for v in infractions.values() for r in v]))
            status = self._outcome[i]
            if status == _COMPLETED:
                clean = all(not v for k, v in infractions.items() if k not in RECORDED_ONLY)
                status = STATUS_PERFECT if clean else STATUS_COMPLETED
            out.append(
                CavResult(
                    cav_id=cav_id,
                    status=status,
                    route_completion=self._route_completion(i),
                    infraction_score=score,
                    route_length=float(self._table.length[i]),
                    infractions=infractions,
                    min_speed_checkpoints=checkpoints,
                    ticks=int(self._ticks[i]),
                )
            )
        return out
