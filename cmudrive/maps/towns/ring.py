"""Interurban network: a ring road with country roads (chords) across it.

The ring is a wobbly ellipse; each chord joins two points of the ring along a smooth curve whose end
headings can be turned, so that it meets the ring at an oblique angle; chords cross each other at
junctions of their own. The seed varies the ring's shape and the chord ends.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from cmudrive.maps.errors import MapError
from cmudrive.maps.towns.geometry import arc_length, bezier, cut, segment_intersections
from cmudrive.maps.towns.graph import Node, Point, RoadGraph
from cmudrive.maps.towns.roads import ROAD_KINDS

RING_STEP = 10.0  # [m] point spacing of the ring and chord shapes
MIN_JUNCTION_GAP = 80.0  # [m] shortest road between two junctions
CHORD_HANDLE = 0.3  # Bezier handle length of a chord, as a fraction of its straight length


@dataclass(frozen=True)
class Chord:
    """A country road between two points of the ring, given by their bearing from the ring centre."""

    start: float  # [deg] bearing of the first end, counter-clockwise from east
    end: float  # [deg] bearing of the second end
    name: str
    kind: str = "country"
    turn_start: float = 0.0  # [deg] heading at the first end, relative to the straight line (ccw +)
    turn_end: float = 0.0  # [deg] same at the second end; unequal turns make the road meet the ring obliquely
    control: str = "priority_stop"  # junction type where the chord meets the ring


@dataclass(frozen=True)
class RingSpec:
    """A ring road (two-way) with chords; all junctions at grade."""

    radius: tuple[float, float]  # [m] semi-axes of the ring (east-west, north-south)
    chords: tuple[Chord, ...]
    ring_kind: str = "interurban"
    ring_name: str = "Ring Road"
    crossing_control: str = "priority"  # junction type where two chords cross
    wobble: float = 0.06  # relative amplitude of the ring's low-frequency radius noise
    jitter_deg: float = 3.0  # [deg] largest random shift of a chord end

    def build(self, rng: np.random.Generator) -> RoadGraph:
        return build_ring(self, rng)


def _ring_point(spec: RingSpec, phases: np.ndarray, bearing_deg: np.ndarray) -> np.ndarray:
    t = np.radians(bearing_deg)
    rho = 1.0 + spec.wobble * (np.sin(2 * t + phases[0]) + np.sin(3 * t + phases[1])) / 2
    return np.stack([spec.radius[0] * rho * np.cos(t), spec.radius[1] * rho * np.sin(t)], axis=-1)


def _ring_edges(graph: RoadGraph, spec: RingSpec, phases: np.ndarray, ends: list[tuple[float, str]]) -> None:
    """Two-way ring road between consecutive junctions (bearings sorted counter-clockwise)."""
    kind = ROAD_KINDS[spec.ring_kind]
    perimeter = 2 * np.pi * max(spec.radius)
    step_deg = 360.0 * RING_STEP / perimeter
    for (b0, n0), (b1, n1) in zip(ends, ends[1:] + ends[:1], strict=True):
        stop = b1 if b1 > b0 else b1 + 360.0
        inner = np.arange(b0 + step_deg, stop - step_deg / 2, step_deg)
        pts = _ring_point(spec, phases, inner)
        shape: list[Point] = [(graph.nodes[n0].x, graph.nodes[n0].y)]
        shape += [(float(x), float(y)) for x, y in pts]
        shape.append((graph.nodes[n1].x, graph.nodes[n1].y))
        if arc_length(np.array(shape))[-1] < MIN_JUNCTION_GAP:
            raise MapError(f"ring road: junctions {n0} and {n1} closer than {MIN_JUNCTION_GAP:.0f} m")
        graph.add_road(n0, n1, kind, shape=shape, name=spec.ring_name)


def _rotate(v: np.ndarray, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _chord_line(a: np.ndarray, b: np.ndarray, chord: Chord) -> np.ndarray:
    """Cubic curve from a to b leaving and arriving at the chord's turned headings."""
    reach = CHORD_HANDLE * float(np.linalg.norm(b - a))
    d = (b - a) / np.linalg.norm(b - a)
    return bezier(
        a, a + reach * _rotate(d, chord.turn_start), b - reach * _rotate(d, chord.turn_end), b, RING_STEP
    )


def build_ring(spec: RingSpec, rng: np.random.Generator) -> RoadGraph:
    """Build the road graph of an interurban ring town."""
    phases = rng.uniform(0.0, 2 * np.pi, size=2)
    graph = RoadGraph()
    ends: list[tuple[float, str]] = []
    lines: list[np.ndarray] = []
    for k, chord in enumerate(spec.chords):
        pts = []
        for end, bearing in (("a", chord.start), ("b", chord.end)):
            b = (bearing + float(rng.uniform(-spec.jitter_deg, spec.jitter_deg))) % 360.0
            p = _ring_point(spec, phases, np.array(b))
            node = graph.add_node(Node(f"R{k + 1}{end}", float(p[0]), float(p[1]), control=chord.control))
            ends.append((b, node.id))
            pts.append(p)
        lines.append(_chord_line(pts[0], pts[1], chord))
    ends.sort()
    _ring_edges(graph, spec, phases, ends)

    # junctions where chords cross: arc positions along each chord
    cuts: list[list[tuple[float, str]]] = [[] for _ in spec.chords]
    for i in range(len(lines)):
        for j in range(i + 1, len(lines)):
            for si, sj, p in segment_intersections(lines[i], lines[j]):
                node_id = f"X{sum(len(c) for c in cuts) // 2 + 1}"
                node = graph.add_node(Node(node_id, float(p[0]), float(p[1]), control=spec.crossing_control))
                cuts[i].append((si, node.id))
                cuts[j].append((sj, node.id))
    for k, (chord, line) in enumerate(zip(spec.chords, lines, strict=True)):
        total = float(arc_length(line)[-1])
        stops = [(0.0, f"R{k + 1}a"), *sorted(cuts[k]), (total, f"R{k + 1}b")]
        for (s0, n0), (s1, n1) in itertools.pairwise(stops):
            if s1 - s0 < MIN_JUNCTION_GAP:
                raise MapError(f"chord {chord.name!r}: junctions {n0} and {n1} only {s1 - s0:.0f} m apart")
            piece = cut(line, s0, s1)
            shape = [(float(x), float(y)) for x, y in piece] if len(piece) > 2 else []
            graph.add_road(n0, n1, ROAD_KINDS[chord.kind], shape=shape, name=chord.name)
    return graph
