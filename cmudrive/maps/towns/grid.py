"""Grid of city blocks: north-south columns and east-west rows of streets, each of one road kind.

Junction controls follow the road hierarchy (a table from the ranks of the roads that meet to a SUMO
junction type). The seed varies the block sizes, moves interior junctions by a few metres and removes a
few low-rank street segments (turning 4-way junctions into T-junctions) while keeping every junction
reachable from every other. Arterials get a left-turn pocket before signalised junctions.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from cmudrive.maps.errors import MapError
from cmudrive.maps.towns.geometry import arc_length, cut, normals, offset
from cmudrive.maps.towns.graph import Edge, Node, RoadGraph, strongly_connected
from cmudrive.maps.towns.roads import ROAD_KINDS, RoadKind

MIN_POCKET_APPROACH = 40.0  # [m] straight road kept upstream of a left-turn pocket


@dataclass(frozen=True)
class Street:
    """One straight street of the grid."""

    kind: str  # key of ROAD_KINDS
    reverse: bool = False  # one-way kinds: traffic runs west (rows) or south (columns)
    name: str = ""


@dataclass(frozen=True)
class ControlRule:
    """Junction type where the highest-ranked road has rank ``major`` and the lowest ``minor``."""

    major: int
    minor: int
    control: str


@dataclass(frozen=True)
class GridSpec:
    """A rectangular grid of streets; columns run west to east, rows south to north."""

    columns: tuple[Street, ...]
    rows: tuple[Street, ...]
    block_x: tuple[float, float]  # [m] range of the distance between neighbouring columns
    block_y: tuple[float, float]  # [m] same between rows
    controls: tuple[ControlRule, ...]
    default_control: str = "priority"
    jitter: float = 0.0  # [m] largest random shift of an interior junction along each axis
    missing: int = 0  # street segments removed at random (each makes two T-junctions)
    missing_max_rank: int = 1  # only streets up to this rank lose segments

    def build(self, rng: np.random.Generator) -> RoadGraph:
        return build_grid(self, rng)


@dataclass(frozen=True)
class _Segment:
    a: tuple[int, int]  # grid index (column, row) of the west / south end
    b: tuple[int, int]
    street: Street
    line: tuple[str, int]  # ("column", i) or ("row", j): which street of the grid
    interior: bool  # not on the outer boundary


def _node_id(ij: tuple[int, int]) -> str:
    return f"J{ij[0]}_{ij[1]}"


def _kind(street: Street) -> RoadKind:
    try:
        return ROAD_KINDS[street.kind]
    except KeyError as exc:
        raise MapError(f"unknown road kind {street.kind!r}; valid: {sorted(ROAD_KINDS)}") from exc


def _segments(spec: GridSpec) -> list[_Segment]:
    nx, ny = len(spec.columns), len(spec.rows)
    segs = [
        _Segment((i, j), (i, j + 1), st, ("column", i), 0 < i < nx - 1)
        for i, st in enumerate(spec.columns)
        for j in range(ny - 1)
    ]
    segs += [
        _Segment((i, j), (i + 1, j), st, ("row", j), 0 < j < ny - 1)
        for j, st in enumerate(spec.rows)
        for i in range(nx - 1)
    ]
    return segs


def _arcs(segs: list[_Segment]) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    out = []
    for s in segs:
        kind = _kind(s.street)
        if not kind.oneway or not s.street.reverse:
            out.append((s.a, s.b))
        if not kind.oneway or s.street.reverse:
            out.append((s.b, s.a))
    return out


def _strongly_connected(segs: list[_Segment]) -> bool:
    return strongly_connected(_arcs(segs))


def _degree(segs: list[_Segment], ij: tuple[int, int]) -> int:
    return sum(ij in (s.a, s.b) for s in segs)


def _interior(spec: GridSpec, ij: tuple[int, int]) -> bool:
    return 0 < ij[0] < len(spec.columns) - 1 and 0 < ij[1] < len(spec.rows) - 1


def _pass_through(segs: list[_Segment], ij: tuple[int, int]) -> bool:
    """Two legs of one street meet here: a point on that street, not a junction."""
    meeting = [s for s in segs if ij in (s.a, s.b)]
    return len(meeting) == 2 and meeting[0].line == meeting[1].line


def _drop_segments(spec: GridSpec, segs: list[_Segment], rng: np.random.Generator) -> list[_Segment]:
    """Remove ``spec.missing`` interior low-rank segments; each end stays a junction of >= 3 legs or, on
    the boundary, becomes a plain point of the boundary street."""
    kept = list(segs)
    dropped = 0
    for k in rng.permutation(len(segs)):
        if dropped >= spec.missing:
            break
        s = segs[int(k)]
        if not s.interior or _kind(s.street).rank > spec.missing_max_rank:
            continue
        trial = [t for t in kept if t is not s]
        ends_ok = all(
            _degree(trial, ij) >= 3 or (not _interior(spec, ij) and _pass_through(trial, ij))
            for ij in (s.a, s.b)
        )
        if ends_ok and _strongly_connected(trial):
            kept = trial
            dropped += 1
    return kept


def _control(spec: GridSpec, segs: list[_Segment], ij: tuple[int, int]) -> str:
    meeting = [s for s in segs if ij in (s.a, s.b)]
    if len(meeting) <= 2:
        return "priority"
    ranks = [_kind(s.street).rank for s in meeting]
    major, minor = max(ranks), min(ranks)
    for rule in spec.controls:
        if (rule.major, rule.minor) == (major, minor):
            return rule.control
    return spec.default_control


def _positions(n: int, block: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(rng.uniform(block[0], block[1], n - 1))])


def _runs(segs: list[_Segment]) -> list[list[_Segment]]:
    """Consecutive segments of one street between junctions (joined across pass-through points)."""
    runs: list[list[_Segment]] = []
    for s in segs:  # segments of a street are listed west->east / south->north
        if runs and runs[-1][-1].line == s.line and runs[-1][-1].b == s.a and _pass_through(segs, s.a):
            runs[-1].append(s)
        else:
            runs.append([s])
    return runs


def build_grid(spec: GridSpec, rng: np.random.Generator) -> RoadGraph:
    """Build the road graph of a grid town."""
    nx, ny = len(spec.columns), len(spec.rows)
    if nx < 2 or ny < 2:
        raise MapError("a grid needs at least two columns and two rows")
    xs = _positions(nx, spec.block_x, rng)
    ys = _positions(ny, spec.block_y, rng)
    shift = rng.uniform(-spec.jitter, spec.jitter, size=(nx, ny, 2))
    shift[[0, -1], :, 0] = 0.0  # keep the outer boundary straight
    shift[:, [0, -1], 1] = 0.0
    segs = _drop_segments(spec, _segments(spec), rng)
    if not _strongly_connected(segs):
        raise MapError("grid streets are not strongly connected (check the one-way directions)")

    def xy(ij: tuple[int, int]) -> tuple[float, float]:
        return float(xs[ij[0]] + shift[ij][0]), float(ys[ij[1]] + shift[ij][1])

    graph = RoadGraph()
    junctions = sorted({s.a for s in segs} | {s.b for s in segs})
    for ij in junctions:
        if not _pass_through(segs, ij):
            graph.add_node(Node(_node_id(ij), *xy(ij), control=_control(spec, segs, ij)))
    for run in _runs(segs):
        street = run[0].street
        kind = _kind(street)
        column = run[0].a[0] == run[0].b[0]
        label = chr(65 + run[0].a[0]) if column else str(run[0].a[1] + 1)
        name = street.name or f"{kind.name} {label}"
        points = [xy(run[0].a)] + [xy(s.b) for s in run]
        a, b = _node_id(run[0].a), _node_id(run[-1].b)
        if kind.oneway and street.reverse:
            a, b, points = b, a, points[::-1]
        graph.add_road(a, b, kind, shape=points if len(points) > 2 else (), name=name)
    _add_left_pockets(graph)
    return graph


def _polyline(graph: RoadGraph, edge: Edge) -> np.ndarray:
    if edge.shape:
        return np.array(edge.shape, dtype=float)
    a, b = graph.nodes[edge.src], graph.nodes[edge.dst]
    return np.array([[a.x, a.y], [b.x, b.y]], dtype=float)


def _add_left_pockets(graph: RoadGraph) -> None:
    """Split edges of kinds with ``left_pocket`` before signalised junctions that have a left leg."""
    for edge in list(graph.edges.values()):
        pocket = edge.kind.left_pocket
        dst = graph.nodes[edge.dst]
        if pocket <= 0 or dst.control != "traffic_light":
            continue
        poly = _polyline(graph, edge)
        length = float(arc_length(poly)[-1])
        if length < pocket + MIN_POCKET_APPROACH:
            continue
        d = poly[-1] - poly[-2]
        d /= np.linalg.norm(d)
        has_left = False
        for other in graph.legs(dst.id) - {edge.src}:
            o = np.array([graph.nodes[other].x - dst.x, graph.nodes[other].y - dst.y])
            o /= np.linalg.norm(o)
            has_left |= bool(d[0] * o[1] - d[1] * o[0] > 0.7)
        if not has_left:
            continue
        head = cut(poly, 0.0, length - pocket)
        tail = offset(cut(poly, length - pocket, length), edge.kind.lane_width)  # pocket takes the median
        centre = head[-1] + normals(head)[-1] * edge.kind.median / 2
        mid = graph.add_node(Node(f"{edge.id}.pocket", float(centre[0]), float(centre[1])))
        graph.edges[edge.id] = replace(edge, dst=mid.id, shape=_shape(head))
        lanes = edge.kind.cross_section(extra_left=1)
        graph.add_edge(replace(edge, id=f"{edge.id}.pocket", src=mid.id, lanes=lanes, shape=_shape(tail)))


def _shape(poly: np.ndarray) -> tuple[tuple[float, float], ...]:
    return tuple((float(x), float(y)) for x, y in poly)
