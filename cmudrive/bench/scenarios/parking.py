"""Pulling out of a parking slot: ParkingExit (``reference/SCENARIOS.md`` #29).

T is CAV 0's first route point. At instantiation CAV 0 is moved into the parking (or shoulder) lane on
the ``direction`` side abreast T, pushed toward that lane's outer edge by (w_side - half-width)/4, facing
along it; two cars are parked in the same lane (same edge offset) ``front_vehicle_distance`` m ahead and
``behind_vehicle_distance`` m behind it, and a SUMO car stands in the driving lane beside it at T. At
activation that car drives off under SUMO's own control and is removed once it drove 50 m. The scenario
ends once CAV 0 drove ``front_vehicle_distance`` + 15 m along its route (or ST240); then the scenario's
cars are removed. ``flow_distance`` (the reference's background spacing, ``RoadGap``) and ``speed`` are
read and not applied.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from cmudrive.bench.scenarios.base import RouteProgress, Scenario
from cmudrive.bench.scenarios.behaviours import lane_path
from cmudrive.bench.scenarios.params import DIRECTION, Param
from cmudrive.bench.scenarios.placement import LanePoint, heading, point_xy, side_sign, walk
from cmudrive.bench.scenarios.plan import PlanItem, path, point
from cmudrive.maps.model import LaneKind
from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.snapshot import Role, Snapshot

BESIDE_DRIVE = 50.0  # [m] the car beside drives this far, then leaves
AFTER_FRONT = 15.0  # [m] the scenario ends when CAV 0 drove front_vehicle_distance + this
BESIDE_CLEARANCE = 0.3  # [m] at least this between CAV 0 in its slot and the car beside it


class ParkingExit(Scenario):
    """#29: the CAV starts in a tight parking slot and must merge into traffic."""

    type_name = "ParkingExit"
    params: ClassVar[tuple[Param, ...]] = (
        DIRECTION,
        Param("front_vehicle_distance", "m", 20.0, lo=6.0, hi=100.0),
        Param("behind_vehicle_distance", "m", 10.0, lo=6.0, hi=100.0),
        Param("flow_distance", "m", 25.0, lo=0.0, hi=200.0),
        Param("speed", "km/h", 60.0, lo=0.0, hi=130.0),
    )

    def place(self) -> None:
        m, lane = self.map, self.t_wp.lane
        if self.trigger_index > 2:
            raise self.error("the trigger point must be CAV 0's first route point (it starts in the slot)")
        direction = str(self.p["direction"])
        k = int(m.lane_index[lane]) + (-1 if direction == "right" else 1)
        side = np.flatnonzero((m.lane_edge == m.lane_edge[lane]) & (m.lane_index == k))
        if len(side) != 1 or m.lane_kind[side[0]] not in (LaneKind.PARKING, LaneKind.SHOULDER):
            raise self.error(
                f"no place for the scenario: lane {m.lane_ids[lane]} has no parking or shoulder lane on "
                f"its {direction}"
            )
        self.side = int(side[0])
        w_side, half = float(m.lane_width[self.side]), 0.5 * ACTOR_TYPES["cav"].width
        # toward the outer edge; on a shoulder narrower than the CAV (CARLA's towns: 0.3-0.5 m) as far out
        # as it takes to clear the car that stands beside it on the driving lane (it touched that car at
        # tick 1 otherwise): the CAV then stands partly on the kerb, as a car parked on a narrow street
        clear = 0.5 * (ACTOR_TYPES["cav"].width + ACTOR_TYPES["car"].width) + BESIDE_CLEARANCE
        from_centres = 0.5 * (float(m.lane_width[lane]) + w_side)  # driving lane centre to side lane centre
        self.edge_offset = side_sign(direction) * max((w_side - half) / 4.0, clear - from_centres)
        s, _ = m.index.project(point_xy(m, self.t_wp)[None], np.array([self.side]))
        self.slot = LanePoint(self.side, float(s[0]))
        self.goal = float(self.ctx.routes[0].distance[self.trigger_index]) + self.num(
            "front_vehicle_distance"
        )
        self.goal += AFTER_FRONT
        self.beside = f"{self.spec.name}:beside"
        self.beside_gone = False
        m = self.map
        self.slot_pose = (point_xy(m, self.slot, self.edge_offset), heading(m, self.slot))  # CAV 0's start
        self.parked = []  # (name, (2,) position [m], yaw [rad]) of the cars ahead of and behind the slot
        front, behind = self.num("front_vehicle_distance"), -self.num("behind_vehicle_distance")
        for name, ahead in (("front", front), ("behind", behind)):
            at = walk(m, self.slot, ahead, through_junctions=False)
            self.parked.append((name, point_xy(m, at, self.edge_offset), heading(m, at)))

    def plan(self) -> list[PlanItem]:
        m = self.map
        items: list[PlanItem] = [point("slot", *self.slot_pose)]
        items += [point("car", xy, yaw) for _, xy, yaw in self.parked]
        items.append(point("car", point_xy(m, self.t_wp), heading(m, self.t_wp)))
        return [*items, path("drive_off", lane_path(m, self.t_wp, BESIDE_DRIVE, prefer=self.route_lanes))]

    def on_instantiate(self) -> None:
        m, world = self.map, self.world
        xy, yaw = self.slot_pose
        st = world.cav_state
        st.x[0], st.y[0], st.yaw[0], st.speed[0] = xy[0], xy[1], yaw, 0.0  # CAV 0 into the slot
        for name, at_xy, at_yaw in self.parked:
            self.spawn(name, "car", at_xy, at_yaw)
        route = self.ctx.routes[0]
        names = [str(m.edge_ids[m.lane_edge[x]]) for x in route.path if not m.lane_internal[x]]
        edges = [e for i, e in enumerate(names) if i == 0 or e != names[i - 1]]
        pos = min(self.t_wp.s + 0.5 * ACTOR_TYPES["car"].length, float(m.lane_length[self.t_wp.lane]) - 0.1)
        lane_index = int(m.lane_index[self.t_wp.lane])
        world.sumo.add_vehicle(self.beside, "car", edges, int(Role.SCENARIO), pos, lane_index, 0.0)
        world.sumo.override(self.beside, speed=0.0)  # waits for the activation

    def on_activate(self, snap: Snapshot) -> None:
        self.world.sumo.override(self.beside, speed=-1.0)  # drives off under SUMO's control

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        import libsumo

        if not self.beside_gone:
            try:
                driven = float(libsumo.vehicle.getDistance(self.beside))
            except libsumo.TraCIException:
                driven = 0.0
            if driven >= BESIDE_DRIVE or self.beside not in self.world.sumo.actors:
                self.world.sumo.remove(self.beside)
                self.beside_gone = True
        self.passed |= self.ego_driven(progress) >= self.goal
        return self.ego_passed()

    def on_end(self) -> None:
        self.world.sumo.remove(self.beside)
