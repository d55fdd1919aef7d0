"""Obstacles on the ego lane: Accident, ConstructionObstacle, ParkedObstacle, HazardAtSideLane.

One family (``reference/SCENARIOS.md`` #1, #4, #11, #25 and "Lane blockers / obstacles"): something
blocks the ego lane on a junction-free stretch with a free same-direction lane beside it; the CAV must
pass it through that lane. Shared sequence: ``LeaveSpace`` at activation; once CAV 0 is within
``close_distance`` of the first obstacle, idle 5 s, then cap background traffic (``MaxSpeed``); the
scenario ends when CAV 0 is ahead of the end point E (50 m past the last
obstacle, "in front of" test with no distance limit), or after the 240 s timeout. The actors are
removed and the cap lifted at the end.

Placement (T_wp = CAV 0's route point at the trigger, w = its lane width, ``fwd`` stops before a
junction: a layout that runs into one is refused with an error naming the scenario):

=====================  =========================================================================
Accident               police car at fwd(distance), car A 10 m further, car B 6 m further, all
                       0.3 w toward ``direction``; present from instantiation
ConstructionObstacle   C = fwd(distance): arrow board 5 m before C (across the lane centre), cones
                       every 2 m from C+2 to C+8 at 0.425 w on the passing side, 3 cones 1 m apart
                       across the lane at C+8; placed at activation, ego lane removed from BA
ParkedObstacle         one car at fwd(distance), 0.35 w toward ``direction``
HazardAtSideLane       bicycles at fwd(distance) and 9 m further, 0.275 w to the right; from
                       activation they ride their lane at ``bicycle_speed`` for
                       ``bicycle_drive_distance`` m, then stop
=====================  =========================================================================

Every type but HazardAtSideLane puts a warning sign beside T on the ``direction`` side (on the
sidewalk or shoulder, pushed 0.3 w outward; 1.5 m outside the outer lane where there is neither).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from cmudrive.bench.scenarios.base import EGO, RouteProgress, Scenario
from cmudrive.bench.scenarios.behaviours import PathMotion, ahead_of, lane_path, time_to_arrival, within
from cmudrive.bench.scenarios.flows import VehicleFlow, flow_path
from cmudrive.bench.scenarios.params import DIRECTION, KMH, Param
from cmudrive.bench.scenarios.placement import (
    LanePoint,
    heading,
    neighbour,
    point_xy,
    roadside,
    side_sign,
    walk,
    width,
)
from cmudrive.bench.scenarios.plan import PlanItem, path, point
from cmudrive.maps.model import NO_INDEX, LaneKind
from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.snapshot import Snapshot

IDLE = 5.0  # [s] after CAV 0 came close, before background traffic is capped
END_MARGIN = 50.0  # [m] the end point lies this far past the last obstacle
SIGN_PUSH = 0.3  # [lane widths] the warning sign's extra outward push


@dataclass(frozen=True)
class Item:
    """One obstacle actor: name suffix, actor type, lane point, lateral offset [m] (+ left), extra yaw
    [rad] relative to the lane, and whether it is a static prop."""

    suffix: str
    type_name: str
    at: LanePoint
    offset: float
    yaw: float = 0.0
    prop: bool = False


class LaneObstacle(Scenario):
    """The family's shared behaviour; subclasses give ``layout`` and the numbers."""

    close_distance: ClassVar[float] = 50.0  # [m] CAV 0 this close to the first obstacle starts the idle
    leave_space_extra: ClassVar[float] = 36.0  # [m] LeaveSpace(distance + this) at activation
    hidden: ClassVar[bool] = False  # True: obstacles appear at activation (else at instantiation)
    warning_sign: ClassVar[bool] = True
    two_ways: ClassVar[bool] = False  # pass through the oncoming lane (the *TwoWays variants)
    opposite_flow: ClassVar[bool] = True  # TwoWays: an OppositeFlow runs on the oncoming lane after the idle

    def layout(self) -> list[Item]:
        raise NotImplementedError

    # ------------------------------------------------------------------ placement
    @property
    def direction(self) -> str:
        return str(self.p.get("direction", "right"))

    def place(self) -> None:
        pass_side = "left" if self.direction == "right" else "right"
        if self.two_ways:
            if self.map.lane_opposite[self.t_wp.lane] == NO_INDEX:
                raise self.error(
                    f"no place for the scenario: lane {self.map.lane_ids[self.t_wp.lane]} at the trigger "
                    "point has no oncoming lane beside it to pass the obstacle through"
                )
        elif neighbour(self.map, self.t_wp.lane, pass_side) == NO_INDEX:
            raise self.error(
                f"no place for the scenario: lane {self.map.lane_ids[self.t_wp.lane]} at the trigger point "
                f"has no same-direction driving lane on its {pass_side} to pass the obstacle through"
            )
        self.items = self.layout()
        self.end_point = self.fwd(self.anchor(), END_MARGIN, "end point")
        self.end_xy = point_xy(self.map, self.end_point)
        self.end_heading = heading(self.map, self.end_point)
        self.first_xy = point_xy(self.map, self.items[0].at, self.items[0].offset)
        w = width(self.map, self.t_wp)
        self.sign_xy, _ = roadside(self.map, self.t_wp, self.direction, SIGN_PUSH * w)
        self.close_at = np.nan  # [s] when CAV 0 first came within close_distance
        self.capped = False
        self.flow: VehicleFlow | None = None

    def anchor(self) -> LanePoint:
        """The lane point the end (fwd(50) past it) and the OppositeFlow are measured from: the last
        obstacle (the reference's car B, the parked car, the door's car)."""
        return self.items[-1].at

    def shift(self, fraction: float) -> float:
        """Lateral offset [m] of ``fraction`` lane widths toward ``direction``."""
        return side_sign(self.direction) * fraction * width(self.map, self.t_wp)

    def spawn_items(self) -> None:
        for item in self.items:
            xy = point_xy(self.map, item.at, item.offset)
            yaw = heading(self.map, item.at) + item.yaw
            self.spawn(item.suffix, item.type_name, xy, yaw, prop=item.prop)

    # ------------------------------------------------------------------ life cycle
    def on_instantiate(self) -> None:
        if self.warning_sign:
            self.spawn(
                "sign", "warning_sign", self.sign_xy, heading(self.map, self.t_wp) + np.pi / 2, prop=True
            )
        if not self.hidden:
            self.spawn_items()

    def on_activate(self, snap: Snapshot) -> None:
        background = self.background
        if background is not None:
            background.leave_space(0, self.num("distance") + self.leave_space_extra)
        if self.hidden:
            self.spawn_items()

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        if np.isnan(self.close_at) and self.close_trigger(progress):
            self.close_at = self.time
        if not self.capped and self.time - self.close_at >= IDLE:
            self.capped = True
            self.after_idle()
        if self.flow is not None:
            self.flow.update(snap)
        self.update_passed(progress)
        return self.ego_passed()

    def close_point(self) -> np.ndarray:
        return self.first_xy

    def close_trigger(self, progress: RouteProgress) -> bool:
        """CAV 0 came close: the idle before the background cap (or the TwoWays switches) starts."""
        return within(progress, self.close_point(), self.close_distance)

    def update_passed(self, progress: RouteProgress) -> None:
        ahead = bool(ahead_of(progress.xy[EGO : EGO + 1], self.end_xy, self.end_heading)[0])
        self.passed |= bool(progress.present[EGO]) and ahead

    def after_idle(self) -> None:
        """One-way: cap background traffic (MaxSpeed). TwoWays: WrongDirOff for the affected CAVs (every CAV
        whose route passes the trigger meets the obstacle), OppOff, and an OppositeFlow on the oncoming lane
        beside the last obstacle."""
        background = self.background
        if not self.two_ways:
            if background is not None:
                background.max_speed(self.num("speed") * KMH)
            return
        for i in np.flatnonzero(self.affected).tolist():
            self.criteria.set_wrong_direction_check(i, False)
        if not self.opposite_flow:
            return
        if background is not None:
            background.opposite_traffic(False)
        self.flow = self.oncoming_flow()

    def oncoming_flow(self) -> VehicleFlow:
        """OppositeFlow: at the ego lane's speed limit v, from 1.5 v[km/h] + 30 m upstream to as far
        downstream of the oncoming-lane point beside the last obstacle (clipped at junctions)."""
        source, sink, v = self.oncoming_ends()
        gap, rng = self.span("frequency"), self.ctx.rng
        return VehicleFlow(f"{self.spec.name}:opp", self.world, self.map, source, sink, gap, v, rng, False)

    def oncoming_ends(self) -> tuple[LanePoint, LanePoint, float]:
        """The OppositeFlow's source and sink, and its speed [m/s]."""
        m, last = self.map, self.anchor()
        opposite = int(m.lane_opposite[last.lane])
        s, _ = m.index.project(point_xy(m, last)[None], np.array([opposite]))
        ref = LanePoint(opposite, float(s[0]))
        v = float(m.lane_speed[self.t_wp.lane])  # [m/s]
        half = 1.5 * v * 3.6 + 30.0  # [m] upstream mixes units: 1.5 x (speed in km/h) metres
        source = walk(m, ref, -half, through_junctions=False)
        sink = walk(m, ref, half, through_junctions=False)
        return source, sink, v

    def plan(self) -> list[PlanItem]:
        m = self.map
        items: list[PlanItem] = []
        if self.warning_sign:
            items.append(point("warning_sign", self.sign_xy, heading(m, self.t_wp) + np.pi / 2))
        for it in self.items:
            items.append(point(it.type_name, point_xy(m, it.at, it.offset), heading(m, it.at) + it.yaw))
        if self.two_ways and self.opposite_flow:
            source, sink, _ = self.oncoming_ends()
            items.append(path("flow", flow_path(m, source, sink).xy))
        return items

    def on_end(self) -> None:
        background = self.background
        if self.capped and not self.two_ways and background is not None:
            background.max_speed(None)
        if self.capped and self.two_ways:
            for i in np.flatnonzero(self.affected).tolist():
                self.criteria.set_wrong_direction_check(i, True)
            if self.flow is not None:
                self.flow.stop()
                if background is not None:
                    background.opposite_traffic(True)


class Accident(LaneObstacle):
    """#1: a police car and two crashed cars in the ego lane."""

    type_name = "Accident"
    params: ClassVar[tuple[Param, ...]] = (
        Param("distance", "m", 120.0, lo=5.0, hi=400.0),
        DIRECTION,
        Param("speed", "km/h", 60.0, lo=0.0, hi=130.0),
    )

    def layout(self) -> list[Item]:
        d = self.num("distance")
        police = self.fwd(self.t_wp, d, "police car")
        car_a = self.fwd(police, 10.0, "first crashed car")
        car_b = self.fwd(car_a, 6.0, "second crashed car")
        off = self.shift(0.3)
        return [
            Item("police", "police", police, off),
            Item("car_a", "car", car_a, off),
            Item("car_b", "car", car_b, off),
        ]

    def close_point(self) -> np.ndarray:  # the reference waits for car A
        return point_xy(self.map, self.items[1].at, self.items[1].offset)


class ParkedObstacle(LaneObstacle):
    """#25: one badly parked car intruding into the ego lane."""

    type_name = "ParkedObstacle"
    leave_space_extra = 20.0
    params: ClassVar[tuple[Param, ...]] = Accident.params

    def layout(self) -> list[Item]:
        at = self.fwd(self.t_wp, self.num("distance"), "parked car")
        return [Item("car", "car", at, self.shift(0.35))]


class ConstructionObstacle(LaneObstacle):
    """#4: road works closing the ego lane: arrow board and an L of cones."""

    type_name = "ConstructionObstacle"
    close_distance = 30.0
    leave_space_extra = 10.0  # the reference does not LeaveSpace here; it removes the ego lane instead
    hidden = True
    params: ClassVar[tuple[Param, ...]] = (
        Param("distance", "m", 100.0, lo=10.0, hi=400.0),
        DIRECTION,
        Param("speed", "km/h", 60.0, lo=0.0, hi=130.0),
    )

    def layout(self) -> list[Item]:
        d = self.num("distance")
        c = self.c = self.fwd(self.t_wp, d, "construction site")
        board = self.fwd(self.t_wp, d - 5.0, "arrow board")
        w, side = width(self.map, self.t_wp), side_sign(self.direction)
        items = [Item("board", "warning_sign", board, 0.0, prop=True)]
        for k, ahead in enumerate((2.0, 4.0, 6.0, 8.0)):  # along the passing side of the lane
            items.append(Item(f"cone{k}", "cone", self.fwd(c, ahead, "cones"), -side * 0.425 * w, prop=True))
        across = self.fwd(c, 8.0, "cones")
        for k in range(3):  # across the lane toward `direction`, 1 m apart
            items.append(Item(f"cone{4 + k}", "cone", across, -side * (0.425 * w - (k + 1.0)), prop=True))
        return items

    def on_activate(self, snap: Snapshot) -> None:
        if self.background is not None:
            self.background.remove_lane([self.t_wp.lane])
        super().on_activate(snap)

    def close_point(self) -> np.ndarray:  # the reference waits for C, 5 m past the arrow board
        return point_xy(self.map, self.c)

    def anchor(self) -> LanePoint:  # the reference's end and oncoming flow are measured from C
        return self.c

    def on_end(self) -> None:
        super().on_end()
        if self.background is not None:
            self.background.readd_lane([self.t_wp.lane])


class HazardAtSideLane(LaneObstacle):
    """#11: two slow cyclists at the right edge of the ego lane."""

    type_name = "HazardAtSideLane"
    leave_space_extra = 29.0
    warning_sign = False
    params: ClassVar[tuple[Param, ...]] = (
        Param("distance", "m", 100.0, lo=5.0, hi=400.0),
        Param("speed", "km/h", 60.0, lo=0.0, hi=130.0),
        Param("bicycle_speed", "km/h", 10.0, lo=0.0, hi=40.0),
        Param("bicycle_drive_distance", "m", 50.0, lo=0.0, hi=500.0),
    )

    @property
    def direction(self) -> str:
        return "right"  # the cyclists ride at the right edge; the CAV passes on the left

    def layout(self) -> list[Item]:
        d = self.num("distance")
        first = self.fwd(self.t_wp, d, "first bicycle")
        second = self.fwd(first, 9.0, "second bicycle")
        off = self.shift(0.275)
        return [Item("bike1", "bicycle", first, off), Item("bike2", "bicycle", second, off)]

    def place(self) -> None:
        super().place()
        ride = self.num("bicycle_drive_distance")
        speed = self.num("bicycle_speed") * KMH
        self.bikes = [
            PathMotion(lane_path(self.map, it.at, max(ride, 0.5), it.offset, self.route_lanes), speed)
            for it in self.items
        ]
        self.riding = False
        self.ahead_at = np.nan  # [m] CAV 0's route distance when it got ahead of bicycle 2

    def plan(self) -> list[PlanItem]:
        return super().plan() + [path("ride", bike.path) for bike in self.bikes]

    def on_activate(self, snap: Snapshot) -> None:
        super().on_activate(snap)
        self.riding = True

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        if self.riding:
            for item, bike in zip(self.items, self.bikes, strict=True):
                bike.advance(self.world.dt)
                xy, yaw = bike.pose()
                self.world.set_layer_pose(
                    f"{self.spec.name}:{item.suffix}", xy[0], xy[1], yaw, bike.current_speed
                )
        return super().on_update(snap, progress)

    def close_point(self) -> np.ndarray:
        return self.bikes[0].pose()[0]

    def update_passed(self, progress: RouteProgress) -> None:
        """CAV 0 ahead of bicycle 2 (by both half-lengths), then 50 m more along its route."""
        xy, yaw = self.bikes[1].pose()
        margin = 0.5 * (1.8 + 4.89)  # [m] half-lengths of a bicycle and a CAV
        front = xy + margin * np.array([np.cos(yaw), np.sin(yaw)])
        driven = self.ego_driven(progress)
        if np.isnan(self.ahead_at) and progress.present[EGO]:
            if ahead_of(progress.xy[EGO : EGO + 1], front, yaw)[0]:
                self.ahead_at = driven
        self.passed |= driven - self.ahead_at >= END_MARGIN


FREQUENCY = Param("frequency", "m", (20.0, 100.0), lo=5.0, hi=1000.0, is_range=True)


class AccidentTwoWays(Accident):
    """#2: the accident on a two-way road; the CAV passes through the oncoming lane in a gap of an
    OppositeFlow (``frequency`` m gaps); no speed cap."""

    type_name = "AccidentTwoWays"
    two_ways = True
    params: ClassVar[tuple[Param, ...]] = (*Accident.params, FREQUENCY)


class ParkedObstacleTwoWays(ParkedObstacle):
    """#26: the parked car on a two-way road, passed through the oncoming lane."""

    type_name = "ParkedObstacleTwoWays"
    two_ways = True
    params: ClassVar[tuple[Param, ...]] = (*ParkedObstacle.params, FREQUENCY)


class ConstructionObstacleTwoWays(ConstructionObstacle):
    """#5: the road works on a two-way road, passed through the oncoming lane."""

    type_name = "ConstructionObstacleTwoWays"
    two_ways = True
    params: ClassVar[tuple[Param, ...]] = (*ConstructionObstacle.params, FREQUENCY)


class HazardAtSideLaneTwoWays(HazardAtSideLane):
    """#12: the cyclists on a two-way road; after the idle only the wrong-direction check is switched off
    (the reference re-spaces background oncoming traffic with ``frequency``; ours is left as it is)."""

    type_name = "HazardAtSideLaneTwoWays"
    two_ways = True
    opposite_flow = False
    params: ClassVar[tuple[Param, ...]] = (
        *HazardAtSideLane.params,
        Param("frequency", "m", 100.0, lo=5.0, hi=1000.0),
    )


class VehicleOpensDoorTwoWays(LaneObstacle):
    """#41: a car parked in the side lane opens its door into the ego lane on a two-way road."""

    type_name = "VehicleOpensDoorTwoWays"
    two_ways = True
    warning_sign = False
    leave_space_extra = 20.0
    params: ClassVar[tuple[Param, ...]] = (
        Param("distance", "m", 50.0, lo=5.0, hi=400.0),
        DIRECTION,
        FREQUENCY,
        Param("speed", "km/h", 60.0, lo=0.0, hi=130.0),  # read upstream, unused
    )
    DOOR_HINGE = 0.9  # [m] ahead of the car's centre
    DOOR_ANGLE = np.radians(60.0)  # opened this far from the car's side

    def layout(self) -> list[Item]:
        m, lane = self.map, self.t_wp.lane
        k = int(m.lane_index[lane]) + (-1 if self.direction == "right" else 1)
        side = np.flatnonzero((m.lane_edge == m.lane_edge[lane]) & (m.lane_index == k))
        if len(side) != 1 or m.lane_kind[side[0]] == LaneKind.DRIVING:
            raise self.error(
                f"no place for the parked car: lane {m.lane_ids[lane]} has no parking or shoulder lane on "
                f"its {self.direction}"
            )
        w, w_side = width(m, self.t_wp), float(m.lane_width[side[0]])
        half = 0.5 * ACTOR_TYPES["car"].width
        at = self.fwd(self.t_wp, self.num("distance"), "parked car")
        offset = side_sign(self.direction) * (0.5 * w + 0.5 * w_side - (w_side - half) / 4.0)
        return [Item("car", "car", at, offset)]

    def close_trigger(self, progress: RouteProgress) -> bool:
        """TTA(3.0 s, 10 m, F): the door opens (and stays open); the 5 s idle starts."""
        item = self.items[0]
        if not time_to_arrival(progress, point_xy(self.map, item.at), 3.0, 10.0):
            return False
        h = heading(self.map, item.at)
        car = point_xy(self.map, item.at, item.offset)
        toward = -side_sign(self.direction)  # the door on the ego-lane side: +1 left of the car
        normal = np.array([-np.sin(h), np.cos(h)]) * toward
        hinge = (
            car + self.DOOR_HINGE * np.array([np.cos(h), np.sin(h)]) + 0.5 * ACTOR_TYPES["car"].width * normal
        )
        yaw = h + np.pi - toward * self.DOOR_ANGLE  # swung open backwards, out into the lane
        centre = hinge + 0.5 * ACTOR_TYPES["car_door"].length * np.array([np.cos(yaw), np.sin(yaw)])
        self.spawn("door", "car_door", centre, yaw, prop=True)
        # StopBack: the background behind CAV 0 on its lane waits until the end (what is ahead drives on)
        lane = self.t_wp.lane
        s_ego, _ = self.map.index.project(progress.xy[EGO : EGO + 1], np.array([lane]))
        self.halt_lanes([lane], float(s_ego[0]))
        return True
