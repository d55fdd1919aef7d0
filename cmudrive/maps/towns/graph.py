"""The road graph a town layout builds: junction nodes, directed edges with lanes, explicit lane links.

This is the in-memory form of SUMO's plain XML (``plain.py`` writes it). Coordinates are SUMO's frame:
x east, y north, metres. An edge is one direction of travel; netconvert spreads its lanes to the right
of the edge line, so the two directions of a two-way road share their centre line.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from cmudrive.maps.errors import MapError
from cmudrive.maps.towns.geometry import offset
from cmudrive.maps.towns.roads import Lane, RoadKind

Point = tuple[float, float]  # (x, y) [m]

# SUMO junction types used by the towns (netconvert plain-XML node ``type``).
CONTROLS = ("traffic_light", "priority", "priority_stop", "allway_stop", "right_before_left")


@dataclass(frozen=True)
class Node:
    """A junction (or a point where an edge's lane count changes)."""

    id: str
    x: float  # [m]
    y: float  # [m]
    control: str = "priority"  # SUMO junction type, one of CONTROLS


@dataclass(frozen=True)
class Edge:
    """One direction of a road between two nodes."""

    id: str
    src: str
    dst: str
    kind: RoadKind
    lanes: tuple[Lane, ...]  # kerb (index 0) to centre line
    speed: float  # [m/s]
    shape: tuple[Point, ...] = ()  # full polyline from src to dst; () = straight
    name: str = ""

    @property
    def drive_lanes(self) -> list[int]:
        """SUMO indices of the driving lanes."""
        return [i for i, lane in enumerate(self.lanes) if lane.kind == "drive"]


@dataclass(frozen=True)
class LaneLink:
    """An explicit lane-to-lane connection; netconvert then guesses none for ``src_edge``."""

    src_edge: str
    dst_edge: str
    src_lane: int
    dst_lane: int


@dataclass
class RoadGraph:
    """Nodes, edges and explicit lane links of one town, in insertion order (which fixes the output)."""

    nodes: dict[str, Node] = field(default_factory=dict)
    edges: dict[str, Edge] = field(default_factory=dict)
    links: list[LaneLink] = field(default_factory=list)

    def add_node(self, node: Node) -> Node:
        if node.id in self.nodes:
            raise MapError(f"duplicate node id {node.id!r}")
        if node.control not in CONTROLS:
            raise MapError(f"node {node.id!r}: unknown junction type {node.control!r}; valid: {CONTROLS}")
        self.nodes[node.id] = node
        return node

    def add_edge(self, edge: Edge) -> Edge:
        if edge.id in self.edges:
            raise MapError(f"duplicate edge id {edge.id!r}")
        for end in (edge.src, edge.dst):
            if end not in self.nodes:
                raise MapError(f"edge {edge.id!r} refers to unknown node {end!r}")
        self.edges[edge.id] = edge
        return edge

    def add_road(
        self,
        src: str,
        dst: str,
        kind: RoadKind,
        shape: Sequence[Point] = (),
        name: str = "",
        speed: float | None = None,
    ) -> list[Edge]:
        """Add a road: edge ``src->dst`` and ``dst->src`` (for one-way kinds: only its left sidewalk)."""
        lanes = kind.cross_section()
        v = kind.speed if speed is None else speed
        pts = [(float(x), float(y)) for x, y in shape]
        back = pts[::-1]
        if kind.median > 0:  # each direction's edge line sits half a median right of the road centre
            if not pts:
                pts = [(self.nodes[src].x, self.nodes[src].y), (self.nodes[dst].x, self.nodes[dst].y)]
            line = np.array(pts)
            pts = _tuples(offset(line, -kind.median / 2))
            back = _tuples(offset(line[::-1], -kind.median / 2))
        out = [self.add_edge(Edge(f"{src}-{dst}", src, dst, kind, lanes, v, tuple(pts), name))]
        if not kind.oneway:
            out.append(self.add_edge(Edge(f"{dst}-{src}", dst, src, kind, lanes, v, tuple(back), name)))
        elif kind.sidewalk > 0:  # the left sidewalk of a one-way road: a pedestrian-only reverse edge
            walk = (Lane("sidewalk", kind.sidewalk),)
            out.append(self.add_edge(Edge(f"{dst}-{src}", dst, src, kind, walk, v, tuple(back), name)))
        return out

    def link(self, src_edge: str, dst_edge: str, pairs: Iterable[tuple[int, int]]) -> None:
        """Add explicit lane links ``(src_lane, dst_lane)`` between two edges."""
        for a, b in pairs:
            self.links.append(LaneLink(src_edge, dst_edge, a, b))

    def legs(self, node_id: str) -> set[str]:
        """Neighbouring node ids (one per road leg, whatever its direction)."""
        out = {e.dst for e in self.edges.values() if e.src == node_id}
        return out | {e.src for e in self.edges.values() if e.dst == node_id}

    def strongly_connected(self) -> bool:
        """True when every node reaches every other node along edges with driving lanes."""
        roads = [e for e in self.edges.values() if e.drive_lanes]
        return set(self.nodes) <= {e.src for e in roads} and strongly_connected((e.src, e.dst) for e in roads)

    def check(self, name: str) -> None:
        """Raise MapError if the graph has isolated nodes or is not strongly connected."""
        used = {e.src for e in self.edges.values()} | {e.dst for e in self.edges.values()}
        lonely = sorted(set(self.nodes) - used)
        if lonely:
            raise MapError(f"town {name!r}: nodes without edges: {lonely[:5]}")
        if not self.strongly_connected():
            raise MapError(f"town {name!r}: road graph is not strongly connected")


def _tuples(poly: np.ndarray) -> list[Point]:
    return [(float(x), float(y)) for x, y in poly]


def strongly_connected(arcs: Iterable[tuple[Hashable, Hashable]]) -> bool:
    """True when every vertex of the directed graph given by ``arcs`` reaches every other vertex."""
    fwd: dict[Hashable, list[Hashable]] = {}
    bwd: dict[Hashable, list[Hashable]] = {}
    for a, b in arcs:
        fwd.setdefault(a, []).append(b)
        bwd.setdefault(b, []).append(a)
        fwd.setdefault(b, [])
        bwd.setdefault(a, [])
    if not fwd:
        return True
    start = next(iter(fwd))
    return _reach(start, fwd) == set(fwd) == _reach(start, bwd)


def _reach(start: Hashable, adj: dict[Hashable, list[Hashable]]) -> set[Hashable]:
    seen = {start}
    stack = [start]
    while stack:
        for nxt in adj[stack.pop()]:
            if nxt not in seen:
                seen.add(nxt)
                stack.append(nxt)
    return seen
