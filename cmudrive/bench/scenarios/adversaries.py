"""An emergency vehicle that crosses the junction against the CAV's right of way:
OppositeVehicleRunningRedLight and OppositeVehicleTakingPriority (``reference/SCENARIOS.md`` #23, #24).

The adversary is a SUMO ``ambulance`` (blue light) on the first entry lane with a straight exit of the
approach named by ``direction`` (right / left / opposite, relative to CAV 0's approach to its first
junction past T), up to 30 m upstream of the junction (the walk stops at the previous junction); it
appears at activation and stands. P, the collision point, is where the straight extensions of CAV 0's
and its approach lanes meet (the junction centre when they are parallel). Once CAV 0's time to
arrival at P drops below 2.2 s (or its distance below 12 m), the vehicle drives straight through at a
constant 60 km/h to 10 m past its exit, ignoring lights, right of way *and* other vehicles (SUMO speed
mode 0, as the reference's imposed velocity), for at most its path length / 16.7 m/s; then it is removed.
OppositeVehicleRunningRedLight also freezes the junction's lights from activation to the end: CAV 0's
approach green, every other signal red. The scenario ends once the vehicle is gone and CAV 0 left the
junction; no scenario timeout.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from cmudrive.bench.scenarios.base import EGO, RouteProgress, Scenario
from cmudrive.bench.scenarios.behaviours import time_to_arrival
from cmudrive.bench.scenarios.junctions import approach_lanes, exit_distance
from cmudrive.bench.scenarios.params import Param
from cmudrive.bench.scenarios.placement import LanePoint, point_xy, walk
from cmudrive.bench.scenarios.plan import PlanItem, path, point
from cmudrive.maps import RoadMap, RouteError
from cmudrive.maps.model import LaneKind, TurnDir
from cmudrive.maps.routing import LanePos, RoutePlanner
from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.snapshot import Role, Snapshot

EV_TYPE = "ambulance"
SPEED = 60.0 / 3.6  # [m/s]
UPSTREAM = 30.0  # [m] of the junction
PAST_EXIT = 10.0  # [m]
SIDES = {"right": math.pi / 2, "left": -math.pi / 2, "opposite": math.pi}  # approach heading - CAV 0's
SIDE_TOLERANCE = math.radians(35.0)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _end(m: RoadMap, lane: int) -> tuple[np.ndarray, float]:
    p = m.polyline(lane)
    d = p[-1] - p[-2]
    return p[-1], float(math.atan2(d[1], d[0]))


class OppositeVehicle(Scenario):
    """The family's shared behaviour."""

    uses_timeout = False
    params: ClassVar[tuple[Param, ...]] = (
        Param("direction", "", "right", choices=("right", "left", "opposite")),
    )
    red_light: ClassVar[bool] = False

    def place(self) -> None:
        m = self.map
        before, _, _ = self.junction_exit()
        route = self.ctx.routes[0]
        self.ego_lane = int(route.lane[before])
        self.junction = int(m.lane_junction[route.lane[before + 1]])
        if self.red_light and not np.any((m.link_from == self.ego_lane) & (m.link_tls >= 0)):
            raise self.error(
                f"no place for the scenario: CAV 0 enters its junction from lane "
                f"{m.lane_ids[self.ego_lane]}, which has no traffic light (the red-light runner needs one)"
            )
        entering = ~m.lane_internal[m.link_from] & (m.lane_kind[m.link_from] == LaneKind.DRIVING)
        links = np.flatnonzero(
            (m.link_junction == self.junction) & entering & (m.link_dir == TurnDir.STRAIGHT)
        )
        ego_end, ego_heading = _end(m, self.ego_lane)
        want = SIDES[str(self.p["direction"])]
        options = sorted(
            (int(m.lane_index[m.link_from[k]]), int(m.link_from[k]), int(m.link_to[k]))
            for k in links
            if abs(_wrap(_end(m, int(m.link_from[k]))[1] - ego_heading - want)) < SIDE_TOLERANCE
        )
        if not options:
            raise self.error(
                f"no place for the scenario: CAV 0's junction has no approach from the {self.p['direction']} "
                "with a straight exit"
            )
        _, lane, out = options[0]
        self.start = walk(m, LanePoint(lane, float(m.lane_length[lane])), -UPSTREAM, through_junctions=False)
        sink = walk(m, LanePoint(out, 0.0), PAST_EXIT, through_junctions=False)
        try:
            path = RoutePlanner(m).plan_lanes(
                LanePos(self.start.lane, self.start.s), LanePos(sink.lane, sink.s)
            )
        except RouteError as exc:
            raise self.error(f"no place for the adversary: {exc}") from None
        # the adversary's entry: its lanes up to the junction (upstream's rmEntries=[adversary lane])
        entry = []
        for x in path.path:
            if m.lane_internal[x]:
                break
            entry.append(int(x))
        self.entry_lanes = entry
        names = [str(m.edge_ids[m.lane_edge[x]]) for x in path.path if not m.lane_internal[x]]
        self.edges = [e for i, e in enumerate(names) if i == 0 or e != names[i - 1]]
        self.sink_xy = point_xy(m, sink)
        self.path_xy = path.xy  # (n, 2) [m] its drive through the junction
        self.max_time = path.length / SPEED  # [s]
        adv_end, adv_heading = _end(m, lane)
        self.collision_point = self._meet(ego_end, ego_heading, adv_end, adv_heading)
        self.ev_id = f"{self.spec.name}:ev"
        self.fired_at = math.nan
        self.gone = False
        r = self.ctx.routes[EGO]  # [m] along CAV 0's route: out of its junction
        self.goal = exit_distance(self.map, r, self.trigger_index)

    def plan(self) -> list[PlanItem]:
        start = point(EV_TYPE, self.path_xy[0], float(np.arctan2(*(self.path_xy[1] - self.path_xy[0])[::-1])))
        items: list[PlanItem] = [start, path("approach", self.path_xy)]
        return items + ([self.light_point(self.ego_lane)] if self.red_light else [])

    def _meet(self, a: np.ndarray, ha: float, b: np.ndarray, hb: float) -> np.ndarray:
        """Where the lines through a (heading ha) and b (heading hb) cross (junction centre: parallel)."""
        da, db = np.array([math.cos(ha), math.sin(ha)]), np.array([math.cos(hb), math.sin(hb)])
        det = da[0] * -db[1] - da[1] * -db[0]
        if abs(det) < 0.2:
            return np.asarray(self.map.junction_xy[self.junction], np.float64)
        t = ((b - a)[0] * -db[1] - (b - a)[1] * -db[0]) / det
        return a + t * da

    def on_activate(self, snap: Snapshot) -> None:
        import libsumo

        sumo = self.world.sumo
        if self.background is not None:
            self.background.clear_junction(self.junction)
            self.background.remove_lane(self.entry_lanes)  # nothing may stand where the vehicle starts
        if not self.red_light:  # upstream: stopEntries for OppositeVehicleTakingPriority only
            self.stop_entries(self.junction)
        half = 0.5 * ACTOR_TYPES[EV_TYPE].length
        sumo.add_vehicle(
            self.ev_id, EV_TYPE, self.edges, int(Role.SCENARIO),
            depart_pos=min(self.start.s + half, float(self.map.lane_length[self.start.lane]) - 0.1),
            depart_lane=int(self.map.lane_index[self.start.lane]), depart_speed=0.0,
        )  # fmt: skip
        self.added_at = self.world.step_count
        sumo.override(self.ev_id, ignore_lights=True, ignore_right_of_way=True, speed=0.0, lane_changes=False)
        libsumo.vehicle.setSpeedMode(self.ev_id, 0)  # ignores vehicles too: it will not brake for the CAV
        if self.red_light:
            self.world.lights.force_lanes(approach_lanes(self.map, self.ego_lane), "G", others="r")
            self.hold_at(self.junction)

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        import libsumo

        sumo = self.world.sumo
        if not self.gone:
            row = np.flatnonzero(snap.ids == self.ev_id)
            if math.isnan(self.fired_at) and len(row):  # (in the world: SUMO inserted it)
                if time_to_arrival(progress, self.collision_point, 2.2, 12.0):
                    self.fired_at = self.time
                    libsumo.vehicle.setSpeed(self.ev_id, SPEED)
            at_sink = (
                len(row) and np.hypot(*(np.array([snap.x[row[0]], snap.y[row[0]]]) - self.sink_xy)) < 2.0
            )
            timed = not math.isnan(self.fired_at) and self.time - self.fired_at > self.max_time
            dropped = False  # SUMO tried to insert it and gave up (its start stayed occupied)
            if not len(row) and self.world.step_count > self.added_at:
                known = set(libsumo.vehicle.getIDList()) | set(libsumo.simulation.getPendingVehicles())
                dropped = self.ev_id not in known
            if at_sink or timed or dropped or self.ev_id not in sumo.actors:
                sumo.remove(self.ev_id)
                self.gone = True
        self.passed |= self.ego_driven(progress) >= self.goal
        return self.gone and self.ego_passed()

    def on_end(self) -> None:
        self.world.sumo.remove(self.ev_id)
        if self.background is not None:
            self.background.readd_lane(self.entry_lanes)
        if self.red_light:
            self.world.lights.release()


class OppositeVehicleRunningRedLight(OppositeVehicle):
    """#23: the CAV has green; an emergency vehicle runs the red light across its path."""

    type_name = "OppositeVehicleRunningRedLight"
    red_light = True


class OppositeVehicleTakingPriority(OppositeVehicle):
    """#24: at an unsignalized junction an emergency vehicle takes priority across the CAV's path."""

    type_name = "OppositeVehicleTakingPriority"
