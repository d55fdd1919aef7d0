"""Derive a town's static scenery (buildings, street lights, guardrails) from its road map.

SUMO networks carry no scenery, and the OpenDRIVE files of CARLA's towns that we import carry none that
matters (``docs/scenery.md``), so :func:`build_scenery` places it by rule, deterministically for a seed:

- **Road area.** Every lane (driving, sidewalk, bike, parking, shoulder, crossing, walking area) as its
  centreline buffered by half its width, plus every junction outline: the surface that someone drives
  or walks on. Nothing is ever placed within ``margin`` of it: every candidate box is tested against it
  at the end and dropped when it comes closer.
- **Buildings** line the boundary of the road area: the holes of its union are the blocks between roads,
  the outer boundary is the edge of the town. Walking along each boundary ring with the road on the left,
  slots of random frontage (10-30 m) and gap (3-8 m) follow each other, and a building of random depth
  (10-20 m) stands on the right of each straight slot, set back 2-4 m behind the outer edge (of the
  sidewalk, or of the outermost lane where a road has none). The street beside a slot (its nearest lane's
  edge) sets the rest: beside streets with a sidewalk and two or more driving lanes (downtown) the whole
  slot is built, 6-30 m high; beside other streets with a sidewalk, houses stand in gardens (55-85 % of
  the slot, at most 8-12 m deep, 6-14 m high); beside roads without a sidewalk half of the slots are built
  (4-10 m high); beside fast roads (speed limit >= ``fast_speed``, no sidewalk) a third, 10-20 m back. A
  second pass of small buildings (7-10 m) fills corners and short blocks that the first one left empty.
- **Street lights** (0.3 m square poles, 6-8 m high) stand every 25-40 m just outside the outer edge of
  every sidewalk.
- **Guardrails** run along fast roads without a sidewalk, as chains of thin boxes (``rail_segment`` long)
  just outside the right edge of the outermost lane, and along the left edge of the innermost lane where
  the road has no opposite lane beside it (a median); segments that would come near another lane (ramps,
  junctions, a narrow median) are dropped, which leaves the gaps that entries and exits need.
- Overlaps between objects are resolved greedily in a fixed order (guardrails, poles, buildings, small
  buildings): an object that comes closer than ``building_gap_min`` to an accepted building, or that
  overlaps an accepted object, is dropped.

All geometry is done with shapely 2 on arrays of geometries (one ``STRtree`` query per test, no Python
loop over geometry pairs); the walk along the boundary rings is vectorised per ring. A town takes about a
second to a few seconds; :func:`cmudrive.maps.load_scenery` caches the result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmudrive.maps.model import LaneKind, RoadMap
from cmudrive.maps.scenery import SceneryKind, StaticScenery

try:
    import shapely
except ImportError as exc:  # pragma: no cover - shapely is a dependency of the scenery builder
    raise ImportError("building static scenery needs shapely>=2 (pip install 'shapely>=2')") from exc


@dataclass(frozen=True)
class SceneryConfig:
    """The numbers of the scenery rules (module docstring); ranges are drawn uniformly."""

    margin: float = 0.3  # [m] no box comes closer than this to a lane area or junction outline
    fast_speed: float = 22.0  # [m/s] roads this fast (without a sidewalk) get guardrails, set-back buildings
    # buildings
    setback: tuple[float, float] = (2.0, 4.0)  # [m] behind the outer road edge
    fast_setback: tuple[float, float] = (10.0, 20.0)  # [m] behind the edge of a fast road
    fast_build_share: float = 0.35  # share of building slots built beside fast roads
    rural_build_share: float = 0.5  # share built beside other roads without a sidewalk
    frontage: tuple[float, float] = (10.0, 30.0)  # [m] building length along the road
    depth: tuple[float, float] = (10.0, 20.0)  # [m] building depth away from the road
    gap: tuple[float, float] = (3.0, 8.0)  # [m] between neighbouring buildings along the road
    small_frontage: tuple[float, float] = (7.0, 10.0)  # [m] the second, corner-filling pass
    small_depth: tuple[float, float] = (7.0, 10.0)  # [m]
    house_share: tuple[float, float] = (0.55, 0.85)  # of the slot's frontage, beside non-downtown streets
    house_depth: tuple[float, float] = (8.0, 12.0)  # [m] at most, beside non-downtown streets
    building_gap_min: float = 2.0  # [m] accepted buildings keep at least this far apart
    height_downtown: tuple[float, float] = (6.0, 30.0)  # [m] sidewalk and >= 2 lanes per direction
    height_town: tuple[float, float] = (6.0, 14.0)  # [m] other streets with a sidewalk
    height_rural: tuple[float, float] = (4.0, 10.0)  # [m] roads without a sidewalk
    max_bend: float = 15.0  # [deg] a slot whose road edge turns more than this is not built
    min_block_area: float = 150.0  # [m^2] smaller holes of the road area (islands, medians) get nothing
    # street lights
    pole_spacing: tuple[float, float] = (25.0, 40.0)  # [m] along a sidewalk
    pole_size: float = 0.3  # [m] square footprint
    pole_height: tuple[float, float] = (6.0, 8.0)  # [m]
    # guardrails
    rail_segment: float = 4.0  # [m] length of one box of the chain
    rail_width: float = 0.3  # [m]
    rail_height: float = 0.8  # [m]


def build_scenery(road_map: RoadMap, seed: int = 0, config: SceneryConfig | None = None) -> StaticScenery:
    """Static scenery of ``road_map`` (module docstring); the same map and seed give the same arrays."""
    cfg = config or SceneryConfig()
    rng = np.random.default_rng(seed)
    areas, area_lane = road_areas(road_map)
    tree = shapely.STRtree(areas)
    edges = _EdgeTable.build(road_map, cfg.fast_speed)
    rails = _guardrails(road_map, edges, cfg)
    poles = _poles(road_map, edges, cfg, rng)
    road = shapely.union_all(shapely.buffer(areas, 0.05))  # closes the seams between neighbouring lanes
    rings = _boundary_rings(road, cfg.min_block_area)
    big = _buildings(rings, tree, area_lane, edges, cfg, rng, small=False)
    small = _buildings(rings, tree, area_lane, edges, cfg, rng, small=True)
    candidates = StaticScenery.concatenate([rails, poles, big, small])
    boxes = shapely.polygons(candidates.corners())
    clear = _clear_of(boxes, tree, cfg.margin)
    keep = _resolve_overlaps(candidates.select(clear), boxes[clear], cfg.building_gap_min)
    return candidates.select(np.flatnonzero(clear)[keep])


# ---------------------------------------------------------------------------------------------- road area
def road_areas(road_map: RoadMap) -> tuple[np.ndarray, np.ndarray]:
    """Every lane's surface and every junction outline as shapely polygons (A,), and the lane of each
    (-1 for junction outlines). Lanes are their centreline buffered by half their width (flat ends, round
    joins); walking areas are their closed outline; a degenerate lane (one point, or zero length) is a
    disc of its width."""
    m = road_map
    lanes = np.arange(m.num_lanes)
    walking = m.lane_kind == LaneKind.WALKINGAREA
    counts = np.diff(m.lane_pt_ptr)
    geoms = np.empty(m.num_lanes, dtype=object)
    line_rows = lanes[~walking & (counts >= 2) & (m.lane_length > 0.05)]
    geoms[line_rows] = shapely.buffer(
        _lane_lines(m, line_rows), 0.5 * m.lane_width[line_rows], cap_style="flat"
    )
    point_rows = lanes[~walking & ~np.isin(lanes, line_rows) & (counts >= 1)]
    first = m.pt_xy[m.lane_pt_ptr[point_rows]]
    geoms[point_rows] = shapely.buffer(shapely.points(first), 0.5 * m.lane_width[point_rows])
    walk_rows = lanes[walking & (counts >= 3)]
    for lane in walk_rows.tolist():  # a few hundred closed outlines at most
        geoms[lane] = shapely.make_valid(shapely.polygons(m.polyline(lane)))
    junction_geoms = [
        shapely.make_valid(shapely.polygons(m.junction_shape(j)))
        for j in range(len(m.junction_ids))
        if len(m.junction_shape(j)) >= 3
    ]
    junctions = np.empty(len(junction_geoms), dtype=object)  # (a list of polygons would become a 3D array)
    junctions[:] = junction_geoms
    all_geoms = np.concatenate([geoms, junctions])
    owner = np.concatenate([lanes, np.full(len(junction_geoms), -1)])
    present = ~shapely.is_missing(all_geoms) & ~shapely.is_empty(all_geoms)
    return all_geoms[present], owner[present]


def _lane_lines(m: RoadMap, lanes: np.ndarray) -> np.ndarray:
    """Centrelines of ``lanes`` (each with at least two points) as shapely line strings (n,)."""
    if len(lanes) == 0:
        return np.empty(0, dtype=object)
    starts, ends = m.lane_pt_ptr[lanes], m.lane_pt_ptr[lanes + 1]
    counts = ends - starts
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])  # where each lane begins in the gathered points
    rows = np.repeat(starts - first, counts) + np.arange(counts.sum())
    return shapely.linestrings(m.pt_xy[rows], indices=np.repeat(np.arange(len(lanes)), counts))


@dataclass(frozen=True)
class _EdgeTable:
    """Per-lane facts about the lane's edge (arrays over the map's N lanes)."""

    fast: np.ndarray  # (N,) bool the edge's fastest driving lane reaches fast_speed and it has no sidewalk
    sidewalk: np.ndarray  # (N,) bool the edge has a sidewalk
    downtown: np.ndarray  # (N,) bool the edge has a sidewalk and >= 2 driving lanes
    outermost: np.ndarray  # (N,) bool a normal lane that is the rightmost of its edge
    innermost: np.ndarray  # (N,) bool a normal lane that is the leftmost of its edge

    @staticmethod
    def build(m: RoadMap, fast_speed: float) -> _EdgeTable:
        n_edges = len(m.edge_ids)
        edge = m.lane_edge
        normal = ~m.lane_internal & (edge >= 0)
        e = np.where(normal, edge, n_edges)  # internal lanes go to a dummy edge
        driving = normal & (m.lane_kind == LaneKind.DRIVING)
        top_speed = np.zeros(n_edges + 1)
        np.maximum.at(top_speed, e[driving], m.lane_speed[driving])
        n_driving = np.bincount(e[driving], minlength=n_edges + 1)
        has_walk = np.bincount(e[normal & (m.lane_kind == LaneKind.SIDEWALK)], minlength=n_edges + 1) > 0
        lo = np.full(n_edges + 1, np.iinfo(np.int32).max)
        hi = np.full(n_edges + 1, -1)
        index = m.lane_index.astype(np.int64)
        np.minimum.at(lo, e[normal], index[normal])
        np.maximum.at(hi, e[normal], index[normal])
        return _EdgeTable(
            fast=normal & (top_speed[e] >= fast_speed) & ~has_walk[e],
            sidewalk=normal & has_walk[e],
            downtown=normal & has_walk[e] & (n_driving[e] >= 2),
            outermost=normal & (index == lo[e]),
            innermost=normal & (index == hi[e]),
        )


# ---------------------------------------------------------------------------------------------- boxes
def _boxes(
    kind: SceneryKind, a: np.ndarray, b: np.ndarray, width: np.ndarray, height: np.ndarray
) -> StaticScenery:
    """Boxes whose length axis runs from points a (S, 2) to b (S, 2) [m]."""
    d = b - a
    return StaticScenery(
        kind=np.full(len(a), int(kind), np.int8),
        x=0.5 * (a[:, 0] + b[:, 0]),
        y=0.5 * (a[:, 1] + b[:, 1]),
        yaw=np.arctan2(d[:, 1], d[:, 0]),
        length=np.hypot(d[:, 0], d[:, 1]),
        width=np.asarray(width, np.float64),
        height=np.asarray(height, np.float64),
    )


def _edge_lines(m: RoadMap, lanes: np.ndarray, offset: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """Each lane's centreline offset sideways by ``offset`` (+ left) [m], as (lane, points (n, 2)) parts."""
    out: list[tuple[int, np.ndarray]] = []
    ok = lanes[(np.diff(m.lane_pt_ptr)[lanes] >= 2) & (m.lane_length[lanes] > 1.0)]
    if len(ok) == 0:
        return out
    curves = shapely.offset_curve(_lane_lines(m, ok), offset[np.searchsorted(lanes, ok)], join_style="round")
    for lane, curve in zip(ok.tolist(), curves, strict=True):
        for part in shapely.get_parts(curve):
            xy = shapely.get_coordinates(part)
            if len(xy) >= 2:
                out.append((lane, xy))
    return out


def _resample(xy: np.ndarray, s_new: np.ndarray) -> np.ndarray:
    """Points at arc lengths ``s_new`` along the polyline ``xy`` (n, 2)."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    return np.column_stack([np.interp(s_new, s, xy[:, 0]), np.interp(s_new, s, xy[:, 1])])


def _guardrails(m: RoadMap, edges: _EdgeTable, cfg: SceneryConfig) -> StaticScenery:
    """Chains of thin boxes along the outer edge (and the median edge) of fast roads."""
    clearance = cfg.margin + 0.5 * cfg.rail_width + 0.05  # [m] lane edge to the rail's centre line
    right = np.flatnonzero(edges.fast & edges.outermost)
    median = np.flatnonzero(edges.fast & edges.innermost & (m.lane_opposite < 0))
    parts = _edge_lines(m, right, -(0.5 * m.lane_width[right] + clearance))
    parts += _edge_lines(m, median, 0.5 * m.lane_width[median] + clearance)
    a_list, b_list = [], []
    for _, xy in parts:
        length = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
        n_seg = max(1, int(np.ceil(length / cfg.rail_segment)))
        pts = _resample(xy, np.linspace(0.0, length, n_seg + 1))
        a_list.append(pts[:-1])
        b_list.append(pts[1:])
    if not a_list:
        return StaticScenery.empty()
    a, b = np.concatenate(a_list), np.concatenate(b_list)
    n = len(a)
    rails = _boxes(SceneryKind.GUARDRAIL, a, b, np.full(n, cfg.rail_width), np.full(n, cfg.rail_height))
    return rails.select(np.flatnonzero(rails.length > 0.5))


def _poles(m: RoadMap, edges: _EdgeTable, cfg: SceneryConfig, rng: np.random.Generator) -> StaticScenery:
    """Street lights just outside the outer edge of every sidewalk: the right edge of a sidewalk that is
    its edge's rightmost lane, the left edge of one that is its leftmost (CARLA's left-side sidewalks)."""
    sidewalk = m.lane_kind == LaneKind.SIDEWALK
    right = np.flatnonzero(edges.outermost & sidewalk)
    left = np.flatnonzero(edges.innermost & ~edges.outermost & sidewalk & (m.lane_opposite < 0))
    clearance = cfg.margin + 0.5 * cfg.pole_size + 0.05
    parts = _edge_lines(m, right, -(0.5 * m.lane_width[right] + clearance))
    parts += _edge_lines(m, left, 0.5 * m.lane_width[left] + clearance)
    centres, yaws = [], []
    for _, xy in parts:
        length = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
        spacing = rng.uniform(*cfg.pole_spacing)
        s = np.arange(0.5 * min(spacing, length), length, spacing)
        if len(s) == 0:
            continue
        ahead = _resample(xy, np.minimum(s + 0.5, length)) - _resample(xy, np.maximum(s - 0.5, 0.0))
        centres.append(_resample(xy, s))
        yaws.append(np.arctan2(ahead[:, 1], ahead[:, 0]))
    if not centres:
        return StaticScenery.empty()
    xy, yaw = np.concatenate(centres), np.concatenate(yaws)
    n = len(xy)
    return StaticScenery(
        kind=np.full(n, int(SceneryKind.POLE), np.int8),
        x=xy[:, 0],
        y=xy[:, 1],
        yaw=yaw,
        length=np.full(n, cfg.pole_size),
        width=np.full(n, cfg.pole_size),
        height=rng.uniform(*cfg.pole_height, n),
    )


# ---------------------------------------------------------------------------------------------- buildings
def _boundary_rings(road: shapely.Geometry, min_block_area: float) -> list[np.ndarray]:
    """Boundary rings (n, 2) of the road area, oriented so that the road lies on their left: the outer
    boundary of each connected part, and its holes of at least ``min_block_area`` (the blocks)."""
    road = shapely.orient_polygons(road, exterior_cw=False)  # exteriors CCW, holes CW: road on the left
    rings: list[np.ndarray] = []
    for poly in shapely.get_parts(road):
        if not isinstance(poly, shapely.Polygon):
            continue
        rings.append(np.asarray(poly.exterior.coords))
        for hole in poly.interiors:
            if shapely.area(shapely.Polygon(hole)) >= min_block_area:
                rings.append(np.asarray(hole.coords))
    return rings


def _buildings(
    rings: list[np.ndarray],
    tree: shapely.STRtree,
    area_lane: np.ndarray,
    edges: _EdgeTable,
    cfg: SceneryConfig,
    rng: np.random.Generator,
    small: bool,
) -> StaticScenery:
    """Candidate buildings along every ring, on its right (the land side); the street beside each slot
    (the nearest lane) sets its set-back and height."""
    frontage_range = cfg.small_frontage if small else cfg.frontage
    depth_range = cfg.small_depth if small else cfg.depth
    a_all, b_all, depth_all, mid_all = [], [], [], []
    for ring in rings:
        seg = np.hypot(*np.diff(ring, axis=0).T)
        perimeter = float(np.sum(seg))
        if perimeter < frontage_range[0]:
            continue
        n_max = int(perimeter / (frontage_range[0] + cfg.gap[0])) + 1
        frontage = rng.uniform(*frontage_range, n_max)
        gap = rng.uniform(*cfg.gap, n_max)
        start = rng.uniform(0.0, frontage_range[0]) + np.concatenate([[0.0], np.cumsum(frontage + gap)[:-1]])
        fits = start + frontage <= perimeter
        start, frontage = start[fits], frontage[fits]
        mid = start + 0.5 * frontage
        heading = _ring_heading(ring, mid, perimeter)
        bend = np.maximum(
            np.abs(_angle(_ring_heading(ring, start, perimeter) - heading)),
            np.abs(_angle(_ring_heading(ring, start + frontage, perimeter) - heading)),
        )
        straight = bend <= np.radians(cfg.max_bend)  # a slot round a corner would stand in the road
        direction = np.column_stack([np.cos(heading), np.sin(heading)])[straight]
        centre = _resample(ring, mid[straight])
        half = 0.5 * frontage[straight, None] * direction
        a_all.append(centre - half)
        b_all.append(centre + half)
        depth_all.append(rng.uniform(*depth_range, len(start))[straight])
        mid_all.append(centre)
    if not a_all:
        return StaticScenery.empty()
    a, b, depth, mid = (np.concatenate(v) for v in (a_all, b_all, depth_all, mid_all))
    n = len(a)
    lane = _nearest_lane(tree, area_lane, mid)
    has_lane = lane >= 0
    lane = np.maximum(lane, 0)
    fast = has_lane & edges.fast[lane]
    downtown = has_lane & edges.downtown[lane]
    town = has_lane & edges.sidewalk[lane] & ~downtown
    setback = np.where(fast, rng.uniform(*cfg.fast_setback, n), rng.uniform(*cfg.setback, n))
    height = np.where(
        downtown,
        rng.uniform(*cfg.height_downtown, n),
        np.where(town, rng.uniform(*cfg.height_town, n), rng.uniform(*cfg.height_rural, n)),
    )
    share = np.where(fast, cfg.fast_build_share, np.where(downtown | town, 1.0, cfg.rural_build_share))
    built = rng.random(n) < share
    # beside streets that are not downtown, houses stand in gardens: a shorter, shallower box in the slot
    slot = np.hypot(*(b - a).T)
    shrink = np.where(town, rng.uniform(*cfg.house_share, n), 1.0)
    shrink = np.maximum(shrink, np.minimum(cfg.small_frontage[0] / np.maximum(slot, 1e-9), 1.0))
    depth = np.where(town, np.minimum(depth, rng.uniform(*cfg.house_depth, n)), depth)
    centre = 0.5 * (a + b)
    a, b = centre + (a - centre) * shrink[:, None], centre + (b - centre) * shrink[:, None]
    direction = (b - a) / np.maximum(np.hypot(*(b - a).T), 1e-9)[:, None]
    right = np.column_stack([direction[:, 1], -direction[:, 0]])  # the land side
    shift = right * (setback + 0.5 * depth)[:, None]
    boxes = _boxes(SceneryKind.BUILDING, a + shift, b + shift, depth, height)
    return boxes.select(np.flatnonzero(built))


def _ring_heading(ring: np.ndarray, s: np.ndarray, perimeter: float, window: float = 1.0) -> np.ndarray:
    """(n,) direction [rad] of a closed ring around arc lengths ``s`` (over +-``window`` m)."""
    ahead = _resample(ring, np.mod(s + window, perimeter))
    behind = _resample(ring, np.mod(s - window, perimeter))
    d = ahead - behind
    return np.arctan2(d[:, 1], d[:, 0])


def _angle(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _nearest_lane(tree: shapely.STRtree, area_lane: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(n,) lane of the road area nearest to each point (-1 where that is a junction outline)."""
    if len(xy) == 0:
        return np.zeros(0, np.int64)
    point_i, area_i = tree.query_nearest(shapely.points(xy), all_matches=False)
    lane = np.full(len(xy), -1, np.int64)
    lane[point_i] = area_lane[area_i]
    return lane


# ---------------------------------------------------------------------------------------------- checks
def _clear_of(boxes: np.ndarray, tree: shapely.STRtree, margin: float) -> np.ndarray:
    """(S,) bool: the box keeps more than ``margin`` from every road area in ``tree``."""
    clear = np.ones(len(boxes), bool)
    if len(boxes):
        hit, _ = tree.query(boxes, predicate="dwithin", distance=margin)
        clear[hit] = False
    return clear


def _resolve_overlaps(scenery: StaticScenery, boxes: np.ndarray, building_gap: float) -> np.ndarray:
    """(S,) bool: greedy in row order, a box is kept unless it overlaps a kept box, or is a building
    closer than ``building_gap`` to a kept building. Guardrail segments may overlap each other (the
    segments of one chain overlap a little where it bends)."""
    n = len(scenery)
    keep = np.ones(n, bool)
    if n == 0:
        return keep
    tree = shapely.STRtree(boxes)
    i, j = tree.query(boxes, predicate="dwithin", distance=building_gap)
    near = i != j
    i, j = i[near], j[near]
    building = scenery.kind == SceneryKind.BUILDING
    touching = shapely.intersection(boxes[i], boxes[j])
    overlap = shapely.area(touching) > 1e-6
    rail = scenery.kind == SceneryKind.GUARDRAIL
    conflict = (overlap & ~(rail[i] & rail[j])) | (building[i] & building[j])
    i, j = i[conflict], j[conflict]
    order = np.argsort(i, kind="stable")
    i, j = i[order], j[order]
    ptr = np.searchsorted(i, np.arange(n + 1))
    for row in range(n):  # rows are in priority order; each looks only at its own conflicts
        others = j[ptr[row] : ptr[row + 1]]
        if np.any(keep[others[others < row]]):
            keep[row] = False
    return keep
