"""Flow and actor locations of the generated routes, derived from the junction CAV 0 drives through.

Each placer takes the map, CAV 0's dense route, the trigger's route index and a random stream, and
returns the type's location parameters (CARLA-frame ``{"x", "y", "z"}`` strings) or None when the
junction has no place for them. The scenario class then checks them as the evaluator would.

* EnterActorFlow, MergerIntoSlowTraffic(V2): another entry of the junction with a connection onto CAV
  0's exit road; source 30-40 m up it, sink 35-60 m down CAV 0's exit lane.
* HighwayCutIn: an entry of another road (the ramp) whose link leads onto the lane right of CAV 0's exit
  lane, so that the car's lane change to the left ends in CAV 0's lane; the car 25-40 m up it,
  ``end_location`` 80 m down CAV 0's exit lane.
* HighwayExit: the lane left of CAV 0's at T; source 26-29 m behind T, sink 100 m ahead on a lane
  CAV 0 does not take.
* InterurbanActorFlow: as HighwayExit, else the opposite approach's straight lane (source 40 m up,
  sink 60 m past the junction).
* InterurbanAdvancedActorFlow: the oncoming lane of CAV 0's exit road (it enters the junction); source
  30-45 m up it, sink 50-80 m past its straight exit.
* CrossingBicycleFlow: a bike lane entering the junction from another approach (the one most opposite
  CAV 0's first); source 20-40 m up it, end 40 m past its exit.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from cmudrive.bench.scenarios.base import first_real_junction
from cmudrive.bench.scenarios.placement import LanePoint, point_xy, walk
from cmudrive.maps import RoadMap, Route
from cmudrive.maps.coords import map_to_carla
from cmudrive.maps.model import LaneKind, TurnDir

Params = dict[str, str | dict[str, str]]
Placer = Callable[[RoadMap, Route, int, np.random.Generator], Params | None]


def junction_links(m: RoadMap, junction: int, kind: int = LaneKind.DRIVING) -> np.ndarray:
    """(k, 3) int: (from lane, to lane, TurnDir) of the links through ``junction`` between normal lanes
    of ``kind``."""
    f, t = m.link_from, m.link_to
    ok = (
        (m.link_junction == junction)
        & ~m.lane_internal[f]
        & ~m.lane_internal[t]
        & (m.lane_kind[f] == kind)
        & (m.lane_kind[t] == kind)
    )
    return np.column_stack([f[ok], t[ok], m.link_dir[ok]]).astype(np.int64)


def first_junction(m: RoadMap, route: Route, k0: int) -> tuple[int, int, int] | None:
    """(junction, route index of the last point before it, first index after it) of CAV 0's first
    junction past route index ``k0`` (road joins passed over, as the scenarios do:
    ``first_real_junction``); None without one."""
    first = first_real_junction(m, route, k0)
    if first <= 0:
        return None
    after = np.flatnonzero(~route.in_junction[first:]) + first
    if len(after) == 0:
        return None
    return int(m.lane_junction[route.lane[first]]), first - 1, int(after[0])


def _xyz(m: RoadMap, p: LanePoint) -> dict[str, str]:
    c = map_to_carla(point_xy(m, p)[None])[0]
    return {"x": f"{round(float(c[0]), 2) + 0.0!r}", "y": f"{round(float(c[1]), 2) + 0.0!r}", "z": "0.0"}


def _up(m: RoadMap, lane: int, d: float) -> LanePoint:
    """``d`` m before the end of ``lane`` (walking back over the lanes before it, not past a junction)."""
    return walk(m, LanePoint(lane, float(m.lane_length[lane])), -d, through_junctions=False)


def _down(m: RoadMap, lane: int, d: float) -> LanePoint:
    return walk(m, LanePoint(lane, 0.0), d, through_junctions=False)


def _joining(m: RoadMap, route: Route, k0: int, rng: np.random.Generator) -> tuple[int, int] | None:
    """(entry lane of another approach with a link onto CAV 0's exit road, CAV 0's exit lane)."""
    j = first_junction(m, route, k0)
    if j is None:
        return None
    junction, before, after = j
    entry, exit_ = int(route.lane[before]), int(route.lane[after])
    links = junction_links(m, junction)
    ok = (m.lane_edge[links[:, 1]] == m.lane_edge[exit_]) & (m.lane_edge[links[:, 0]] != m.lane_edge[entry])
    if not np.any(ok):
        return None
    pick = links[ok][int(rng.integers(int(ok.sum())))]
    return int(pick[0]), exit_


def enter_flow(m: RoadMap, route: Route, k0: int, rng: np.random.Generator) -> Params | None:
    pair = _joining(m, route, k0, rng)
    if pair is None:
        return None
    src = _up(m, pair[0], float(rng.uniform(30.0, 40.0)))
    sink = _down(m, pair[1], float(rng.uniform(35.0, 60.0)))
    return {"start_actor_flow": _xyz(m, src), "end_actor_flow": _xyz(m, sink)}


def highway_cut_in(m: RoadMap, route: Route, k0: int, rng: np.random.Generator) -> Params | None:
    j = first_junction(m, route, k0)
    if j is None:
        return None
    junction, before, after = j
    entry, exit_ = int(route.lane[before]), int(route.lane[after])
    beside = int(m.lane_right[exit_])
    if beside < 0 or m.lane_kind[beside] != LaneKind.DRIVING:
        return None
    links = junction_links(m, junction)
    ramps = links[(links[:, 1] == beside) & (m.lane_edge[links[:, 0]] != m.lane_edge[entry])]
    if len(ramps) == 0:
        return None
    ramp = int(ramps[int(rng.integers(len(ramps))), 0])
    car = _up(m, ramp, float(rng.uniform(25.0, 40.0)))
    return {"other_actor_location": _xyz(m, car), "end_location": _xyz(m, _down(m, exit_, 80.0))}


def _left_lane_flow(m: RoadMap, route: Route, k0: int, rng: np.random.Generator) -> Params | None:
    left = int(m.lane_left[route.lane[k0]])
    if left < 0 or m.lane_kind[left] != LaneKind.DRIVING:
        return None
    s, _ = m.index.project(route.xy[k0][None], np.array([left]))
    src = walk(m, LanePoint(left, float(s[0])), -float(rng.uniform(26.0, 29.0)), through_junctions=False)
    sink = walk(m, src, 100.0, through_junctions=True)
    if int(sink.lane) in set(route.path.tolist()) or m.lane_internal[sink.lane]:
        return None
    return {"start_actor_flow": _xyz(m, src), "end_actor_flow": _xyz(m, sink)}


def _opposite_straight(m: RoadMap, route: Route, k0: int) -> tuple[int, int] | None:
    """The straight link of the approach opposite CAV 0's entry into its first junction past T."""
    j = first_junction(m, route, k0)
    if j is None:
        return None
    junction, before, _ = j
    links = junction_links(m, junction)
    if len(links) == 0:
        return None
    ego = route.heading[before]
    ends = np.array([m.polyline(int(a))[-1] - m.polyline(int(a))[-2] for a in links[:, 0]])
    dot = np.cos(ego) * ends[:, 0] + np.sin(ego) * ends[:, 1]
    dot = dot / np.maximum(np.linalg.norm(ends, axis=1), 1e-9)
    ok = (dot < -math.cos(math.radians(35.0))) & (links[:, 2] == TurnDir.STRAIGHT)
    if not np.any(ok):
        return None
    pick = links[ok][0]
    return int(pick[0]), int(pick[1])


def interurban_flow(m: RoadMap, route: Route, k0: int, rng: np.random.Generator) -> Params | None:
    out = _left_lane_flow(m, route, k0, rng)
    if out is not None:
        return out
    link = _opposite_straight(m, route, k0)
    if link is None:
        return None
    return {
        "start_actor_flow": _xyz(m, _up(m, link[0], 40.0)),
        "end_actor_flow": _xyz(m, _down(m, link[1], 60.0)),
    }


def interurban_advanced_flow(m: RoadMap, route: Route, k0: int, rng: np.random.Generator) -> Params | None:
    j = first_junction(m, route, k0)
    if j is None:
        return None
    junction, _, after = j
    oncoming = int(m.lane_opposite[route.lane[after]])
    if oncoming < 0:
        return None
    links = junction_links(m, junction)
    ok = (links[:, 0] == oncoming) & (links[:, 2] == TurnDir.STRAIGHT)
    if not np.any(ok):
        return None
    to = int(links[ok][0, 1])
    src = _up(m, oncoming, float(rng.uniform(30.0, 45.0)))
    sink = _down(m, to, float(rng.uniform(50.0, 80.0)))
    return {"start_actor_flow": _xyz(m, src), "end_actor_flow": _xyz(m, sink)}


def bicycle_flow(m: RoadMap, route: Route, k0: int, rng: np.random.Generator) -> Params | None:
    j = first_junction(m, route, k0)
    if j is None:
        return None
    junction, before, _ = j
    links = junction_links(m, junction, LaneKind.BIKE)
    entry_edge = m.lane_edge[route.lane[before]]
    links = links[m.lane_edge[links[:, 0]] != entry_edge] if len(links) else links
    if len(links) == 0:
        return None
    ego = route.heading[before]
    ends = np.array([m.polyline(int(a))[-1] - m.polyline(int(a))[-2] for a in links[:, 0]])
    dot = (np.cos(ego) * ends[:, 0] + np.sin(ego) * ends[:, 1]) / np.maximum(
        np.linalg.norm(ends, axis=1), 1e-9
    )
    a, b = (int(x) for x in links[int(np.argmin(dot)), :2])
    src = LanePoint(a, max(float(m.lane_length[a]) - float(rng.uniform(20.0, 40.0)), 0.0))
    end = LanePoint(b, min(40.0, float(m.lane_length[b])))
    return {"start_actor_flow": _xyz(m, src), "end_actor_flow": _xyz(m, end)}


FLOW_PLACERS: dict[str, Placer] = {
    "EnterActorFlow": enter_flow,
    "MergerIntoSlowTraffic": enter_flow,
    "MergerIntoSlowTrafficV2": enter_flow,
    "HighwayCutIn": highway_cut_in,
    "HighwayExit": _left_lane_flow,
    "InterurbanActorFlow": interurban_flow,
    "InterurbanAdvancedActorFlow": interurban_advanced_flow,
    "CrossingBicycleFlow": bicycle_flow,
}

__all__ = ["FLOW_PLACERS", "first_junction", "junction_links"]
