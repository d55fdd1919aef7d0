"""An emergency vehicle the CAV must let pass: YieldToEmergencyVehicle (``reference/SCENARIOS.md`` #44).

The emergency vehicle (an ``ambulance`` with SUMO's blue-light device, so SUMO traffic forms a rescue
lane) is a SUMO vehicle under ``SumoSession.override``: it appears at activation in the ego lane exactly
``distance`` m upstream of T_wp (the ego lane removed from background traffic), keeps its lane, runs red
lights, and is told every tick to drive at CAV 0's speed + 25 m/s (90 km/h, the reference's
as-coded number; its type caps it at 36 m/s). SUMO's car-following keeps it from ramming a vehicle ahead
in its lane: it matches a blocking CAV's speed, as the reference's detection does.

End: the vehicle came within 50 m of CAV 0 and 10 s passed, or it got ahead of CAV 0 (its centre past the
point one CAV and one vehicle half-length in front of CAV 0, within 10 m of that point: upstream's
WaitUntilInFront) and then drove 50 m. At the end CAV 0, the scenario's ego, is judged if it is still running
(``record_yield_to_emergency_vehicle``): ahead of the vehicle's centre along its heading = failed to yield
(x0.7). Other CAVs ahead of the vehicle are not charged (upstream's test is the ego's). No scenario timeout.
"""

from __future__ import annotations

import math

import numpy as np

from cmudrive.bench.scenarios.base import EGO, RouteProgress, Scenario
from cmudrive.bench.scenarios.behaviours import ahead_of, lane_path
from cmudrive.bench.scenarios.params import Param
from cmudrive.bench.scenarios.placement import heading, neighbour, point_xy, walk
from cmudrive.bench.scenarios.plan import PlanItem, path, point
from cmudrive.maps.model import NO_INDEX
from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.snapshot import Role, Snapshot

EV_TYPE = "ambulance"
EV_HEADWAY = 0.3  # [s] its car-following headway: it closes to ~10 m behind a blocker at 20 m/s
EXTRA_SPEED = 25.0  # [m/s] over the CAV's speed
APPROACH_PAST = 30.0  # [m] past T that the plan draws the approach (it drives on along the route)
NEAR, NEAR_TIME = 50.0, 10.0  # [m], [s]: within NEAR of CAV 0, then NEAR_TIME: end
PASS_NEAR, PASS_DRIVE = 10.0, 50.0  # [m]: ahead of CAV 0 within PASS_NEAR, then PASS_DRIVE more: end


class YieldToEmergencyVehicle(Scenario):
    """#44: an emergency vehicle approaches from behind in the ego lane."""

    type_name = "YieldToEmergencyVehicle"
    uses_timeout = False
    params = (Param("distance", "m", 140.0, lo=5.0, hi=400.0),)

    def place(self) -> None:
        m = self.map
        lane = self.t_wp.lane
        if neighbour(m, lane, "left") == NO_INDEX and neighbour(m, lane, "right") == NO_INDEX:
            raise self.error(
                f"no place for the scenario: lane {m.lane_ids[lane]} at the trigger point has no "
                "same-direction neighbour to yield into"
            )
        d = self.num("distance")
        self.spawn_at = walk(m, self.t_wp, -d, through_junctions=False)
        travelled = float(np.linalg.norm(point_xy(m, self.t_wp) - point_xy(m, self.spawn_at)))
        if travelled < d - 0.5:  # the walk back stopped at a junction (straight road: chord = arc)
            raise self.error(
                f"parameter 'distance' [m]: the ego lane has only {travelled:.0f} m of junction-free road "
                f"behind the trigger point, {d:g} m needed"
            )
        self.ev_id = f"{self.spec.name}:ev"
        self.half_lengths = 0.5 * (ACTOR_TYPES["cav"].length + ACTOR_TYPES[EV_TYPE].length)  # [m]
        self.near_at = math.nan  # [s] when the vehicle first came within NEAR of CAV 0
        self.passed_at = math.nan  # [m] the vehicle's driven distance when it first got ahead of CAV 0

    def plan(self) -> list[PlanItem]:
        """The vehicle in the ego lane ``distance`` m behind T and its approach along CAV 0's lanes."""
        m, d = self.map, self.num("distance")
        lane_ahead = lane_path(m, self.spawn_at, d + APPROACH_PAST, prefer=self.route_lanes)
        return [
            point(EV_TYPE, point_xy(m, self.spawn_at), heading(m, self.spawn_at)),
            path("approach", lane_ahead),
        ]

    def _edges(self) -> list[str]:
        """SUMO edges from the spawn lane along CAV 0's route."""
        m = self.map
        names = [str(m.edge_ids[m.lane_edge[x]]) for x in self.ctx.routes[0].path if not m.lane_internal[x]]
        first = str(m.edge_ids[m.lane_edge[self.spawn_at.lane]])
        edges = [first] + (names[names.index(first) + 1 :] if first in names else names)
        return [e for i, e in enumerate(edges) if i == 0 or e != edges[i - 1]]

    def on_activate(self, snap: Snapshot) -> None:
        m, sumo = self.map, self.world.sumo
        if self.background is not None:
            self.background.remove_lane([self.t_wp.lane])
        sumo.add_vehicle(
            self.ev_id,
            EV_TYPE,
            self._edges(),
            int(Role.SCENARIO),
            depart_pos=self.spawn_at.s + 0.5 * ACTOR_TYPES[EV_TYPE].length,  # SUMO places the front bumper
            depart_lane=int(m.lane_index[self.spawn_at.lane]),
            depart_speed="max",
        )
        sumo.override(self.ev_id, ignore_lights=True, lane_changes=False)

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        if self.ev_id not in self.world.sumo.actors:  # it left the network
            return True
        row = np.flatnonzero(snap.ids == self.ev_id)
        if len(row) == 0:  # inserted at the next SUMO step
            return False
        r = int(row[0])
        if not hasattr(self, "ev_pose"):  # first tick in the world: follow closely, like the reference
            import libsumo

            libsumo.vehicle.setTau(self.ev_id, EV_HEADWAY)
        ev_xy, ev_yaw = np.array([snap.x[r], snap.y[r]]), float(snap.yaw[r])
        self.ev_pose = (ev_xy, ev_yaw)
        self.world.sumo.override(
            self.ev_id, ignore_lights=True, speed=float(progress.speed[EGO]) + EXTRA_SPEED, lane_changes=False
        )
        gap = float(np.linalg.norm(progress.xy[EGO] - ev_xy))
        if math.isnan(self.near_at) and gap < NEAR:
            self.near_at = self.time
        # upstream's WaitUntilInFront: ahead of the point one CAV + one vehicle half-length in front of CAV
        # 0 (along its heading), and within PASS_NEAR of that point
        yaw = float(progress.yaw[EGO])
        ref = progress.xy[EGO] + self.half_lengths * np.array([math.cos(yaw), math.sin(yaw)])
        ev_ahead = bool(ahead_of(ev_xy[None], ref, yaw)[0])
        if math.isnan(self.passed_at) and ev_ahead and float(np.linalg.norm(ev_xy - ref)) < PASS_NEAR:
            self.passed_at = self._driven()
        if not math.isnan(self.passed_at) and self._driven() - self.passed_at >= PASS_DRIVE:
            return True
        return not math.isnan(self.near_at) and self.time - self.near_at >= NEAR_TIME

    def _driven(self) -> float:
        import libsumo

        return float(libsumo.vehicle.getDistance(self.ev_id))

    def on_end(self) -> None:
        pose = getattr(self, "ev_pose", None)
        if pose is not None and self.ego_running():
            self.criteria.record_yield_to_emergency_vehicle(EGO, pose[0], pose[1], actor=self.ev_id)
        self.world.sumo.remove(self.ev_id)
        if self.background is not None:
            self.background.readd_lane([self.t_wp.lane])
