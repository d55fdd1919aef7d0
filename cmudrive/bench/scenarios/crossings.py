"""Pedestrians and cyclists crossing the CAV's path: DynamicObjectCrossing, ParkingCrossingPedestrian,
PedestrianCrossing, VehicleTurningRoutePedestrian, VehicleTurningRoute (``reference/SCENARIOS.md`` #8,
#27, #30, #43, #42).

One family: one or more *crossers* (pedestrians, or a bicycle) stand beside the road, often behind an
occluder; once CAV 0's time to arrival at the crossing point X drops below t s (or its distance below
d m), each crosser waits its idle time and moves in a straight line across the road at a fixed speed for
a fixed length, then leaves the world. The scenario ends once CAV 0 has driven 40 m further after the
last crosser finished (no scenario timeout: none of these types has ST240).

======================  ============================================================================
type                    crossers, occluders and numbers
======================  ============================================================================
DynamicObjectCrossing   occluder (``blocker_model``) on the ``direction`` sidewalk abreast X =
                        next(``distance``); a pedestrian (blocker half-length + 0.5) m further on,
                        facing the road turned by ``crossing_angle``; TTA(2.1 + 0.1 floor(angle/5) s,
                        6 m, X); 2.0 m/s for twice its distance to X; LeaveSpace(distance + 10)
ParkingCrossingPedestrian  parked car one lane width to the ``direction`` side of B = next(``distance``);
                        pedestrian (car half-length + 0.5) m further on, also one lane width out;
                        TTA(2.15 + 0.1 floor(angle/5) s, 6 m, ego-lane point abreast it); 8 m at
                        2.0 m/s; LeaveSpace(distance + 15)
PedestrianCrossing      J = the route's last point before its first junction past T; three
                        pedestrians on the right sidewalk beside J at (ahead, outward) = (0.4, 1.5),
                        (1.0, 2.5), (1.6, 0.5) m, idle U[0, 1.5] s, speed U[1.3, 2.0] m/s, each walking
                        2.3 x its distance to J; TTA(3.5 s, 12 m, J)
VehicleTurningRoutePedestrian  X = 0.5 m past the route's junction exit; a pedestrian on the far
                        sidewalk of the exit road for a right turn, the near one for a left turn;
                        TTA(2.2 s, 6 m, X); 1.8 m/s across the whole road
VehicleTurningRoute     X = 11 m past the junction exit; a bicycle on the exit road's right sidewalk,
                        present from instantiation; TTA(1.8 s, 6 m, X); 1.8 m/s for twice its
                        distance to X
======================  ============================================================================

Pedestrians, the bicycle and occluders off the driving lanes are our layer's actors only (SUMO does not
see them); a crosser on the road is judged by our collisions like any actor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from cmudrive.bench.scenarios.base import RouteProgress, Scenario
from cmudrive.bench.scenarios.behaviours import PathMotion, time_to_arrival
from cmudrive.bench.scenarios.params import DIRECTION, Param
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

AFTER_CROSSING = 40.0  # [m] CAV 0 drives this far after the crossing before the scenario ends
BLOCKER_MODELS = {  # the route file's blueprint name -> our prop type
    "static.prop.vendingmachine": "vending_machine",
    "static.prop.advertisement": "advertisement",
    "static.prop.container": "container",
}
CROSSING_ANGLE = Param("crossing_angle", "deg", 0.0, lo=-90.0, hi=90.0)


@dataclass
class Crosser:
    """One actor that crosses: it stands at ``start`` facing ``yaw`` [rad], then (``idle`` s after the
    trigger) moves ``length`` m straight ahead at ``speed`` [m/s]."""

    suffix: str
    type_name: str
    start: np.ndarray  # (2,) [m]
    yaw: float
    speed: float
    length: float
    idle: float = 0.0
    motion: PathMotion = field(init=False)
    gone: bool = False

    def __post_init__(self) -> None:
        end = self.start + self.length * np.array([math.cos(self.yaw), math.sin(self.yaw)])
        self.motion = PathMotion(np.stack([self.start, end]), self.speed)


class Crossing(Scenario):
    """The family's shared behaviour; subclasses fill ``crossers``, ``props``, the TTA trigger in
    ``place`` and may ``leave_space``."""

    uses_timeout = False
    hidden: ClassVar[bool] = True  # crossers appear at activation (else at instantiation)
    leave_space: ClassVar[float | None] = None  # [m] LeaveSpace(distance + this) at activation

    crossers: list[Crosser]
    props: list[tuple[str, str, np.ndarray, float]]  # suffix, type, position, yaw
    tta: tuple[float, float, np.ndarray]  # seconds, metres, point

    def plan(self) -> list[PlanItem]:
        items: list[PlanItem] = [point(type_name, xy, yaw) for _, type_name, xy, yaw in self.props]
        for c in self.crossers:
            items += [point(c.type_name, c.start, c.yaw), path("crossing", c.motion.path)]
        return items

    def on_instantiate(self) -> None:
        for suffix, type_name, xy, yaw in self.props:
            self.spawn(suffix, type_name, xy, yaw, prop=type_name != "car")
        if not self.hidden:
            self.spawn_crossers()

    def spawn_crossers(self) -> None:
        for c in self.crossers:
            self.spawn(c.suffix, c.type_name, c.start, c.yaw)

    def on_activate(self, snap: Snapshot) -> None:
        self.fired_at = math.nan
        self.crossed_at = math.nan  # [m] CAV 0's route distance when the crossing ended
        if self.leave_space is not None and self.background is not None:
            self.background.leave_space(0, self.num("distance") + self.leave_space)
        if self.hidden:
            self.spawn_crossers()

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        seconds, metres, point = self.tta
        if math.isnan(self.fired_at):
            if time_to_arrival(progress, point, seconds, metres):
                self.fired_at = self.time
            return False
        for c in self.crossers:
            if c.gone or self.time - self.fired_at < c.idle:
                continue
            c.motion.advance(self.world.dt)
            xy, yaw = c.motion.pose()
            if c.motion.done:
                c.gone = True
                self.despawn(f"{self.spec.name}:{c.suffix}")
            else:
                self.world.set_layer_pose(f"{self.spec.name}:{c.suffix}", xy[0], xy[1], yaw, c.speed)
        if not all(c.gone for c in self.crossers):
            return False
        driven = self.ego_driven(progress)
        if math.isnan(self.crossed_at):  # the crossing just ended: occluders go too
            self.crossed_at = driven
            for actor_id in list(self.actors):
                self.despawn(actor_id)
        self.passed |= driven - self.crossed_at >= AFTER_CROSSING
        return self.ego_passed()

    # ------------------------------------------------------------------ placement helpers
    def facing_road(self, lp: LanePoint, direction: str, angle_deg: float = 0.0) -> float:
        """Yaw [rad] of an actor on the ``direction`` side looking across the road, turned by the angle
        (the reference's lane-yaw + 270 deg - angle in CARLA's left-handed frame)."""
        a = math.radians(angle_deg)
        h = heading(self.map, lp)
        return h + math.pi / 2 + a if direction == "right" else h - math.pi / 2 - a

    def next_point(self, start: LanePoint, distance: float, what: str) -> LanePoint:
        """next(distance) from ``start`` along the route's lanes; refused inside a junction."""
        lp = walk(self.map, start, distance, through_junctions=True, prefer=self.route_lanes)
        if self.map.lane_internal[lp.lane]:
            raise self.error(
                f"no place for the {what}: {distance:g} m downstream of the trigger is inside a junction"
            )
        return lp

    def far_side(self, lp: LanePoint) -> np.ndarray:
        """The roadside point across the whole road from the right side: the right side of the opposite
        carriageway on a two-way road, else the left kerb."""
        m = self.map
        edge = m.lane_edge[lp.lane]
        lanes = np.flatnonzero((m.lane_edge == edge) & (m.lane_kind == LaneKind.DRIVING))
        leftmost = int(lanes[np.argmax(m.lane_index[lanes])])
        opposite = int(m.lane_opposite[leftmost])
        if opposite == NO_INDEX:
            return roadside(m, lp, "left")[0]
        s, _ = m.index.project(point_xy(m, lp)[None], np.array([opposite]))
        return roadside(m, LanePoint(opposite, float(s[0])), "right")[0]


class DynamicObjectCrossing(Crossing):
    """#8: a pedestrian steps out from behind an occluder on the sidewalk."""

    type_name = "DynamicObjectCrossing"
    leave_space = 10.0
    params = (
        Param("distance", "m", 12.0, lo=5.0, hi=200.0),
        DIRECTION,
        Param("blocker_model", "", "static.prop.vendingmachine", choices=tuple(BLOCKER_MODELS)),
        CROSSING_ANGLE,
    )

    def place(self) -> None:
        direction, angle = str(self.p["direction"]), self.num("crossing_angle")
        x_lp = self.next_point(self.t_wp, self.num("distance"), "crossing point")
        x = point_xy(self.map, x_lp)
        blocker = BLOCKER_MODELS[str(self.p["blocker_model"])]
        b = ACTOR_TYPES[blocker]
        b_xy, _ = roadside(self.map, x_lp, direction)
        walker_lp = self.next_point(x_lp, 0.5 * b.length + 0.5, "pedestrian")
        w_xy, _ = roadside(self.map, walker_lp, direction)
        self.props = [("blocker", blocker, b_xy, heading(self.map, x_lp))]
        gap = float(np.linalg.norm(w_xy - x))
        yaw = self.facing_road(walker_lp, direction, angle)
        self.crossers = [Crosser("walker", "pedestrian", w_xy, yaw, 2.0, 2.0 * gap)]
        self.tta = (2.1 + 0.1 * math.floor(angle / 5.0), 6.0, x)


class ParkingCrossingPedestrian(Crossing):
    """#27: a pedestrian steps out in front of a car parked beside the ego lane."""

    type_name = "ParkingCrossingPedestrian"
    leave_space = 15.0
    params = (Param("distance", "m", 12.0, lo=5.0, hi=200.0), DIRECTION, CROSSING_ANGLE)

    def place(self) -> None:
        direction, angle = str(self.p["direction"]), self.num("crossing_angle")
        b_lp = self.next_point(self.t_wp, self.num("distance"), "parked car")
        if neighbour(self.map, b_lp.lane, direction) != NO_INDEX:
            raise self.error(
                f"no place for the parked car: lane {self.map.lane_ids[b_lp.lane]} has a driving lane on its "
                f"{direction} (the car parks one lane width to that side)"
            )
        out = side_sign(direction) * width(self.map, b_lp)
        car = ACTOR_TYPES["car"]
        walker_lp = self.next_point(b_lp, 0.5 * car.length + 0.5, "pedestrian")
        self.props = [("car", "car", point_xy(self.map, b_lp, out), heading(self.map, b_lp))]
        yaw = self.facing_road(walker_lp, direction, angle)
        self.crossers = [Crosser("walker", "pedestrian", point_xy(self.map, walker_lp, out), yaw, 2.0, 8.0)]
        self.tta = (2.15 + 0.1 * math.floor(angle / 5.0), 6.0, point_xy(self.map, walker_lp))


class PedestrianCrossing(Crossing):
    """#30: three pedestrians cross at the junction ahead."""

    type_name = "PedestrianCrossing"
    OFFSETS: ClassVar[tuple[tuple[float, float], ...]] = (
        (0.4, 1.5),
        (1.0, 2.5),
        (1.6, 0.5),
    )  # (ahead, out) [m]

    def place(self) -> None:
        before, _, _ = self.junction_exit()
        j_lp = self.route_point(before)
        j = point_xy(self.map, j_lp)
        base, _ = roadside(self.map, j_lp, "right")
        h = heading(self.map, j_lp)
        ahead, out = np.array([math.cos(h), math.sin(h)]), np.array([math.sin(h), -math.cos(h)])
        rng = self.ctx.rng
        self.props, self.crossers = [], []
        for k, (a, o) in enumerate(self.OFFSETS):
            start = base + a * ahead + o * out
            idle, speed = float(rng.uniform(0.0, 1.5)), float(rng.uniform(1.3, 2.0))
            length = 2.3 * float(np.linalg.norm(start - j))
            self.crossers.append(
                Crosser(f"walker{k}", "pedestrian", start, h + math.pi / 2, speed, length, idle)
            )
        self.tta = (3.5, 12.0, j)


class VehicleTurningRoutePedestrian(Crossing):
    """#43: after the turn, a pedestrian crosses the exit road."""

    type_name = "VehicleTurningRoutePedestrian"

    def place(self) -> None:
        _, after, turn = self.junction_exit()
        x_lp = walk(self.map, self.route_point(after), 0.5, through_junctions=False)
        x = point_xy(self.map, x_lp)
        near, _ = roadside(self.map, x_lp, "right")
        far = self.far_side(x_lp)
        start, end = (far, near) if turn < 0.0 else (near, far)  # right turn: from the far sidewalk
        d = end - start
        yaw = float(np.arctan2(d[1], d[0]))
        self.crossers = [Crosser("walker", "pedestrian", start, yaw, 1.8, float(np.linalg.norm(d)))]
        self.props = []
        self.tta = (2.2, 6.0, x)


class VehicleTurningRoute(Crossing):
    """#42: after the turn, a cyclist crosses the exit road from its right sidewalk."""

    type_name = "VehicleTurningRoute"
    hidden = False

    def place(self) -> None:
        _, after, _ = self.junction_exit()
        x_lp = walk(self.map, self.route_point(after), 11.0, through_junctions=False)
        x = point_xy(self.map, x_lp)
        start, _ = roadside(self.map, x_lp, "right")
        yaw = self.facing_road(x_lp, "right")
        self.crossers = [
            Crosser("bicycle", "bicycle", start, yaw, 1.8, 2.0 * float(np.linalg.norm(start - x)))
        ]
        self.props = []
        self.tta = (1.8, 6.0, x)
