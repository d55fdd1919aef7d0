"""Traffic flows the CAV must merge into or cross: EnterActorFlow, HighwayExit, MergerIntoSlowTraffic,
MergerIntoSlowTrafficV2, InterurbanActorFlow (``reference/SCENARIOS.md`` #9, #14, #18, #19, #15).

Each runs ActorFlows (``flows.VehicleFlow`` with ``imposed``: SUMO cars at ``flow_speed`` [m/s] that
ignore lights and right of way and never change lanes) from the driving lane nearest
``start_actor_flow`` to the one nearest ``end_actor_flow`` (both CARLA-frame x y z, within 5 m of a lane),
with gaps U[``source_dist_interval``] m; all have the 240 s scenario timeout.

* EnterActorFlow: one flow per same-direction lane of the source road, paired in order with the sink road's
  lanes (aligned on the given source and sink lanes); pre-filled; the junction the CAV enters cleared;
  ends when CAV 0 reached a sink.
* HighwayExit: one pre-filled flow; its source lane removed from background traffic (not re-added, as
  upstream); ends when CAV 0 left the first junction past T.
* MergerIntoSlowTraffic(V2): one pre-filled flow; the junction cleared and the source lane removed from
  background traffic; ends when CAV 0 reached any lane of the road at the sink.
* InterurbanActorFlow: one flow, not pre-filled; background oncoming traffic off during the scenario; ends
  when CAV 0 left the first junction past T.

"Reached a sink" is within 2 m of a sink point or past it (ahead along its lane, within a lane width of
it): a CAV that drives beside the sink point passes it without touching its 2 m circle. As in every type,
the end follows CAV 0, the scenario's ego (``base.py``).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from cmudrive.bench.scenarios.base import EGO, RouteProgress, Scenario, first_real_junction
from cmudrive.bench.scenarios.flows import VehicleFlow
from cmudrive.bench.scenarios.junctions import exit_distance
from cmudrive.bench.scenarios.params import Param
from cmudrive.bench.scenarios.placement import LanePoint, heading, point_xy
from cmudrive.bench.scenarios.plan import PlanItem, path
from cmudrive.maps import RouteError
from cmudrive.maps.coords import carla_to_map
from cmudrive.maps.model import LaneKind
from cmudrive.sim.snapshot import Snapshot

SNAP = 5.0  # [m] a flow location must lie this close to a driving lane
SINK_REACHED = 2.0  # [m]
FLOW_PARAMS = (
    Param("start_actor_flow", "m", None, is_location=True, required=True),
    Param("end_actor_flow", "m", None, is_location=True, required=True),
    Param("flow_speed", "m/s", 10.0, lo=0.5, hi=40.0),
    Param("source_dist_interval", "m", (20.0, 50.0), lo=2.0, hi=500.0, is_range=True),
)


class ActorFlowScenario(Scenario):
    """The family's shared behaviour; subclasses set the class switches."""

    params: ClassVar[tuple[Param, ...]] = FLOW_PARAMS
    prefill: ClassVar[bool] = True
    all_lanes: ClassVar[bool] = False  # one flow per same-direction lane (EnterActorFlow)
    end_at_sink: ClassVar[bool] = True  # else: the CAVs left the first junction past T
    clear_junction: ClassVar[bool] = False
    remove_source_lane: ClassVar[bool] = False
    opposite_off: ClassVar[bool] = False
    sink_road: ClassVar[bool] = False  # the end is any same-direction lane abreast the sink (else the sink)

    def locate(self, name: str) -> LanePoint:
        x, y, _ = self.span(name)
        xy = carla_to_map(np.array([[x, y]]))[0]
        proj = self.map.index.nearest_lane(xy[None], max_distance=SNAP)
        if proj.lane[0] < 0:
            raise self.error(f"parameter {name!r}: no driving lane within {SNAP:g} m of it")
        lane = int(proj.lane[0])
        if self.map.lane_internal[lane]:
            return self.out_of_junction(name, lane)
        return LanePoint(lane, float(proj.s[0]))

    def out_of_junction(self, name: str, lane: int) -> LanePoint:
        """A flow end inside a junction (CARLA's junction areas are smaller than SUMO's, and CARLA can spawn
        there; SUMO cannot insert a car on a junction's internal lane): the start of the road its internal
        lane leads onto, so the flow drives the same path from there."""
        m = self.map
        for _ in range(8):  # internal lanes chain through a junction in a few pieces
            after = [int(x) for x in m.successors(lane) if m.lane_kind[x] == LaneKind.DRIVING]
            if not after:
                break
            lane = after[0]
            if not m.lane_internal[lane]:
                return LanePoint(lane, 0.0)
        raise self.error(f"parameter {name!r}: it lies inside a junction whose lane leads onto no road")

    def place(self) -> None:
        source, sink = self.locate("start_actor_flow"), self.locate("end_actor_flow")
        self.pairs = self._pairs(source, sink) if self.all_lanes else [(source, sink)]
        ends = [b for _, b in self.pairs]
        if self.sink_road:
            ends = self._abreast(sink)
        self.sinks = np.array([point_xy(self.map, b) for b in ends])  # (k, 2)
        self.sink_heading = np.array([heading(self.map, b) for b in ends])
        self.flows: list[VehicleFlow] = []
        gap, speed = self.span("source_dist_interval"), self.num("flow_speed")
        for k, (a, b) in enumerate(self.pairs):
            name = f"{self.spec.name}:flow{k}"
            try:
                self.flows.append(
                    VehicleFlow(name, self.ctx.world, self.map, a, b, gap, speed, self.ctx.rng, True)
                )
            except RouteError as exc:  # EnterActorFlow: a lane pair with no path is left out
                if k == 0 or not self.all_lanes:
                    raise self.error(f"no lane path from start_actor_flow to end_actor_flow: {exc}") from None
        route = self.ctx.routes[EGO]
        # [m] along CAV 0's route: where it has left the first junction past T
        self.goal = exit_distance(self.map, route, self.trigger_index)
        if not self.end_at_sink and not np.isfinite(self.goal):
            raise self.error("no place for the scenario: CAV 0's route meets no junction after T")

    def plan(self) -> list[PlanItem]:
        return [path("flow", flow.path.xy) for flow in self.flows]

    def _abreast(self, p: LanePoint) -> list[LanePoint]:
        """The points abreast ``p`` on every driving lane of its road (its edge), ``p`` first."""
        m = self.map
        edge = np.flatnonzero((m.lane_edge == m.lane_edge[p.lane]) & (m.lane_kind == LaneKind.DRIVING))
        xy = point_xy(m, p)[None]
        out = [p]
        for lane in edge.tolist():
            if lane != p.lane:
                s, _ = m.index.project(xy, np.array([lane]))
                out.append(LanePoint(lane, float(s[0])))
        return out

    def _pairs(self, source: LanePoint, sink: LanePoint) -> list[tuple[LanePoint, LanePoint]]:
        """Same-direction lanes of the source and sink roads, aligned on the given lanes."""
        m = self.map

        def lanes_of(p: LanePoint) -> list[int]:
            edge = np.flatnonzero((m.lane_edge == m.lane_edge[p.lane]) & (m.lane_kind == LaneKind.DRIVING))
            return edge[np.argsort(m.lane_index[edge])].tolist()

        src, dst = lanes_of(source), lanes_of(sink)
        shift = dst.index(sink.lane) - src.index(source.lane)
        pairs = []
        for k, a in enumerate(src):
            if 0 <= k + shift < len(dst):
                b = dst[k + shift]
                s_a, _ = m.index.project(point_xy(m, source)[None], np.array([a]))
                s_b, _ = m.index.project(point_xy(m, sink)[None], np.array([b]))
                pairs.append((LanePoint(a, float(s_a[0])), LanePoint(b, float(s_b[0]))))
        return pairs

    def on_activate(self, snap: Snapshot) -> None:
        background, m = self.background, self.map
        for flow in self.flows:
            if self.prefill:
                flow.prefill()
        if background is not None:
            if self.remove_source_lane:
                background.remove_lane([a.lane for a, _ in self.pairs])
            if self.opposite_off:
                background.opposite_traffic(False)
            if self.clear_junction:
                route = self.ctx.routes[0]
                first = first_real_junction(m, route, self.trigger_index)
                if first >= 0:
                    background.clear_junction(int(m.lane_junction[route.lane[first]]))

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        for flow in self.flows:
            flow.update(snap)
        if self.end_at_sink:
            rel = progress.xy[EGO] - self.sinks  # (k, 2)
            along = rel[:, 0] * np.cos(self.sink_heading) + rel[:, 1] * np.sin(self.sink_heading)
            across = -rel[:, 0] * np.sin(self.sink_heading) + rel[:, 1] * np.cos(self.sink_heading)
            near = np.linalg.norm(rel, axis=1) < SINK_REACHED
            past = (along > 0.0) & (np.abs(across) < 3.5) & (along < 30.0)
            self.passed |= bool(progress.present[EGO]) and bool(np.any(near | past))
        else:
            self.passed |= self.ego_driven(progress) >= self.goal
        return self.ego_passed()

    def on_end(self) -> None:
        for flow in self.flows:
            flow.stop()
        if self.opposite_off and self.background is not None:
            self.background.opposite_traffic(True)


class EnterActorFlow(ActorFlowScenario):
    """#9: merge into a continuous flow on every lane of the road the route joins."""

    type_name = "EnterActorFlow"
    all_lanes = True
    clear_junction = True


class HighwayExit(ActorFlowScenario):
    """#14: cross the lane carrying a flow to take the exit."""

    type_name = "HighwayExit"
    end_at_sink = False
    remove_source_lane = True


class MergerIntoSlowTraffic(ActorFlowScenario):
    """#18: merge from the ramp into a slow flow; the source lane leaves background traffic; the end is
    CAV 0 within 2 m of any lane of the road at the sink (or past that point)."""

    type_name = "MergerIntoSlowTraffic"
    clear_junction = True
    remove_source_lane = True
    sink_road = True


class MergerIntoSlowTrafficV2(MergerIntoSlowTraffic):
    """#19: the variant at entries with a dedicated lane."""

    type_name = "MergerIntoSlowTrafficV2"


class InterurbanActorFlow(ActorFlowScenario):
    """#15: turn off across a flow in the lane beside."""

    type_name = "InterurbanActorFlow"
    prefill = False
    end_at_sink = False
    opposite_off = True


class InterurbanAdvancedActorFlow(ActorFlowScenario):
    """#16: cross flow 1, then merge into flow 2 on the opposite carriageway of the same road. Flow 1 runs
    from ``start_actor_flow`` to ``end_actor_flow``; flow 2 from the oncoming lane beside flow 1's sink to
    the oncoming lane beside flow 1's source; neither is pre-filled; the junction is cleared and background
    oncoming traffic paused; ends when CAV 0 reached flow 2's sink."""

    type_name = "InterurbanAdvancedActorFlow"
    params: ClassVar[tuple[Param, ...]] = (
        *FLOW_PARAMS,
        Param("direction", "", "right", choices=("right", "left")),
    )
    prefill = False
    clear_junction = True
    opposite_off = True

    def place(self) -> None:
        super().place()
        m = self.map
        source, sink = self.pairs[0]
        beside = []
        for p in (sink, source):
            opposite = int(m.lane_opposite[p.lane])
            if opposite < 0:
                raise self.error(
                    f"no place for flow 2: lane {m.lane_ids[p.lane]} of flow 1 has no oncoming lane beside it"
                )
            s, _ = m.index.project(point_xy(m, p)[None], np.array([opposite]))
            beside.append(LanePoint(opposite, float(s[0])))
        name = f"{self.spec.name}:flow1"
        gap, speed = self.span("source_dist_interval"), self.num("flow_speed")
        try:
            self.flows.append(
                VehicleFlow(name, self.ctx.world, m, beside[0], beside[1], gap, speed, self.ctx.rng, True)
            )
        except RouteError as exc:
            raise self.error(f"no lane path for flow 2: {exc}") from None
        self.pairs.append((beside[0], beside[1]))
        self.sinks = point_xy(m, beside[1])[None]  # the end: flow 2's sink
        self.sink_heading = np.array([heading(m, beside[1])])
