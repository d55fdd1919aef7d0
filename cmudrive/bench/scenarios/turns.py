"""Turning across or into a flow at a junction (``reference/SCENARIOS.md`` #20-#22, #32-#34):
NonSignalizedJunctionLeftTurn, NonSignalizedJunctionLeftTurnEnterFlow, NonSignalizedJunctionRightTurn,
SignalizedJunctionLeftTurn, SignalizedJunctionLeftTurnEnterFlow, SignalizedJunctionRightTurn.

CAV 0's route turns at its first junction past T (left or right, as the type says). An ActorFlow
(``flows.VehicleFlow``, imposed ``flow_speed`` [m/s], lights and right of way ignored) comes from

* the left turns: one lane (drawn at random) of the *opposite* approach, from up to 4 v m upstream of
  the junction (the walk stops at the previous junction) to 2.5 v m past that lane's straight exit
  (``...EnterFlow``: past its right-turn exit, into the road CAV 0 turns into); not pre-filled; background
  oncoming traffic paused during the scenario;
* the right turns: the right-most lane of the approach from CAV 0's *left*, from up to 5 v m upstream to
  3 v m past its straight exit, pre-filled;

with gaps U[``source_dist_interval``] m; the junction is cleared of background traffic at activation.
The signalized types force the lights: 5 s CAV 0's approach red and the flow's approach green (every
other signal red), then both green until the scenario ends (each approach forced whole, as a CARLA light).
End: CAV 0 drove 10 m past the junction, or the 240 s timeout.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from cmudrive.bench.scenarios.base import EGO, RouteProgress, Scenario
from cmudrive.bench.scenarios.flows import VehicleFlow
from cmudrive.bench.scenarios.junctions import (
    AFTER_JUNCTION,
    approach_lanes,
    exit_distance,
    red_then_green_stage,
)
from cmudrive.bench.scenarios.params import Param
from cmudrive.bench.scenarios.placement import LanePoint, walk
from cmudrive.bench.scenarios.plan import PlanItem, path
from cmudrive.maps import RouteError
from cmudrive.maps.model import LaneKind, TurnDir
from cmudrive.sim.snapshot import Snapshot

SIDE = {"opposite": math.pi, "left": -math.pi / 2}  # [rad] flow approach heading minus CAV 0's
SIDE_TOLERANCE = math.radians(35.0)
STRAIGHT = (TurnDir.STRAIGHT,)
RIGHT = (TurnDir.RIGHT, TurnDir.PARTLY_RIGHT)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class JunctionTurnFlow(Scenario):
    """The family's shared behaviour; subclasses set the geometry switches."""

    params: ClassVar[tuple[Param, ...]] = (
        Param("flow_speed", "m/s", 20.0, lo=0.5, hi=40.0),
        Param("source_dist_interval", "m", (25.0, 50.0), lo=2.0, hi=500.0, is_range=True),
    )
    turn: ClassVar[str] = "left"  # CAV 0's turn
    side: ClassVar[str] = "opposite"  # where the flow comes from
    flow_exit: ClassVar[tuple[TurnDir, ...]] = STRAIGHT
    source_factor: ClassVar[float] = 4.0  # [s] x flow_speed upstream
    sink_factor: ClassVar[float] = 2.5  # [s] x flow_speed past the exit
    prefill: ClassVar[bool] = False
    signalized: ClassVar[bool] = False

    def place(self) -> None:
        m = self.map
        before, _, turn = self.junction_exit()
        if (turn > 0.0) != (self.turn == "left") or abs(turn) < math.radians(30.0):
            raise self.error(
                f"no place for the scenario: CAV 0's route does not turn {self.turn} at its junction"
            )
        route = self.ctx.routes[0]
        self.ego_lane = int(route.lane[before])
        self.junction = int(m.lane_junction[route.lane[before + 1]])
        entering = ~m.lane_internal[m.link_from] & (m.lane_kind[m.link_from] == LaneKind.DRIVING)
        links = np.flatnonzero((m.link_junction == self.junction) & entering)
        ego_heading = self._end_heading(self.ego_lane)
        candidates = []
        for lane in sorted(set(m.link_from[links].tolist())):
            rel = _wrap(self._end_heading(lane) - ego_heading - SIDE[self.side])
            exits = links[(m.link_from[links] == lane) & np.isin(m.link_dir[links], self.flow_exit)]
            if abs(rel) < SIDE_TOLERANCE and len(exits):
                candidates.append((int(m.lane_index[lane]), lane, int(m.link_to[exits[0]])))
        if not candidates:
            raise self.error(
                f"no place for the scenario: the junction has no approach from the {self.side} with a "
                f"{'right-turn' if self.flow_exit == RIGHT else 'straight'} exit"
            )
        if self.side == "opposite":
            _, lane, out = candidates[int(self.ctx.rng.integers(len(candidates)))]
        else:
            _, lane, out = min(candidates)  # the right-most lane
        self.flow_lane = lane
        v = self.num("flow_speed")
        end = LanePoint(lane, float(m.lane_length[lane]))
        self.source = walk(m, end, -self.source_factor * v, through_junctions=False)
        self.sink = walk(m, LanePoint(out, 0.0), self.sink_factor * v, through_junctions=False)
        try:
            self.flow = VehicleFlow(
                f"{self.spec.name}:flow0", self.ctx.world, m, self.source, self.sink,
                self.span("source_dist_interval"), v, self.ctx.rng, imposed=True,
            )  # fmt: skip
        except RouteError as exc:
            raise self.error(f"no place for the flow: {exc}") from None
        r = self.ctx.routes[EGO]  # [m] along CAV 0's route: 10 m past its junction
        self.goal = exit_distance(self.map, r, self.trigger_index) + AFTER_JUNCTION
        if self.signalized and not np.any((m.link_from == self.ego_lane) & (m.link_tls >= 0)):
            raise self.error("no place for the scenario: CAV 0's junction has no traffic light")

    def plan(self) -> list[PlanItem]:
        items: list[PlanItem] = [] if self.flow is None else [path("flow", self.flow.path.xy)]
        if self.signalized:
            items += [self.light_point(self.ego_lane), self.light_point(self.flow_lane)]
        return items

    def _end_heading(self, lane: int) -> float:
        p = self.map.polyline(lane)
        d = p[-1] - p[-2]
        return float(math.atan2(d[1], d[0]))

    flow: VehicleFlow | None = None

    def on_activate(self, snap: Snapshot) -> None:
        background = self.background
        if background is not None:
            background.clear_junction(self.junction)
            if self.side == "opposite":
                background.opposite_traffic(False)
        if not self.signalized:  # upstream: stopEntries for the non-signalized turns only
            self.stop_entries(self.junction)
        else:
            self.hold_at(self.junction)  # its forced reds
        if self.prefill and self.flow is not None:
            self.flow.prefill()
        self.light_phase = -1

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        if self.flow is not None:
            self.flow.update(snap)
        if self.signalized:
            k = red_then_green_stage(self.time - self.activated_at)
            if k != self.light_phase:
                lights = self.world.lights
                lights.force_lanes(approach_lanes(self.map, self.flow_lane), "G", others="r")
                lights.force_lanes(approach_lanes(self.map, self.ego_lane), "r" if k == 0 else "G")
                self.light_phase = k
        self.passed |= self.ego_driven(progress) >= self.goal
        return self.ego_passed()

    def on_end(self) -> None:
        if self.flow is not None:
            self.flow.stop()
        if self.side == "opposite" and self.background is not None:
            self.background.opposite_traffic(True)
        if self.signalized:
            self.world.lights.release()


class NonSignalizedJunctionLeftTurn(JunctionTurnFlow):
    """#20: turn left across oncoming straight traffic at an unsignalized junction."""

    type_name = "NonSignalizedJunctionLeftTurn"


class NonSignalizedJunctionLeftTurnEnterFlow(JunctionTurnFlow):
    """#21: turn left into the road that oncoming right-turning traffic enters."""

    type_name = "NonSignalizedJunctionLeftTurnEnterFlow"
    flow_exit = RIGHT


class NonSignalizedJunctionRightTurn(JunctionTurnFlow):
    """#22: turn right into traffic coming straight from the left."""

    type_name = "NonSignalizedJunctionRightTurn"
    turn, side = "right", "left"
    source_factor, sink_factor = 5.0, 3.0
    prefill = True


class SignalizedJunctionLeftTurn(NonSignalizedJunctionLeftTurn):
    """#32: #20 at a traffic light (5 s red for CAV 0, then a permissive green)."""

    type_name = "SignalizedJunctionLeftTurn"
    signalized = True


class SignalizedJunctionLeftTurnEnterFlow(NonSignalizedJunctionLeftTurnEnterFlow):
    """#33: #21 at a traffic light."""

    type_name = "SignalizedJunctionLeftTurnEnterFlow"
    signalized = True


class SignalizedJunctionRightTurn(NonSignalizedJunctionRightTurn):
    """#34: #22 at a traffic light (right on green while the flow also has green)."""

    type_name = "SignalizedJunctionRightTurn"
    signalized = True
