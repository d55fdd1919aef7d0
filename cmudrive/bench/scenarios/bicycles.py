"""A flow of bicycles along a bike lane across the CAV's path at a junction: CrossingBicycleFlow
(``reference/SCENARIOS.md`` #7).

The flow (``flows.VehicleFlow`` of ``bicycle`` actors, imposed: ``flow_speed`` m/s, red lights and right
of way ignored, no lane changes) runs from the bike-lane point nearest ``start_actor_flow`` (within
``SNAP``) along the bike lanes through the junction (its straight exit where the bike lane has one) to
``PAST_EXIT`` m past the junction exit (clipped at the end of the exit lane), with gaps
U[``source_dist_interval``] m; pre-filled at activation outside the junction. The bike lane must cross
CAV 0's first junction past T. At activation that junction is cleared of background traffic; if CAV 0's
approach has a traffic light: 5 s with every signal of its light red, then CAV 0's approach green and every
other signal red until the end (then the light's program resumes). End: CAV 0
left that junction, or ST240. ``end_actor_flow`` is read and unused, as upstream.

A map without bike lanes (CARLA's Town01-07) has no place for the scenario: setup raises a ScenarioError
naming the route, the scenario and the reason, and the route is recorded as a route-input error.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from cmudrive.bench.scenarios.base import EGO, RouteProgress, Scenario
from cmudrive.bench.scenarios.flows import VehicleFlow
from cmudrive.bench.scenarios.junctions import approach_lanes, exit_distance, red_then_green_stage
from cmudrive.bench.scenarios.params import Param
from cmudrive.bench.scenarios.placement import LanePoint
from cmudrive.bench.scenarios.plan import PlanItem, path
from cmudrive.maps import RouteError
from cmudrive.maps.coords import carla_to_map
from cmudrive.maps.model import LaneKind, TurnDir
from cmudrive.sim.snapshot import Snapshot

SNAP = 10.0  # [m] start_actor_flow must lie this close to a bike lane (reference: < 10 m)
PAST_EXIT = 40.0  # [m] the flow's sink past the junction exit, along the exit bike lane
BIKE_TYPE = "bicycle"


class CrossingBicycleFlow(Scenario):
    """#7: bicycles ride along a bike lane through the junction CAV 0 turns at; it waits for a gap."""

    type_name = "CrossingBicycleFlow"
    params: ClassVar[tuple[Param, ...]] = (
        Param("start_actor_flow", "m", None, is_location=True, required=True),
        Param("end_actor_flow", "m", None, is_location=True),  # read upstream, unused
        Param("flow_speed", "m/s", 10.0, lo=0.5, hi=40.0),
        Param("source_dist_interval", "m", (20.0, 50.0), lo=2.0, hi=500.0, is_range=True),
    )
    PHASES: ClassVar[tuple[tuple[str, str], ...]] = (("r", "r"), ("G", "r"))  # (CAV 0's signal, others)

    def place(self) -> None:
        m = self.map
        bike = m.lane_kind == LaneKind.BIKE
        if not np.any(bike):
            raise self.error(
                f"no place for the scenario: map {m.name!r} has no bike lane (the bicycle flow rides "
                "along one through the junction)"
            )
        x, y, _ = self.span("start_actor_flow")
        xy = carla_to_map(np.array([[x, y]]))[0]
        proj = m.index.nearest_lane(xy[None], kinds=(LaneKind.BIKE,), max_distance=SNAP)
        if proj.lane[0] < 0:
            raise self.error(f"parameter 'start_actor_flow': no bike lane within {SNAP:g} m of it")
        source = LanePoint(int(proj.lane[0]), float(proj.s[0]))
        before, _, _ = self.junction_exit()
        route = self.ctx.routes[0]
        self.ego_lane = int(route.lane[before])
        self.junction = int(m.lane_junction[route.lane[before + 1]])
        out = self._exit_lane(source)
        sink = LanePoint(out, min(PAST_EXIT, float(m.lane_length[out]) - 0.1))
        v, gap = self.num("flow_speed"), self.span("source_dist_interval")
        try:
            self.flow = VehicleFlow(
                f"{self.spec.name}:bikes", self.ctx.world, m, source, sink, gap, v, self.ctx.rng, True,
                type_name=BIKE_TYPE, lanes=bike,
            )  # fmt: skip
        except RouteError as exc:
            raise self.error(f"no place for the bicycle flow: {exc}") from None
        if not np.any(m.lane_junction[self.flow.path.lane] == self.junction):
            raise self.error(
                f"no place for the bicycle flow: the bike lane from 'start_actor_flow' (lane "
                f"{m.lane_ids[source.lane]}) does not cross CAV 0's junction"
            )
        self.signalized = bool(np.any((m.link_from == self.ego_lane) & (m.link_tls >= 0)))
        r = self.ctx.routes[EGO]  # [m] along CAV 0's route: out of its junction
        self.goal = exit_distance(self.map, r, self.trigger_index)

    def _exit_lane(self, source: LanePoint) -> int:
        """The bike lane past the first junction downstream of ``source`` (its straight exit if any)."""
        m, lane = self.map, source.lane
        for _ in range(20):  # a few edges of bike lane before the junction
            links = np.flatnonzero((m.link_from == lane) & (m.lane_kind[m.link_to] == LaneKind.BIKE))
            if len(links) == 0:
                break
            straight = links[m.link_dir[links] == TurnDir.STRAIGHT]
            link = int((straight if len(straight) else links)[0])
            if m.link_via[link] >= 0:  # through a junction's internal lanes
                return int(m.link_to[link])
            lane = int(m.link_to[link])
        raise self.error(
            f"no place for the bicycle flow: bike lane {m.lane_ids[source.lane]} leads through no junction"
        )

    def plan(self) -> list[PlanItem]:
        items: list[PlanItem] = [path("flow", self.flow.path.xy)]
        return items + ([self.light_point(self.ego_lane)] if self.signalized else [])

    def on_activate(self, snap: Snapshot) -> None:
        if self.background is not None:
            self.background.clear_junction(self.junction)
        self.stop_entries(self.junction)  # (and holds the CAVs through the junction: forced lights too)
        self.flow.prefill()
        self.light_phase = -1

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        self.flow.update(snap)
        if self.signalized:
            k = red_then_green_stage(self.time - self.activated_at)
            if k != self.light_phase:
                ego, others = self.PHASES[k]
                self.world.lights.force_lanes(approach_lanes(self.map, self.ego_lane), ego, others)
                self.light_phase = k
        self.passed |= self.ego_driven(progress) >= self.goal
        return self.ego_passed()

    def on_end(self) -> None:
        self.flow.stop()
        if self.signalized:
            self.world.lights.release()
