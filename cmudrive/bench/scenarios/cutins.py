"""Vehicles cutting into the CAV's lane: StaticCutIn and ParkingCutIn (``reference/SCENARIOS.md`` #35,
#28).

Both are scripted paths of our kinematic layer (the car is pushed into SUMO like a CAV, so traffic
reacts to it): a car stands beside the ego lane; once CAV 0's time to arrival at the ego-lane point
abreast it drops below t s (or its distance below d m), it moves onto the ego lane along a smooth lane
change of ``CHANGE_LENGTH`` m and follows the lane; at the end of its path the scenario's cars are
removed and the scenario ends. Neither type has a scenario timeout.

=============  ==================================================================================
StaticCutIn    six cars queue in the adjacent lane on the ``direction`` side abreast next(d), d+11,
               ..., d+55 (placed at activation; that lane removed from background traffic); the
               one at d+22 cuts in when TTA(2.7 s, 15 m) fires, at the CAV's current speed for the
               lane change, then 70 m along the ego lane at 60 km/h (30 s cap); LeaveSpace(d+66)
ParkingCutIn   two cars parked in the side (parking/shoulder) lane abreast next(28) (blocker) and
               next(35) (cut-in car), pushed toward the outer edge by (w_side - half-width)/4,
               present from instantiation; TTA(2.35 s, 10 m) fires, the cut-in car pulls out into
               the ego lane at 20 km/h and drives 30 m; LeaveSpace(45)
=============  ==================================================================================

The reference's cut-in cars are driven by CARLA's lane-change and local-planner controllers; ours
follow a smoothstep lateral profile over ``CHANGE_LENGTH`` m at an imposed speed (no acceleration
phase: CARLA sets the target speed at once too).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from cmudrive.bench.scenarios.base import EGO, RouteProgress, Scenario, first_real_junction
from cmudrive.bench.scenarios.behaviours import PathMotion, lane_change_path, lane_path, time_to_arrival
from cmudrive.bench.scenarios.params import DIRECTION, KMH, Param
from cmudrive.bench.scenarios.placement import LanePoint, heading, neighbour, point_xy, side_sign, walk
from cmudrive.bench.scenarios.plan import PlanItem, path, point
from cmudrive.maps.coords import carla_to_map
from cmudrive.maps.model import NO_INDEX, LaneKind
from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.snapshot import Snapshot

CHANGE_LENGTH = 8.0  # [m] travelled during the lateral move onto the ego lane


class CutIn(Scenario):
    """The family's shared behaviour; subclasses place ``cars`` and the cut-in path in ``place``."""

    uses_timeout = False
    hidden: ClassVar[bool] = False
    leave_space: float = 45.0  # [m] LeaveSpace at activation
    max_time: ClassVar[float] = math.inf  # [s] the cut-in is cut short after this

    cars: list[tuple[str, np.ndarray, float]]  # suffix, position, yaw
    cutter: str  # suffix of the car that cuts in
    path: np.ndarray  # (n, 2) its path
    tta: tuple[float, float, np.ndarray]  # seconds, metres, point
    change_speed: float | None  # [m/s] during the lane change (None: the triggering CAV's speed)
    cruise_speed: float  # [m/s] after it

    def plan(self) -> list[PlanItem]:
        items: list[PlanItem] = [point("car", xy, yaw) for _, xy, yaw in self.cars]
        return [*items, path("cut_in", self.path)]

    def on_instantiate(self) -> None:
        if not self.hidden:
            self.spawn_cars()

    def spawn_cars(self) -> None:
        for suffix, xy, yaw in self.cars:
            self.spawn(suffix, "car", xy, yaw)

    def on_activate(self, snap: Snapshot) -> None:
        self.fired_at = math.nan
        self.motion: PathMotion | None = None
        if self.background is not None:
            self.background.leave_space(0, self.leave_space)
        if self.hidden:
            self.spawn_cars()

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        seconds, metres, point = self.tta
        if self.motion is None:
            if not time_to_arrival(progress, point, seconds, metres):
                return False
            self.fired_at = self.time
            speed = self.change_speed if self.change_speed is not None else float(progress.speed[EGO])
            self.motion = PathMotion(self.path, max(speed, 1.0))
        motion = self.motion
        motion.advance(self.world.dt)
        if motion.s >= CHANGE_LENGTH:
            motion.speed = self.cruise_speed
        xy, yaw = motion.pose()
        self.world.set_layer_pose(f"{self.spec.name}:{self.cutter}", xy[0], xy[1], yaw, motion.speed)
        return motion.done or self.time - self.fired_at >= self.max_time


class StaticCutIn(CutIn):
    """#35: a car leaves a stopped queue in the adjacent lane and cuts in front of the CAV."""

    type_name = "StaticCutIn"
    hidden = True
    max_time = 30.0
    params = (Param("distance", "m", 100.0, lo=5.0, hi=400.0), DIRECTION)
    GAPS: ClassVar[tuple[float, ...]] = (0.0, 11.0, 22.0, 33.0, 44.0, 55.0)  # [m] past next(distance)
    AFTER = 70.0  # [m] along the ego lane after the lane change
    CRUISE = 60.0  # [km/h]

    def place(self) -> None:
        direction, d = str(self.p["direction"]), self.num("distance")
        self.queue_lane = neighbour(self.map, self.t_wp.lane, direction)
        if self.queue_lane == NO_INDEX:
            raise self.error(
                f"no place for the queue: lane {self.map.lane_ids[self.t_wp.lane]} at the trigger point has "
                f"no same-direction driving lane on its {direction}"
            )
        self.leave_space = d + 66.0
        self.cars = []
        w = float(self.map.lane_width[self.t_wp.lane])
        offset = side_sign(direction) * 0.5 * (w + float(self.map.lane_width[self.queue_lane]))
        for k, gap in enumerate(self.GAPS):
            at = walk(self.map, self.t_wp, d + gap, through_junctions=True, prefer=self.route_lanes)
            if self.map.lane_internal[at.lane]:
                raise self.error(
                    f"no place for the queue: car {k} ({d + gap:g} m past T) falls in a junction"
                )
            self.cars.append((f"car{k}", point_xy(self.map, at, offset), heading(self.map, at)))
            if gap == 22.0:
                self.cutter, cut_at = f"car{k}", at
        self.path = lane_change_path(self.map, cut_at, offset, CHANGE_LENGTH, self.AFTER, self.route_lanes)
        self.tta = (2.7, 15.0, point_xy(self.map, cut_at))
        self.change_speed, self.cruise_speed = None, self.CRUISE * KMH

    def on_activate(self, snap: Snapshot) -> None:
        super().on_activate(snap)
        if self.background is not None:
            self.background.remove_lane([self.queue_lane])

    def on_end(self) -> None:
        if self.background is not None:
            self.background.readd_lane([self.queue_lane])


class ParkingCutIn(CutIn):
    """#28: a parked car pulls out of the parking lane into the CAV's lane."""

    type_name = "ParkingCutIn"
    params = (DIRECTION,)
    BLOCKER_AT, CUTTER_AT = 28.0, 35.0  # [m] past T
    DRIVE = 30.0  # [m] the cut-in car's whole path
    SPEED = 20.0  # [km/h]

    def place(self) -> None:
        direction = str(self.p["direction"])
        m = self.map
        side = self.side_lane(direction)
        half = 0.5 * ACTOR_TYPES["car"].width
        w, w_side = float(m.lane_width[self.t_wp.lane]), float(m.lane_width[side])
        offset = side_sign(direction) * (0.5 * w + 0.5 * w_side + (w_side - half) / 4.0)
        self.cars = []
        for suffix, ahead in (("blocker", self.BLOCKER_AT), ("cutter", self.CUTTER_AT)):
            at = walk(m, self.t_wp, ahead, through_junctions=False, prefer=self.route_lanes)
            if at.s - self.t_wp.s < ahead - 1e-6 and at.lane == self.t_wp.lane:
                raise self.error(
                    f"no place for the parked cars: a junction lies less than {ahead:g} m past T"
                )
            self.cars.append((suffix, point_xy(m, at, offset), heading(m, at)))
        self.cutter = "cutter"
        self.path = lane_change_path(
            m, at, offset, CHANGE_LENGTH, self.DRIVE - CHANGE_LENGTH, self.route_lanes
        )
        self.tta = (2.35, 10.0, point_xy(m, at))
        self.change_speed = self.cruise_speed = self.SPEED * KMH

    def side_lane(self, direction: str) -> int:
        """The parking or shoulder lane beside the ego lane on ``direction``'s side."""
        m, lane = self.map, self.t_wp.lane
        k = int(m.lane_index[lane]) + (-1 if direction == "right" else 1)
        same = np.flatnonzero((m.lane_edge == m.lane_edge[lane]) & (m.lane_index == k))
        ok = len(same) == 1 and m.lane_kind[same[0]] in (LaneKind.PARKING, LaneKind.SHOULDER)
        if not ok:
            raise self.error(
                f"no place for the parked cars: lane {m.lane_ids[lane]} has no parking or shoulder lane on "
                f"its {direction}"
            )
        return int(same[0])


class HighwayCutIn(Scenario):
    """#13: a car from an on-ramp times its merge to meet the CAV and cuts into its lane."""

    type_name = "HighwayCutIn"
    uses_timeout = False
    params = (
        Param("other_actor_location", "m", None, is_location=True, required=True),
        Param("end_location", "m", None, is_location=True),  # read by the reference, unused
    )
    SNAP = 5.0  # [m] other_actor_location must lie this close to a driving lane
    SYNC_PAST_EXIT = 10.0  # [m] the car aims at its junction exit + this when the CAV is at its exit
    SWITCH = 5.0  # [m] it starts the lane change this close to that point
    SAME, LATERAL, AFTER = 0.3, 2.0, 3.0  # [s] of the lane change, turned into metres at its speed
    SPEED_SHARE = 0.8  # lane-change speed / the CAV's speed
    MAX_SPEED = 40.0  # [m/s] cap of the timing speed

    def place(self) -> None:
        m = self.map
        x, y, _ = self.span("other_actor_location")
        xy = carla_to_map(np.array([[x, y]]))[0]
        proj = m.index.nearest_lane(xy[None], max_distance=self.SNAP)
        if proj.lane[0] < 0:
            raise self.error(
                f"parameter 'other_actor_location': no driving lane within {self.SNAP:g} m of it"
            )
        self.start = LanePoint(int(proj.lane[0]), float(proj.s[0]))
        route = self.ctx.routes[0]
        first = first_real_junction(m, route, self.trigger_index)
        if first < 0:
            raise self.error(
                "no place for the scenario: CAV 0's route meets no junction (the on-ramp) after T"
            )
        after = np.flatnonzero(~route.in_junction[first:]) + first
        self.ego_exit = float(route.distance[after[0] if len(after) else len(route) - 1])
        to_exit = self._distance_to_exit(self.start)
        self.sync = to_exit + self.SYNC_PAST_EXIT
        self.approach = PathMotion(lane_path(m, self.start, self.sync), 0.0)
        merge_at = walk(m, self.start, self.sync, through_junctions=True)
        self.merge_at = merge_at  # the car's lane point where its lane change starts (route rules read it)
        if neighbour(m, merge_at.lane, "left") == NO_INDEX:
            raise self.error(
                f"no place for the cut-in: lane {m.lane_ids[merge_at.lane]} {self.SYNC_PAST_EXIT:g} m past "
                "the ramp's junction has no driving lane on its left"
            )
        self.cut: PathMotion | None = None

    def _distance_to_exit(self, start: LanePoint) -> float:
        """[m] along the car's lanes (first branch) to the end of the first junction it crosses."""
        m, lane, s, travelled, seen = self.map, start.lane, start.s, 0.0, False
        for _ in range(1000):
            travelled += float(m.lane_length[lane]) - s
            succ = m.successors(lane)
            if len(succ) == 0:
                break
            seen |= bool(m.lane_internal[lane])
            lane, s = int(succ[0]), 0.0
            if seen and not m.lane_internal[lane]:
                return travelled
        raise self.error("parameter 'other_actor_location': the car's lane leads through no junction")

    def plan(self) -> list[PlanItem]:
        """The car at its start and its ramp path to the merge point (the lane change itself is timed to
        the CAV's speed at run time)."""
        xy, yaw = self.approach.pose()
        return [point("car", xy, yaw), path("cut_in", self.approach.path)]

    def on_activate(self, snap: Snapshot) -> None:
        xy, yaw = self.approach.pose()
        self.spawn("car", "car", xy, yaw)
        background = self.background
        if background is not None:
            lanes = self.map.successors(self.start.lane)
            if len(lanes) and self.map.lane_junction[lanes[0]] >= 0:
                background.clear_junction(int(self.map.lane_junction[lanes[0]]))

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        route, dt = self.ctx.routes[0], self.world.dt
        ego_speed = float(progress.speed[0])
        if self.cut is None:
            remaining = self.sync - self.approach.s
            ego_left = self.ego_exit - float(route.distance[progress.index[0]])
            time_left = ego_left / ego_speed if ego_left > 0.0 and ego_speed > 0.1 else math.inf
            self.approach.speed = float(np.clip(remaining / time_left, 0.0, self.MAX_SPEED))
            if ego_left <= 0.0:
                self.approach.speed = self.MAX_SPEED
            self.approach.advance(dt)
            motion = self.approach
            if remaining <= self.SWITCH:
                self.cut = self._lane_change(self.SPEED_SHARE * max(ego_speed, 1.0))
        else:
            motion = self.cut
            motion.advance(dt)
        xy, yaw = motion.pose()
        self.world.set_layer_pose(f"{self.spec.name}:car", xy[0], xy[1], yaw, motion.current_speed)
        return self.cut is not None and self.cut.done

    def _lane_change(self, v: float) -> PathMotion:
        m = self.map
        here = walk(m, self.start, self.approach.s, through_junctions=True)
        same = walk(m, here, v * self.SAME, through_junctions=True)
        target = neighbour(m, same.lane, "left")
        s, _ = m.index.project(point_xy(m, same)[None], np.array([target]))
        offset = -0.5 * float(m.lane_width[same.lane] + m.lane_width[target])
        change = lane_change_path(m, LanePoint(target, float(s[0])), offset, v * self.LATERAL, v * self.AFTER)
        path = np.concatenate([lane_path(m, here, max(v * self.SAME, 0.5))[:-1], change])
        return PathMotion(path, v)
