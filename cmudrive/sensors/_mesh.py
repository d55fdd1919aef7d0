"""Triangle meshes for the front camera: the map's ground surfaces and markings, static scenery,
traffic-light heads and stop signs (built once per map), and the actors of a snapshot (built per tick).

Everything is in the map frame (x east, y north, z up [m]); colours are RGB floats in [0, 1].
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, fields

import numpy as np
import shapely
from shapely.geometry import Polygon

from cmudrive.maps.model import TURN_ORDER, LaneKind, RoadMap, StopKind, TurnDir
from cmudrive.maps.scenery import SceneryKind, StaticScenery
from cmudrive.maps.surfaces import junction_polygons, marking_lines
from cmudrive.sensors._raster import FLAG_EMISSIVE, FLAG_ROAD
from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.snapshot import ActorKind, Snapshot

# ground layers: depth-test bias (1 - keep) so that coplanar surfaces stack without z-fighting
ROAD_KEEP = np.float32(0.999)  # road surfaces over the ground plane
MARK_KEEP = np.float32(0.997)  # markings over road surfaces
SIDEWALK_Z = 0.15  # [m] kerb height: pavements are raised
MARK_Z = 0.0  # [m] markings lie on the road (the bias keeps them on top)

EDGE_LINE_WIDTH = 0.15  # [m]
LANE_LINE_WIDTH = 0.15  # [m]
CENTRE_LINE_WIDTH = 0.18  # [m]
STOP_LINE_WIDTH = 0.4  # [m]
LANE_LINE_DASH = (3.0, 5.0)  # [m] dash, gap (as the BEV renderer)
ZEBRA_STRIPE = (0.5, 0.5)  # [m] stripe, gap along the crossing

ASPHALT = (0.34, 0.34, 0.36)
SURFACE_COLOURS: dict[LaneKind, tuple[float, float, float]] = {
    LaneKind.DRIVING: ASPHALT,
    LaneKind.SIDEWALK: (0.70, 0.67, 0.62),
    LaneKind.WALKINGAREA: (0.70, 0.67, 0.62),
    LaneKind.BIKE: (0.52, 0.36, 0.33),  # red-brown cycle lane
    LaneKind.PARKING: (0.38, 0.38, 0.42),
    LaneKind.SHOULDER: (0.42, 0.41, 0.39),
}
KERB = (0.60, 0.59, 0.56)
WHITE_PAINT = (0.88, 0.88, 0.86)
YELLOW_PAINT = (0.86, 0.70, 0.12)

# actors
VEHICLE_PAINTS = np.array(  # CARLA-like car paints; one per vehicle, chosen by a hash of its id
    [
        (0.92, 0.92, 0.92),  # white
        (0.08, 0.08, 0.09),  # black
        (0.68, 0.70, 0.72),  # silver
        (0.42, 0.43, 0.45),  # grey
        (0.70, 0.08, 0.08),  # red
        (0.12, 0.22, 0.62),  # blue
        (0.07, 0.10, 0.28),  # dark blue
        (0.14, 0.40, 0.20),  # green
        (0.90, 0.74, 0.10),  # yellow
        (0.40, 0.25, 0.15),  # brown
        (0.90, 0.45, 0.10),  # orange
        (0.45, 0.65, 0.85),  # light blue
    ],
    np.float32,
)
CLOTHES = np.array(
    [(0.80, 0.20, 0.25), (0.20, 0.35, 0.70), (0.95, 0.85, 0.30), (0.25, 0.60, 0.35), (0.95, 0.50, 0.15)],
    np.float32,
)
TROUSERS = (0.12, 0.13, 0.20)
SKIN = (0.85, 0.65, 0.50)
TYRES = (0.06, 0.06, 0.06)
GLASS = (0.10, 0.13, 0.16)
REAR_LAMP = (0.55, 0.02, 0.02)
BRAKE_LAMP = (1.0, 0.08, 0.05)
FRONT_LAMP = (1.0, 0.95, 0.80)
SIREN = (0.15, 0.35, 1.0)
TYPE_PAINTS = {  # actor types with a fixed colour instead of a paint chosen by id
    "ambulance": (0.92, 0.92, 0.92),
    "police": (0.10, 0.12, 0.30),
    "cone": (1.0, 0.45, 0.0),
    "warning_sign": (1.0, 0.78, 0.0),
}
SMALL_PROPS = ("cone", "warning_sign")  # drawn as one plain box

# scenery
SCENERY_COLOURS = {
    SceneryKind.WALL: (0.55, 0.53, 0.50),
    SceneryKind.POLE: (0.30, 0.30, 0.32),
    SceneryKind.GUARDRAIL: (0.70, 0.72, 0.74),
    SceneryKind.TREE: (0.35, 0.24, 0.14),  # trunk
    SceneryKind.OBJECT: (0.50, 0.50, 0.48),
}
FACADES = np.array(
    [(0.72, 0.66, 0.58), (0.60, 0.55, 0.52), (0.78, 0.74, 0.68), (0.55, 0.42, 0.36), (0.66, 0.68, 0.70)],
    np.float32,
)
CANOPY = (0.20, 0.42, 0.18)
CANOPY_WIDTH = 3.5  # [m]

# traffic lights and signs
POLE = (0.25, 0.25, 0.27)
HOUSING = (0.10, 0.10, 0.10)
LAMP_OFF = (0.16, 0.16, 0.15)
LAMP_ON = {0: (1.0, 0.12, 0.08), 1: (1.0, 0.75, 0.05), 2: (0.15, 1.0, 0.35)}  # red, amber, green
LAMP_OF_STATE = {"r": 0, "u": 0, "s": 0, "y": 1, "g": 2, "G": 2}  # SUMO signal -> lit lamp ('u': red)
SIGNAL_OFFSET = 1.0  # [m] pole beyond the right end of the stop line
HEAD_BOTTOM, HEAD_HEIGHT, HEAD_WIDTH = 2.3, 1.0, 0.4  # [m]
LAMP_SIZE = 0.3  # [m]
STOP_SIGN = (0.80, 0.06, 0.08)
STOP_SIGN_RADIUS = 0.38  # [m]
STOP_SIGN_CENTRE = 2.2  # [m] above the road

# box faces over corners 0-3 (bottom: front-left, front-right, rear-right, rear-left) and 4-7 (top)
_FACES = np.array([[0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7], [4, 5, 6, 7]])
_FACE_TRIS = np.concatenate([_FACES[:, [0, 1, 2]], _FACES[:, [0, 2, 3]]])  # (10, 3)
_FACE_NORMALS = np.array([[1.0, 0.0], [0.0, -1.0], [-1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])  # local (lon, lat)
_LIGHT_DIR = np.array([0.45, 0.75]) / np.hypot(0.45, 0.75)  # fixed horizontal light for face shading


@dataclass(frozen=True)
class Triangles:
    """``T`` flat-coloured triangles."""

    xyz: np.ndarray  # (T, 3, 3) float64 vertices [m]
    colour: np.ndarray  # (T, 3) float32 RGB in [0, 1]
    flags: np.ndarray  # (T,) uint8 FLAG_* bits
    keep: np.ndarray  # (T,) float32 depth-test factor (1 - bias)

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    @staticmethod
    def make(xyz: np.ndarray, colour, flags: int = 0, keep: float = 1.0) -> Triangles:
        n = len(xyz)
        col = np.broadcast_to(np.asarray(colour, np.float32), (n, 3))
        return Triangles(
            np.asarray(xyz, np.float64).reshape(n, 3, 3),
            np.ascontiguousarray(col),
            np.full(n, flags, np.uint8),
            np.full(n, keep, np.float32),
        )

    @staticmethod
    def concat(parts: list[Triangles]) -> Triangles:
        parts = [p for p in parts if len(p)]
        if not parts:
            return Triangles.make(np.zeros((0, 3, 3)), (0.0, 0.0, 0.0))
        return Triangles(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Triangles)))


# ---------------------------------------------------------------------------------------- geometry
def _normals(xy: np.ndarray) -> np.ndarray:
    """Unit left normals (n, 2) at the vertices of a polyline (averaged over adjacent segments)."""
    seg = np.diff(xy, axis=0)
    seg /= np.maximum(np.linalg.norm(seg, axis=1, keepdims=True), 1e-12)
    normals = np.stack([-seg[:, 1], seg[:, 0]], axis=1)
    vertex = np.vstack([normals[:1], normals[:-1] + normals[1:], normals[-1:]])
    return vertex / np.maximum(np.linalg.norm(vertex, axis=1, keepdims=True), 1e-12)


def _quads(left: np.ndarray, right: np.ndarray, z: float) -> np.ndarray:
    """Triangles (2 (n - 1), 3, 3) of the strip between two polylines (n, 2) at height z."""
    zl = np.full((len(left), 1), z)
    left3, right3 = np.hstack([left, zl]), np.hstack([right, zl])
    a, b, c, d = left3[:-1], left3[1:], right3[1:], right3[:-1]
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def strip(xy: np.ndarray, half_width: float, z: float, offset: float = 0.0) -> np.ndarray:
    """Triangles of a band of ``2 half_width`` around a polyline shifted ``offset`` to its left."""
    if len(xy) < 2:
        return np.zeros((0, 3, 3))
    n = _normals(xy)
    return _quads(xy + (offset + half_width) * n, xy + (offset - half_width) * n, z)


def _wall(xy: np.ndarray, z0: float, z1: float) -> np.ndarray:
    """Triangles (2 (n - 1), 3, 3) of a vertical wall along a polyline (n, 2) from z0 to z1 [m]."""
    bottom = np.hstack([xy, np.full((len(xy), 1), z0)])
    top = np.hstack([xy, np.full((len(xy), 1), z1)])
    a, b, c, d = bottom[:-1], bottom[1:], top[1:], top[:-1]
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def _dashes(xy: np.ndarray, half_width: float, dash: float, gap: float, z: float) -> np.ndarray:
    """Straight dashes (2 triangles each) of length ``dash`` every ``dash + gap`` along a polyline."""
    if len(xy) < 2:
        return np.zeros((0, 3, 3))
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    starts = np.arange(0.5 * gap, s[-1] - dash, dash + gap)
    if len(starts) == 0:
        return np.zeros((0, 3, 3))
    a = np.stack([np.interp(starts, s, xy[:, 0]), np.interp(starts, s, xy[:, 1])], 1)
    b = np.stack([np.interp(starts + dash, s, xy[:, 0]), np.interp(starts + dash, s, xy[:, 1])], 1)
    d = (b - a) / np.maximum(np.linalg.norm(b - a, axis=1, keepdims=True), 1e-9)
    n = np.stack([-d[:, 1], d[:, 0]], 1) * half_width
    zc = np.full((len(a), 1), z)
    p = [np.hstack([q, zc]) for q in (a + n, b + n, b - n, a - n)]
    return np.concatenate([np.stack([p[0], p[1], p[2]], 1), np.stack([p[0], p[2], p[3]], 1)])


def polygon_triangles(poly: np.ndarray, z: float) -> np.ndarray:
    """Triangles (k, 3, 3) covering a simple polygon (n, 2): constrained Delaunay, fan as fallback."""
    if len(poly) < 3:
        return np.zeros((0, 3, 3))
    try:
        shape = Polygon(poly)
        if not shape.is_valid:
            shape = shapely.make_valid(shape)
        tris = [
            np.asarray(t.exterior.coords)[:3] for t in shapely.constrained_delaunay_triangles(shape).geoms
        ]
    except (shapely.errors.ShapelyError, ValueError, AttributeError):
        tris = []
    if not tris:  # a fan around the centroid
        c = poly.mean(axis=0)
        tris = [np.array([c, poly[k], poly[(k + 1) % len(poly)]]) for k in range(len(poly))]
    out = np.zeros((len(tris), 3, 3))
    out[:, :, :2] = np.array(tris)
    out[:, :, 2] = z
    return out


def boxes(x, y, yaw, length, width, z0, z1, colour, flags=0) -> Triangles:
    """Oriented boxes (B,) as 10 triangles each (4 sides and the top), faces shaded by a fixed light
    (emissive ones not); every argument is a scalar or an array over boxes, ``colour`` (B, 3) or (3,)."""
    x, y, yaw, length, width, z0, z1, flags = np.broadcast_arrays(
        *(np.atleast_1d(np.asarray(v, np.float64)) for v in (x, y, yaw, length, width, z0, z1, flags))
    )
    flags = flags.astype(np.uint8)
    nb = len(x)
    c, s = np.cos(yaw), np.sin(yaw)
    lon = np.array([1.0, 1.0, -1.0, -1.0])[None, :] * (0.5 * length)[:, None]
    lat = np.array([1.0, -1.0, -1.0, 1.0])[None, :] * (0.5 * width)[:, None]
    cx = x[:, None] + lon * c[:, None] - lat * s[:, None]
    cy = y[:, None] + lon * s[:, None] + lat * c[:, None]
    corners = np.empty((nb, 8, 3))
    corners[:, :4, 0], corners[:, 4:, 0] = cx, cx
    corners[:, :4, 1], corners[:, 4:, 1] = cy, cy
    corners[:, :4, 2], corners[:, 4:, 2] = z0[:, None], z1[:, None]
    xyz = corners[:, _FACE_TRIS]  # (B, 10, 3, 3)
    # shade: world normal of each side face against the fixed light; the top is brightest
    nx = _FACE_NORMALS[None, :, 0] * c[:, None] - _FACE_NORMALS[None, :, 1] * s[:, None]
    ny = _FACE_NORMALS[None, :, 0] * s[:, None] + _FACE_NORMALS[None, :, 1] * c[:, None]
    shade = 0.72 + 0.2 * (nx * _LIGHT_DIR[0] + ny * _LIGHT_DIR[1])  # (B, 5)
    shade[:, 4] = 1.0
    shade = np.concatenate([shade, shade], axis=1)  # (B, 10), as _FACE_TRIS
    col = np.broadcast_to(np.asarray(colour, np.float32).reshape(-1, 3), (nb, 3))
    shade[(flags & FLAG_EMISSIVE) != 0] = 1.0
    tri_col = (col[:, None, :] * shade[:, :, None]).astype(np.float32).reshape(-1, 3)
    return Triangles(xyz.reshape(-1, 3, 3), tri_col, np.repeat(flags, 10), np.ones(nb * 10, np.float32))


# ---------------------------------------------------------------------------------------- the map
def ground_triangles(m: RoadMap) -> Triangles:
    """Junction areas, lane surfaces (pavements raised), zebra crossings and the lane markings."""
    junctions = [polygon_triangles(p, 0.0) for p in junction_polygons(m)]
    parts = [Triangles.make(np.concatenate([np.zeros((0, 3, 3)), *junctions]), ASPHALT, FLAG_ROAD, ROAD_KEEP)]
    for lane in range(m.num_lanes):
        kind = LaneKind(int(m.lane_kind[lane]))
        xy, half = m.polyline(lane), 0.5 * float(m.lane_width[lane])
        if kind == LaneKind.CROSSING:
            parts.append(
                Triangles.make(_dashes(xy, half, *ZEBRA_STRIPE, MARK_Z), WHITE_PAINT, FLAG_ROAD, MARK_KEEP)
            )
            continue
        raised = kind in (LaneKind.SIDEWALK, LaneKind.WALKINGAREA)
        z = SIDEWALK_Z if raised else 0.0
        tris = polygon_triangles(xy, z) if kind == LaneKind.WALKINGAREA else strip(xy, half, z)
        flags = 0 if raised else FLAG_ROAD
        parts.append(Triangles.make(tris, SURFACE_COLOURS[kind], flags, 1.0 if raised else ROAD_KEEP))
        if kind == LaneKind.SIDEWALK and len(xy) >= 2:  # kerb faces along both edges
            n = _normals(xy)
            kerbs = [_wall(xy + side * half * n, 0.0, SIDEWALK_Z) for side in (1.0, -1.0)]
            parts.append(Triangles.make(np.concatenate(kerbs), KERB))
    solid, dashed, centre, stop = marking_lines(m)
    paint: list[tuple[np.ndarray, tuple[float, float, float]]] = []
    paint += [(strip(p, 0.5 * EDGE_LINE_WIDTH, MARK_Z), WHITE_PAINT) for p in solid]
    paint += [(_dashes(p, 0.5 * LANE_LINE_WIDTH, *LANE_LINE_DASH, MARK_Z), WHITE_PAINT) for p in dashed]
    paint += [(strip(p, 0.5 * CENTRE_LINE_WIDTH, MARK_Z), YELLOW_PAINT) for p in centre]
    paint += [(strip(np.asarray(p), 0.5 * STOP_LINE_WIDTH, MARK_Z), WHITE_PAINT) for p in stop]
    parts += [Triangles.make(t, c, FLAG_ROAD, MARK_KEEP) for t, c in paint if len(t)]
    return Triangles.concat(parts)


def scenery_triangles(scenery: StaticScenery) -> Triangles:
    """Scenery boxes; buildings in varied facade colours, trees as a trunk and a canopy box."""
    if len(scenery) == 0:
        return Triangles.concat([])
    kind = scenery.kind.astype(np.int64)
    colour = np.zeros((len(scenery), 3), np.float32)
    for k, c in SCENERY_COLOURS.items():
        colour[kind == k] = c
    building = kind == SceneryKind.BUILDING
    colour[building] = FACADES[np.flatnonzero(building) % len(FACADES)]
    tree = kind == SceneryKind.TREE
    top = np.where(tree, 0.45 * scenery.height, scenery.height)
    parts = [boxes(scenery.x, scenery.y, scenery.yaw, scenery.length, scenery.width, 0.0, top, colour)]
    if tree.any():
        t = scenery.select(tree)
        side = np.maximum(CANOPY_WIDTH, t.width)
        parts.append(boxes(t.x, t.y, t.yaw, side, side, 0.4 * t.height, t.height, CANOPY))
    return Triangles.concat(parts)


@dataclass(frozen=True)
class SignalLamps:
    """Lamps of the traffic-light heads: ``M`` lamps, 10 triangles each, in the order of their mesh."""

    tls: np.ndarray  # (M,) int64 traffic light
    signal: np.ndarray  # (M,) int64 signal index in the light's state string, -1 unknown
    colour: np.ndarray  # (M,) int64 0 red, 1 amber, 2 green (its place in the head)


def signal_triangles(m: RoadMap) -> tuple[Triangles, Triangles, SignalLamps]:
    """Traffic-light heads (poles and housings; and their lamps, listed separately) at the right end
    of every traffic-light stop line, one head per distinct signal of the lane, facing upstream; stop
    signs (stop-sign and all-way-stop lines) as red octagons on a pole there."""
    fixed: list[Triangles] = []
    lamp_parts: list[Triangles] = []
    tls_of: list[int] = []
    signal_of: list[int] = []
    colour_of: list[int] = []
    for k in range(len(m.stop_kind)):
        right, left = np.asarray(m.stop_xy[k], np.float64)
        along = (left - right) / max(float(np.linalg.norm(left - right)), 1e-9)
        back = np.array([-along[1], along[0]])  # upstream (the line runs right to left)
        facing = float(np.arctan2(back[1], back[0]))
        base = right - SIGNAL_OFFSET * along
        if m.stop_kind[k] != StopKind.TRAFFIC_LIGHT:
            fixed.append(boxes(base[0], base[1], facing, 0.08, 0.08, 0.0, STOP_SIGN_CENTRE, POLE))
            ang = np.pi / 8 + np.arange(9) * np.pi / 4
            centre = np.array([*(base + 0.06 * back), STOP_SIGN_CENTRE])
            ring = np.zeros((9, 3))
            ring[:, :2] = centre[:2] + STOP_SIGN_RADIUS * np.cos(ang)[:, None] * along
            ring[:, 2] = centre[2] + STOP_SIGN_RADIUS * np.sin(ang)
            fixed.append(
                Triangles.make(np.stack([np.broadcast_to(centre, (8, 3)), ring[:-1], ring[1:]], 1), STOP_SIGN)
            )
            continue
        lane, tls = int(m.stop_lane[k]), int(m.stop_tls[k])
        links = np.flatnonzero((m.link_from == lane) & (m.link_tls == tls))
        links = links[np.argsort([TURN_ORDER[TurnDir(int(m.link_dir[i]))] for i in links], kind="stable")]
        signals = list(dict.fromkeys(int(m.link_tls_index[i]) for i in links)) or [-1]
        top = HEAD_BOTTOM + HEAD_HEIGHT
        fixed.append(boxes(base[0], base[1], facing, 0.15, 0.15, 0.0, top, POLE))
        for j, sig in enumerate(signals):
            head = base + along * (0.3 + (HEAD_WIDTH + 0.05) * j)  # toward the road
            fixed.append(boxes(head[0], head[1], facing, 0.3, HEAD_WIDTH, HEAD_BOTTOM, top, HOUSING))
            lamp_xy = head + 0.17 * back
            for c in range(3):  # red on top
                zc = top - (c + 0.5) * HEAD_HEIGHT / 3
                lamp_parts.append(
                    boxes(
                        lamp_xy[0],
                        lamp_xy[1],
                        facing,
                        0.04,
                        LAMP_SIZE,
                        zc - LAMP_SIZE / 2,
                        zc + LAMP_SIZE / 2,
                        LAMP_OFF,
                        FLAG_EMISSIVE,
                    )
                )
                tls_of.append(tls)
                signal_of.append(sig)
                colour_of.append(c)
    lamps = SignalLamps(
        np.array(tls_of, np.int64), np.array(signal_of, np.int64), np.array(colour_of, np.int64)
    )
    return Triangles.concat(fixed), Triangles.concat(lamp_parts), lamps


def lamp_colours(lamps: SignalLamps, tls_state: np.ndarray) -> np.ndarray:
    """(M, 3) float32 colour of every lamp for the lights' current state strings (one per light)."""
    states = [str(t) for t in tls_state]
    lengths = np.array([len(t) for t in states] + [0], np.int64)
    start = np.concatenate([[0], np.cumsum(lengths)])
    chars = np.frombuffer(("".join(states) + "O").encode("ascii"), np.uint8)
    known = (lamps.tls >= 0) & (lamps.tls < len(states))
    tls = np.where(known, lamps.tls, len(states))  # unknown lights read the trailing "O" (off)
    valid = known & (lamps.signal >= 0) & (lamps.signal < lengths[tls])
    char = chars[np.where(valid, start[tls] + lamps.signal, len(chars) - 1)]
    lit = _LAMP_OF_CHAR[char] == lamps.colour
    return np.where(lit[:, None], _LAMP_ON_RGB[lamps.colour], np.asarray(LAMP_OFF, np.float32))


_LAMP_OF_CHAR = np.full(256, -1, np.int64)  # ASCII signal character -> lamp it lights
for _char, _lamp in LAMP_OF_STATE.items():
    _LAMP_OF_CHAR[ord(_char)] = _lamp
_LAMP_ON_RGB = np.array([LAMP_ON[k] for k in range(3)], np.float32)


# ---------------------------------------------------------------------------------------- actors
_TYPES = list(ACTOR_TYPES.values())
_TYPE_KIND = np.array([int(t.kind) for t in _TYPES])
_TYPE_EXTENT = np.array([(t.length, t.width) for t in _TYPES])
_TYPE_HEIGHT = np.array([t.height for t in _TYPES])
_TYPE_FIXED_PAINT = np.array([t.name in TYPE_PAINTS for t in _TYPES])
_TYPE_PAINT = np.array([TYPE_PAINTS.get(t.name, (0.0, 0.0, 0.0)) for t in _TYPES], np.float32)
_TYPE_SMALL_PROP = np.array([t.name in SMALL_PROPS for t in _TYPES])


def actor_heights(kind: np.ndarray, length: np.ndarray, width: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Height [m] and ActorType index of each actor: the type of its kind nearest in (length, width)."""
    cost = (
        (length[:, None] - _TYPE_EXTENT[None, :, 0]) ** 2
        + (width[:, None] - _TYPE_EXTENT[None, :, 1]) ** 2
        + 1e6 * (kind[:, None] != _TYPE_KIND[None, :])
    )
    best = np.argmin(cost, axis=1) if len(kind) else np.zeros(0, np.int64)  # argmin of (0, T) raises
    return _TYPE_HEIGHT[best], best


def id_hash(ids: np.ndarray) -> np.ndarray:
    """(A,) int64 deterministic hash of actor ids (CRC-32), the seed of colours and rain streaks."""
    return np.array([zlib.crc32(str(i).encode()) for i in ids], np.int64)


def actor_paints(snap: Snapshot, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How the camera paints the actors at ``rows``: (m,) ActorType index (``ACTOR_TYPES`` order, the type
    of the actor's kind nearest in extent), (m, 3) float32 body paint and (m, 3) float32 clothes of
    walkers and riders (RGB in [0, 1])."""
    kind = snap.kind[rows].astype(np.int64)
    _, tidx = actor_heights(kind, snap.length[rows], snap.width[rows])
    seed = id_hash(snap.ids[rows])
    paint = np.where(
        _TYPE_FIXED_PAINT[tidx, None], _TYPE_PAINT[tidx], VEHICLE_PAINTS[seed % len(VEHICLE_PAINTS)]
    )
    return tidx, paint, CLOTHES[seed % len(CLOTHES)]


def actor_triangles(snap: Snapshot, rows: np.ndarray) -> tuple[Triangles, np.ndarray]:
    """Triangles of the actors at ``rows`` and the CSR pointer (len(rows) + 1,) over them."""
    kind = snap.kind[rows].astype(np.int64)
    x, y, yaw = snap.x[rows], snap.y[rows], snap.yaw[rows]
    length, width = snap.length[rows], snap.width[rows]
    height, tidx = actor_heights(kind, length, width)
    _, paint, clothes = actor_paints(snap, rows)
    columns: list[list[np.ndarray]] = [[] for _ in range(10)]  # owner, x, y, yaw, l, w, z0, z1, colour, flags
    n = len(rows)

    def add(sel: np.ndarray, lon, lw, ww, z0, z1, colour, flags: int = 0) -> None:
        """Boxes for actors ``sel``: centre ``lon`` [m] ahead of the actor centre, length ``lw`` and
        width ``ww`` [m], from ``z0`` to ``z1`` [m]; scalars or arrays over all actors."""
        s = np.flatnonzero(sel)
        if len(s) == 0:
            return
        lon = np.broadcast_to(lon, (n,))[s]
        col = np.broadcast_to(np.asarray(colour, np.float32).reshape(-1, 3), (n, 3))[s]
        values = [s, x[s] + lon * np.cos(yaw[s]), y[s] + lon * np.sin(yaw[s]), yaw[s]]
        values += [np.broadcast_to(v, (n,))[s] for v in (lw, ww, z0, z1)]
        for column, v in zip(columns, [*values, col, np.full(len(s), flags, np.uint8)], strict=True):
            column.append(v)

    small_prop = _TYPE_SMALL_PROP[tidx]
    car_like = (
        np.isin(kind, [ActorKind.CAR, ActorKind.VAN, ActorKind.EMERGENCY, ActorKind.PROP]) & ~small_prop
    )
    big = np.isin(kind, [ActorKind.TRUCK, ActorKind.BUS])
    emergency = kind == ActorKind.EMERGENCY
    vehicle = car_like | big
    # wheels / underbody, body, cabin (glass), rear and front lamp bars
    add(vehicle, 0.0, 0.82 * length, width, 0.0, 0.4, TYRES)
    add(car_like, 0.0, length, width, 0.3, 0.62 * height, paint)
    add(
        car_like,
        -0.08 * length,
        0.52 * length,
        0.9 * width,
        0.62 * height,
        height,
        paint * 0.35 + 0.65 * np.asarray(GLASS, np.float32),
    )
    add(big, 0.0, length, width, 0.35, height, paint)
    add(big, 0.5 * length - 0.4, 0.84, 0.96 * width, 0.55 * height, 0.85 * height, GLASS)
    braking = snap.brake_light[rows]
    rear = np.where(braking[:, None], np.asarray(BRAKE_LAMP), np.asarray(REAR_LAMP)).astype(np.float32)
    add(vehicle, -0.5 * length - 0.01, 0.04, 0.9 * width, 0.55, 0.7, rear, FLAG_EMISSIVE)
    add(vehicle, 0.5 * length + 0.01, 0.04, 0.9 * width, 0.5, 0.62, FRONT_LAMP, FLAG_EMISSIVE)
    add(
        emergency & snap.siren[rows],
        -0.08 * length,
        0.3,
        0.8 * width,
        height,
        height + 0.15,
        SIREN,
        FLAG_EMISSIVE,
    )
    # two-wheelers: frame and rider
    two = np.isin(kind, [ActorKind.BICYCLE, ActorKind.MOTORCYCLE])
    add(two, 0.0, length, np.minimum(width, 0.25), 0.0, 0.9, TYRES)
    add(two, -0.1 * length, 0.45, np.minimum(width, 0.55), 0.9, height, clothes)
    # pedestrians: legs, torso, head
    ped = kind == ActorKind.PEDESTRIAN
    add(ped, 0.0, 0.6 * length, 0.6 * width, 0.0, 0.52 * height, TROUSERS)
    add(ped, 0.0, 0.8 * length, width, 0.52 * height, 0.86 * height, clothes)
    add(ped, 0.0, 0.45 * length, 0.4 * width, 0.86 * height, height, SKIN)
    # small props (cones, warning signs)
    add(small_prop, 0.0, length, width, 0.0, height, paint)
    if not columns[0]:
        return Triangles.concat([]), np.zeros(n + 1, np.int64)
    owner, *box = (np.concatenate(c) for c in columns)
    order = np.argsort(owner, kind="stable")  # boxes grouped by actor
    tris = boxes(*(v[order] for v in box))
    ptr = np.concatenate([[0], np.cumsum(10 * np.bincount(owner, minlength=n))]).astype(np.int64)
    return tris, ptr
