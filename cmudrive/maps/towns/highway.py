"""Motorway with interchanges: two carriageways, exit and entry ramps, frontage roads, end junctions.

The motorway runs west to east between two at-grade end junctions ``W`` and ``E`` (where it slows to
the ``motorway_end`` speed). Eastbound traffic uses the southern carriageway and its ramps lead to a
frontage road south of it; westbound is the same layout turned by 180 degrees, with a northern frontage
road. The frontage roads bend into the end junctions, so the network is one planar loop (no bridges).

At each interchange (in travel direction): a deceleration lane opens on the right, the exit ramp leaves
from it at the gore, the entry ramp joins further on as a new right lane, which either ends as an
acceleration lane or (``auxiliary``) runs on to become the next exit's lane. All lane-to-lane
connections of the carriageways are explicit.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from cmudrive.maps.errors import MapError
from cmudrive.maps.towns.geometry import bezier
from cmudrive.maps.towns.graph import Edge, Node, RoadGraph
from cmudrive.maps.towns.roads import KMH, ROAD_KINDS

MIN_SECTION = 60.0  # [m] shortest carriageway section between two lane-count changes
CORNER_STEP = 8.0  # [m] point spacing of curved road shapes


@dataclass(frozen=True)
class Interchange:
    """A half-diamond interchange per direction, centred at a fraction of the motorway length."""

    at: float  # position of the centre, as a fraction of the motorway length from the west end
    terminal_control: str = "priority_stop"  # junction type where the ramps meet the frontage road


@dataclass(frozen=True)
class HighwaySpec:
    """A motorway between two end junctions with interchanges to frontage roads on both sides."""

    length: tuple[float, float]  # [m] range of the distance between the end junctions
    interchanges: tuple[Interchange, ...]
    speed_kmh: tuple[float, ...] = (100.0, 110.0, 120.0)  # choices of the motorway speed limit
    auxiliary: bool = True  # entry lanes run on to the next exit (else every entry lane ends)
    median: float = 3.0  # [m] between the carriageways
    frontage_offset: float = 260.0  # [m] from the motorway axis to the frontage roads
    ramp_spread: float = 330.0  # [m] from an interchange centre to its gore / merge point
    terminal_spread: float = 90.0  # [m] from an interchange centre to the ramp ends on the frontage road
    decel_length: float = 180.0  # [m] exit lane before the gore
    accel_length: float = 250.0  # [m] acceleration lane after the merge
    end_length: float = 300.0  # [m] 2-lane reduced-speed section next to each end junction
    end_control: str = "traffic_light"
    corner_radius: float = 90.0  # [m] where the frontage road turns towards an end junction
    jitter: float = 0.02  # largest random shift of an interchange centre, as a fraction of the length

    def build(self, rng: np.random.Generator) -> RoadGraph:
        return build_highway(self, rng)


Transform = Callable[[float, float], tuple[float, float]]


@dataclass(frozen=True)
class _Half:
    """One travel direction, built in a frame where it runs along +x with its ramps on the south side."""

    road: str  # carriageway node prefix
    side: str  # frontage node prefix
    start: str  # end junction at frame x = 0
    finish: str  # end junction at frame x = length
    to_world: Transform


def _stations(spec: HighwaySpec, length: float, centres: list[float]) -> list[tuple[float, str, int]]:
    """Carriageway nodes along the frame x axis as (x, tag, interchange number)."""
    g, d, a = spec.ramp_spread, spec.decel_length, spec.accel_length
    out: list[tuple[float, str, int]] = [(0.0, "start", 0), (spec.end_length, "fast", 0)]
    for k, c in enumerate(centres):
        if k == 0 or not spec.auxiliary:
            out.append((c - g - d, "decel", k))
        out += [(c - g, "gore", k), (c + g, "merge", k)]
        if k == len(centres) - 1 or not spec.auxiliary:
            out.append((c + g + a, "accel", k))
    out += [(length - spec.end_length, "slow", 0), (length, "finish", 0)]
    xs = [x for x, _, _ in out]
    if any(b - a_ < MIN_SECTION for a_, b in itertools.pairwise(xs)):
        raise MapError(f"motorway too short for its interchanges: stations at {[round(x) for x in xs]} m")
    return out


def _carriageway(
    graph: RoadGraph, spec: HighwaySpec, half: _Half, stations: list[tuple[float, str, int]], speed: float
) -> dict[tuple[str, int], tuple[str, str]]:
    """Add the carriageway of one direction; returns (node id, carriageway edge there) of each gore
    (the edge arriving) and merge (the edge leaving), keyed by (tag, interchange number)."""
    y = -spec.median / 2
    ids: list[str] = []
    for x, tag, k in stations:
        if tag in ("start", "finish"):
            ids.append(half.start if tag == "start" else half.finish)
            continue
        node_id = f"{half.road}_{tag}{k + 1}" if tag not in ("fast", "slow") else f"{half.road}_{tag}"
        graph.add_node(Node(node_id, *half.to_world(x, y)))
        ids.append(node_id)
    edges: list[Edge] = []
    for i in range(len(stations) - 1):
        tag = stations[i][1]
        end_section = i in (0, len(stations) - 2)
        kind = ROAD_KINDS["motorway_end"] if end_section else ROAD_KINDS["motorway"]
        extra = int(tag in ("decel", "merge"))
        lanes = kind.cross_section(extra_right=extra)
        if tag == "merge" and stations[i + 1][1] == "accel":
            lanes = (replace(lanes[0], acceleration=True), *lanes[1:])
        v = kind.speed if end_section else speed
        edges.append(graph.add_edge(Edge(f"{ids[i]}-{ids[i + 1]}", ids[i], ids[i + 1], kind, lanes, v)))
    for i in range(1, len(stations) - 1):
        up, down = edges[i - 1], edges[i]
        n_up, n_down = len(up.lanes), len(down.lanes)
        if stations[i][1] == "merge":  # the entry ramp takes the new right lane
            graph.link(up.id, down.id, [(j, j + 1) for j in range(n_up)])
        elif n_down == n_up + 1:  # a lane opens on the right
            graph.link(up.id, down.id, [(0, 0)] + [(j, j + 1) for j in range(n_up)])
        elif n_down == n_up - 1:  # the right lane ends (or leaves as the exit ramp)
            graph.link(up.id, down.id, [(j + 1, j) for j in range(n_down)])
    ramp_points: dict[tuple[str, int], tuple[str, str]] = {}
    for i, (_, tag, k) in enumerate(stations):
        if tag == "gore":
            ramp_points[tag, k] = (ids[i], edges[i - 1].id)
        elif tag == "merge":
            ramp_points[tag, k] = (ids[i], edges[i].id)
    return ramp_points


def _half(
    graph: RoadGraph,
    spec: HighwaySpec,
    half: _Half,
    length: float,
    interchanges: list[tuple[float, str]],
    speed: float,
) -> None:
    """Carriageway, ramps and frontage road of one direction; ``interchanges`` are (frame x of the
    centre, ramp terminal control) in travel order."""
    centres = [c for c, _ in interchanges]
    stations = _stations(spec, length, centres)
    ramp_points = _carriageway(graph, spec, half, stations, speed)
    f, t, g = spec.frontage_offset, spec.terminal_spread, spec.ramp_spread
    y_ramp = -spec.median / 2 - ROAD_KINDS["motorway"].lanes * ROAD_KINDS["motorway"].lane_width
    ramp = ROAD_KINDS["ramp"]
    frontage_nodes = [half.start]
    for k, (c, control) in enumerate(interchanges):
        exit_t = graph.add_node(Node(f"{half.side}_exit{k + 1}", *half.to_world(c - t, -f), control=control))
        entry_t = graph.add_node(
            Node(f"{half.side}_entry{k + 1}", *half.to_world(c + t, -f), control=control)
        )
        frontage_nodes += [exit_t.id, entry_t.id]
        bend = 0.55 * (g - t), 0.55 * (f + y_ramp)
        off = bezier(
            np.array([c - g, y_ramp]),
            np.array([c - g + bend[0], y_ramp]),
            np.array([c - t, -f + bend[1]]),
            np.array([c - t, -f]),
            CORNER_STEP,
        )
        on = bezier(
            np.array([c + t, -f]),
            np.array([c + t, -f + bend[1]]),
            np.array([c + g - bend[0], y_ramp]),
            np.array([c + g, y_ramp]),
            CORNER_STEP,
        )
        (gore, before_gore), (merge, after_merge) = ramp_points["gore", k], ramp_points["merge", k]
        exit_ramp = graph.add_road(gore, exit_t.id, ramp, shape=[half.to_world(*p) for p in off])[0]
        entry_ramp = graph.add_road(entry_t.id, merge, ramp, shape=[half.to_world(*p) for p in on])[0]
        graph.link(before_gore, exit_ramp.id, [(0, 0)])  # the exit lane leaves as the ramp
        graph.link(entry_ramp.id, after_merge, [(0, 0)])  # the ramp becomes the new right lane
    frontage_nodes.append(half.finish)
    _frontage(graph, spec, half, length, frontage_nodes)


def _arc(cx: float, cy: float, r: float, a0: float, a1: float) -> list[tuple[float, float]]:
    """Points of a circular arc from angle a0 to a1 [deg] around (cx, cy)."""
    n = max(3, int(np.ceil(r * np.radians(abs(a1 - a0)) / CORNER_STEP)) + 1)
    ang = np.radians(np.linspace(a0, a1, n))
    return [(cx + r * float(np.cos(t)), cy + r * float(np.sin(t))) for t in ang]


def _frontage(graph: RoadGraph, spec: HighwaySpec, half: _Half, length: float, nodes: list[str]) -> None:
    """Two-way frontage road in the frame: from the start junction down to y = -f, east through the
    ramp terminals, and up into the finish junction, with quarter-circle corners."""
    kind = ROAD_KINDS["frontage"]
    f, r = spec.frontage_offset, spec.corner_radius
    name = "South Frontage Road" if half.side == "S" else "North Frontage Road"
    for i, (a, b) in enumerate(itertools.pairwise(nodes)):
        pa = (graph.nodes[a].x, graph.nodes[a].y)
        pb = (graph.nodes[b].x, graph.nodes[b].y)
        frame: list[tuple[float, float]] = []
        if i == 0:
            frame += [(0.0, 0.0), *_arc(r, -f + r, r, 180.0, 270.0)]
        if i == len(nodes) - 2:
            frame += [*_arc(length - r, -f + r, r, 270.0, 360.0), (length, 0.0)]
        inner = [half.to_world(x, y) for x, y in frame if (x, y) != (0.0, 0.0) and (x, y) != (length, 0.0)]
        shape = [pa, *inner, pb] if inner else []
        graph.add_road(a, b, kind, shape=shape, name=name)


def build_highway(spec: HighwaySpec, rng: np.random.Generator) -> RoadGraph:
    """Build the road graph of a motorway town."""
    length = float(rng.uniform(*spec.length))
    speed = float(rng.choice(np.array(spec.speed_kmh))) * KMH
    east = sorted(
        ((ic.at + float(rng.uniform(-spec.jitter, spec.jitter))) * length, ic.terminal_control)
        for ic in spec.interchanges
    )
    west = [(length - c, control) for c, control in reversed(east)]
    graph = RoadGraph()
    graph.add_node(Node("W", 0.0, 0.0, control=spec.end_control))
    graph.add_node(Node("E", length, 0.0, control=spec.end_control))
    eastbound = _Half("EB", "S", "W", "E", lambda x, y: (x, y))
    westbound = _Half("WB", "N", "E", "W", lambda x, y: (length - x, -y))
    _half(graph, spec, eastbound, length, east, speed)
    _half(graph, spec, westbound, length, west, speed)
    return graph
