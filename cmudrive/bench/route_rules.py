"""Placement rules of a benchmark route: what a scenario's upstream intent needs beyond "it can run".

``cmudrive routes check`` reports each broken rule by route and rule name after the checks that decide
whether a route can run at all (``route_check``); a route that breaks a rule still runs. The rules hold
for Bench2Drive's own routes and are what our generated sets (``cmudrive220``, ``cmudrive44``,
``training``) must meet:

=====================  ==============================================================================
rule                   a route breaks it when
=====================  ==============================================================================
route-reaches-end      CAV 0's route ends before it can meet the scenario's own end (past the
                       obstacle's end point E, 10 m past the junction, at the flow's sink, past the
                       invading flow's source, out of the parking slot): the scenario could only time out
                       or end with the route (drive counters, which Bench2Drive's routes also outlast,
                       and the crossers', cut-ins' and emergency vehicle's ends are not checked)
cav-clear-of-actors    a CAV's box at its start comes within ``CLEARANCE`` of the box of an actor the
                       scenario places (its queue, its parked or crashed cars, its walkers, props): it
                       would start inside or against it
junction-free-invading InvadingTurn: CAV 0's route crosses a junction between T and the flow's source
                       S (upstream's layout is one road: the invading cars would run through the
                       junction to CAV 0's stop line)
highway-merge          HighwayCutIn: the car does not come from an on-ramp into CAV 0's lane: its lane
                       reaches CAV 0's road through a signalised junction, CAV 0 enters the merge on a
                       minor link or on a road no wider than the car's (CAV 0 is the one on the
                       ramp), the lane on the left of the car's lane where it starts its lane change
                       is not on CAV 0's route, or CAV 0's route ends less than ``MERGE_ROOM`` past
                       that point (upstream removes the ramp's entry and extends the road's exit by
                       170 m: the cut-in happens in front of the ego, on a highway)
parking-slot           ParkingExit: the slot is not on a parking lane at least ``PARKING_WIDTH`` wide
                       (a 0.3-0.5 m shoulder of CARLA's towns leaves CAV 0 and both parked cars
                       sticking a metre into the driving lane; upstream's routes use Town03's 3.5 m
                       parking lanes)
=====================  ==============================================================================

Bench2Drive's own Town01-07 routes (``bench2drive220.xml`` imported with ``--cavs 4``) break none of them
except where our four added CAVs start against a scenario actor.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cmudrive.bench.scenarios.plan import PlanPoint
from cmudrive.maps import RoadMap, Route
from cmudrive.maps.model import LaneKind

if TYPE_CHECKING:
    from cmudrive.bench.scenarios.base import Scenario
    from cmudrive.bench.scenarios.cutins import HighwayCutIn

CLEARANCE = 0.5  # [m] between a CAV's box at its start and a placed actor's box
MERGE_ROOM = 80.0  # [m] of CAV 0's route past the cut-in car's lane-change start (highway-merge)
PARKING_WIDTH = 2.0  # [m] the narrowest parking lane a ParkingExit slot may use (parking-slot)
MARKERS = frozenset({"light", "patch", "slot"})  # plan points that are not actors


@dataclass(frozen=True)
class RuleViolation:
    rule: str
    message: str


def rule_violations(routes: list[Route], placed: Sequence[Scenario]) -> list[RuleViolation]:
    """The rules a route breaks, given its CAVs' dense routes and its scenarios as placed
    (``route_check.build_placed``)."""
    from cmudrive.bench.scenarios.cutins import HighwayCutIn
    from cmudrive.bench.scenarios.invading import InvadingTurn
    from cmudrive.bench.scenarios.parking import ParkingExit

    out: list[RuleViolation] = []
    ego = routes[0]
    for sc in placed:
        name = sc.spec.name
        short = _short_of_end(sc, ego)
        if short is not None:
            out.append(RuleViolation("route-reaches-end", f"scenario {name!r}: CAV 0's route {short}"))
        out += _starts_against_actors(sc, routes)
        if isinstance(sc, InvadingTurn):
            k0 = sc.trigger_index
            ks = k0 + int(np.argmin(np.linalg.norm(ego.xy[k0:] - sc.s_xy, axis=1)))
            lanes = ego.lane[k0 : ks + 1]
            inside = ego.in_junction[k0 : ks + 1] & ~sc.map.junction_is_join[sc.map.lane_junction[lanes]]
            if bool(np.any(inside)):
                message = "CAV 0's route crosses a junction between the trigger point and the flow's source"
                out.append(RuleViolation("junction-free-invading", f"scenario {name!r}: {message}"))
        if isinstance(sc, ParkingExit):
            kind, width = LaneKind(int(sc.map.lane_kind[sc.side])), float(sc.map.lane_width[sc.side])
            if kind != LaneKind.PARKING or width < PARKING_WIDTH:
                message = (
                    f"the slot is on a {width:.1f} m {kind.name.lower()} lane (a parking lane at least "
                    f"{PARKING_WIDTH:g} m wide is needed)"
                )
                out.append(RuleViolation("parking-slot", f"scenario {name!r}: {message}"))
        if isinstance(sc, HighwayCutIn):
            problem = _not_a_merge(sc, ego)
            if problem is not None:
                out.append(RuleViolation("highway-merge", f"scenario {name!r}: {problem}"))
    return out


def _not_a_merge(sc: HighwayCutIn, ego: Route) -> str | None:
    """Why HighwayCutIn's car does not merge from a ramp into CAV 0's lane in front of it, or None."""
    from cmudrive.bench.scenarios.base import first_real_junction
    from cmudrive.bench.scenarios.placement import neighbour, point_xy

    m = sc.map
    lane, seen = sc.start.lane, 0
    while seen < 100:  # the car's lane that enters its first junction
        succ = m.successors(lane)
        if len(succ) == 0 or m.lane_internal[int(succ[0])]:
            break
        lane, seen = int(succ[0]), seen + 1
    car_links = np.flatnonzero(m.link_from == lane)
    if bool(np.any(m.link_tls[car_links] >= 0)):
        return "the car reaches CAV 0's road through a signalised junction, not an on-ramp"
    first = first_real_junction(m, ego, sc.trigger_index)
    if first > 0:
        before, via = int(ego.lane[first - 1]), int(ego.lane[first])
        ego_links = np.flatnonzero((m.link_from == before) & (m.link_via == via))
        if len(ego_links) and not all(str(m.link_state[x]) == "M" for x in ego_links):
            return "CAV 0 enters the merge on a minor link: it is the one on the ramp, not the car"
        if _driving_lanes(m, lane) >= _driving_lanes(m, before):
            return "the car's road is as wide as CAV 0's: it is no on-ramp"
    target = neighbour(m, sc.merge_at.lane, "left")
    if target < 0 or target not in {int(x) for x in ego.path}:
        return "the car's lane change does not lead into CAV 0's lane (its left lane is not on CAV 0's route)"
    at = point_xy(m, sc.merge_at)
    k = int(np.argmin(np.linalg.norm(ego.xy - at, axis=1)))
    room = float(ego.distance[-1] - ego.distance[k])
    if room < MERGE_ROOM:
        return f"CAV 0's route ends {room:.0f} m past the car's lane-change start (at least {MERGE_ROOM:g} m)"
    return None


def _driving_lanes(m: RoadMap, lane: int) -> int:
    """Driving lanes of ``lane``'s edge."""
    return int(np.sum((m.lane_edge == m.lane_edge[lane]) & m.driving))


def _short_of_end(sc: Scenario, ego: Route) -> str | None:
    """How CAV 0's route falls short of the scenario's own end, or None when it reaches it."""
    from cmudrive.bench.scenarios.actorflows import SINK_REACHED, ActorFlowScenario
    from cmudrive.bench.scenarios.behaviours import ahead_of
    from cmudrive.bench.scenarios.invading import PAST_NEAR, InvadingTurn
    from cmudrive.bench.scenarios.junctions import RouteRule
    from cmudrive.bench.scenarios.obstacles import LaneObstacle

    length = float(ego.distance[-1])
    if isinstance(sc, LaneObstacle):
        if not ahead_of(ego.xy, sc.end_xy, sc.end_heading).any():
            gap = float(np.min(np.linalg.norm(ego.xy - sc.end_xy, axis=1)))
            return f"ends {gap:.0f} m short of the end point E, 50 m past the last obstacle"
        return None
    if isinstance(sc, InvadingTurn):
        past = ahead_of(ego.xy, sc.s_xy, sc.s_heading)
        if not np.any(past & (np.linalg.norm(ego.xy - sc.s_xy, axis=1) < PAST_NEAR)):
            return "never gets past the invading flow's source S"
        return None
    if isinstance(sc, ActorFlowScenario) and sc.end_at_sink:
        rel = ego.xy[:, None, :] - sc.sinks[None]  # (n, k, 2)
        if not np.any(np.linalg.norm(rel, axis=2) < SINK_REACHED + 3.5):
            return "never reaches the flow's sink"
        return None
    if isinstance(sc, RouteRule) and sc.counter is not None:
        return None  # a drive counter: Bench2Drive's routes end before theirs too
    goal = getattr(sc, "goal", None)
    if isinstance(goal, float) and goal > length:
        return f"ends {goal - length:.0f} m before the scenario's end ({goal:.0f} m along it)"
    return None


def _starts_against_actors(sc: Scenario, routes: list[Route]) -> list[RuleViolation]:
    """A violation per CAV whose box at its start comes within CLEARANCE of a placed actor's box."""
    from cmudrive.bench.scenarios.parking import ParkingExit
    from cmudrive.bench.scenarios.placement import point_xy
    from cmudrive.sim.actor_types import ACTOR_TYPES
    from cmudrive.sim.collisions import pair_penetration

    points = [p for p in sc.plan() if isinstance(p, PlanPoint) and p.kind in ACTOR_TYPES]
    if isinstance(sc, ParkingExit):  # the car drawn at T drives off from beside CAV 0's slot
        at_t = point_xy(sc.map, sc.t_wp)
        points = [p for p in points if p.kind != "car" or not np.allclose(p.xy, at_t)]
    if not points:
        return []
    cav = ACTOR_TYPES["cav"]
    out = []
    for i, r in enumerate(routes):
        xy, yaw = r.xy[0], float(r.heading[0])
        if i == 0 and isinstance(sc, ParkingExit):
            xy, yaw = sc.slot_pose
        half = (0.5 * cav.length + CLEARANCE, 0.5 * cav.width + CLEARANCE)  # the CAV's box, grown
        a = np.array([[xy[0], xy[1], np.cos(yaw), np.sin(yaw), *half]])
        boxes = np.array(
            [
                [p.xy[0], p.xy[1], np.cos(p.yaw), np.sin(p.yaw), 0.5 * ACTOR_TYPES[p.kind].length,
                 0.5 * ACTOR_TYPES[p.kind].width]
                for p in points
            ]
        )  # fmt: skip
        overlap = pair_penetration(np.repeat(a, len(points), axis=0), boxes)
        if np.any(overlap > 0.0):
            p = points[int(np.argmax(overlap))]
            gap = float(np.linalg.norm(xy - p.xy))
            out.append(
                RuleViolation(
                    "cav-clear-of-actors",
                    f"scenario {sc.spec.name!r}: CAV {i} starts against its {p.kind} ({gap:.1f} m centre "
                    f"to centre, boxes less than {CLEARANCE:g} m apart)",
                )
            )
    return out


__all__ = ["CLEARANCE", "MERGE_ROOM", "PARKING_WIDTH", "RuleViolation", "rule_violations"]
