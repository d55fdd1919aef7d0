"""The front RGB camera of every CAV, rendered from the world's arrays: road surface and markings,
static scenery, actors as boxes, traffic-light heads and stop signs, weather and light.

Model: a level pinhole camera like SimLingo's, 110 deg horizontal field of view, mounted 1.5 m behind
the vehicle centre and 2.0 m above the road, looking along the vehicle's heading; default 256 x 128
(W x H) with square pixels (vertical FOV ~71 deg, horizon on the middle row).

Why our own rasteriser, in numba: the scene is a few thousand flat-coloured triangles per camera and
the budget is 16 cameras in 25 ms on 2 CPU cores, headless, with no GPU guaranteed. A ray cast of every
pixel in numpy costs ~2 s per tick, and a numpy rasteriser vectorised over triangles has no fast
per-pixel "keep the nearest" scatter (``np.minimum.at`` is slow). An OpenGL context (EGL / OSMesa
software rendering via moderngl or pyrender) would add a system library that clusters often lack, a
draw and read-back round trip per camera, and driver-dependent pixels; at 256 x 128 the fill work is
tiny and the cost is in feeding triangles to the renderer. CARLA or another game engine is what
cmudrive exists to avoid. A numba z-buffer rasteriser compiles once (``cache=True``), reads our numpy
arrays directly, renders all cameras of a tick in one call (``prange`` over cameras), is bit-for-bit
deterministic and needs nothing beyond numba. The map's triangles are built once and bucketed in a grid
of ``cell_size`` cells, so a camera only visits the cells within ``max_range`` that can be in its
horizontal field of view; triangles crossing the camera plane are clipped at ``near``. Measured: 16
cameras of 256 x 128 on downtown with ~170 actors take ~4.5-5 ms per tick on 2 quiet cores, ~10 ms
while other jobs share them (``benchmarks/sensors.py``, docs/camera.md); the first call compiles for
7-10 s, later processes load numba's cache in < 0.3 s.

Conventions: map frame x east, y north, z up [m]. Camera frame (OpenCV) x right, y down, z forward
[m]; pixel (row r, col c) has its centre at (u, v) = (c + 0.5, r + 0.5), u = fx x / z + cx,
v = fy y / z + cy, cx = W / 2, cy = H / 2, fx = fy = (W / 2) / tan(FOV / 2). Images are uint8 RGB
(n, H, W, 3), row 0 at the top. The depth buffer is z along the optical axis [m], +inf for sky (road
markings read up to 0.3 % short, see :mod:`cmudrive.sensors._raster`).

Weather (:class:`cmudrive.sim.weather.Weather`, any preset or one matched from CARLA) acts through its
fields: ``light_level`` and the sun altitude set brightness and tint (night: dark, with the ego's
low-beam cone; lamps stay lit); ``fog_density`` and ``precipitation`` set an exponential haze toward
the fog colour with distance; ``precipitation`` adds lens blur and rain streaks (deterministic per
actor id and tick); ``wetness`` darkens paved surfaces and gives them a sheen of the sky.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from cmudrive.maps.model import RoadMap
from cmudrive.maps.scenery import StaticScenery
from cmudrive.sensors import _mesh
from cmudrive.sensors._raster import render_batch
from cmudrive.sim.snapshot import Snapshot
from cmudrive.sim.weather import Weather

# colours (RGB in [0, 1]) and light: tuned by eye against CARLA's look, one place to change them
GRASS = (0.36, 0.45, 0.26)  # the ground plane outside the map's surfaces
SKY_CLEAR = ((0.30, 0.50, 0.85), (0.72, 0.82, 0.92))  # (top, horizon) of a clear sky
SKY_OVERCAST = ((0.52, 0.54, 0.57), (0.70, 0.71, 0.72))
SKY_NIGHT = ((0.01, 0.015, 0.04), (0.05, 0.06, 0.10))
SUNSET_HORIZON, SUNSET_TOP = (0.98, 0.62, 0.36), (0.34, 0.40, 0.62)
SUNSET_TINT = (0.05, -0.12, -0.30)  # added to white light when the sun is low
DENSE_FOG = (0.78, 0.79, 0.80)
NIGHT_AMBIENT, NIGHT_TINT = 0.12, (0.75, 0.85, 1.15)  # street lighting after auto-exposure, bluish
HEADLIGHTS = 0.9  # [-] low-beam gain at the lamps, on top of the ambient light
HEADLIGHT_RANGE = 30.0  # [m] distance at which the low beams' gain halves
EGO_HALF_LENGTH = 2.4  # [m] vehicle centre to front bumper (the lamps), a ~4.9 m car
SKY_HAZE_DISTANCE = 100.0  # [m] the sky takes the haze of this much air
FOG_VISIBILITY_X_DENSITY = 2450.0  # [m]: meteorological visibility = this / fog_density (70 -> 35 m)
RAIN_VISIBILITY = 150.0  # [m] visibility in spray and mist of the hardest rain


@dataclass(frozen=True)
class CameraConfig:
    """Intrinsics, mounting and render range of the front camera."""

    width: int = 256  # [px]
    height: int = 128  # [px]
    fov_deg: float = 110.0  # [deg] horizontal
    mount_x: float = -1.5  # [m] ahead of the vehicle centre (negative: behind)
    mount_z: float = 2.0  # [m] above the road
    near: float = 0.1  # [m] near clipping plane
    max_range: float = 100.0  # [m] map triangles and actors farther than this are not drawn
    cell_size: float = 16.0  # [m] grid cell of the map's triangles

    def __post_init__(self) -> None:
        if self.width < 2 or self.height < 2:
            raise ValueError(f"camera resolution {self.width}x{self.height} is too small")
        if not 1.0 <= self.fov_deg < 179.0:
            raise ValueError(f"camera fov_deg {self.fov_deg} is outside [1, 179)")
        if self.near <= 0.0 or self.max_range <= self.near or self.cell_size <= 0.0:
            raise ValueError("camera needs 0 < near < max_range and cell_size > 0")

    @property
    def focal(self) -> float:
        """fx = fy [px]."""
        return 0.5 * self.width / math.tan(math.radians(0.5 * self.fov_deg))

    def intrinsics(self) -> np.ndarray:
        """(3, 3) pinhole matrix K (pixel centres at +0.5)."""
        f = self.focal
        return np.array([[f, 0.0, 0.5 * self.width], [0.0, f, 0.5 * self.height], [0.0, 0.0, 1.0]])


class _Look(NamedTuple):
    """Colours and numbers the shading pass needs for one weather."""

    sky_top: np.ndarray  # (3,) float32
    sky_horizon: np.ndarray  # (3,) float32 (also the fog colour)
    grass: np.ndarray  # (3,) float32
    light: np.ndarray  # (3,) float32 ambient light on surfaces
    params: np.ndarray  # (8,) float64, see `_raster._shade`


def weather_look(w: Weather, config: CameraConfig) -> _Look:
    """Derive the camera's look from a weather's physical fields (see the module docstring)."""
    cloud = w.cloudiness / 100.0
    clear, overcast = np.array(SKY_CLEAR), np.array(SKY_OVERCAST)
    top, horizon = (1.0 - cloud) * clear + cloud * overcast
    if w.is_night:
        brightness, tint = NIGHT_AMBIENT, np.array(NIGHT_TINT)
        top, horizon = np.array(SKY_NIGHT)
    else:
        brightness = 0.35 + 0.65 * w.light_level  # auto-exposure lifts dull light part of the way
        warm = min(max(1.0 - w.sun_altitude_deg / 20.0, 0.0), 1.0)  # sun within 20 deg of the horizon
        low_sun = min(1.6 * warm * (1.0 - 0.4 * cloud), 1.0)
        tint = 1.0 + low_sun * np.array(SUNSET_TINT)
        horizon = horizon + low_sun * (np.array(SUNSET_HORIZON) - horizon)
        top = top + 0.5 * low_sun * (np.array(SUNSET_TOP) - top)
        top, horizon = top * (0.5 + 0.5 * brightness), np.clip(horizon * (0.5 + 0.5 * brightness), 0.0, 1.0)
    # haze: extinction 3 / V makes contrast fall to 5 % at the visibility V (Koschmieder's law)
    fog_visibility = FOG_VISIBILITY_X_DENSITY / w.fog_density if w.fog_density > 0 else math.inf
    beta = 3.0 / fog_visibility + (w.precipitation / 100.0) * 3.0 / RAIN_VISIBILITY  # [1/m]
    fog = horizon * (1.5 if w.is_night else 1.0)
    if w.fog_density > 30:  # dense fog is bright grey, whatever the sky
        mix = min((w.fog_density - 30.0) / 40.0, 1.0)
        fog = (1 - mix) * fog + mix * np.array(DENSE_FOG) * (0.4 + 0.6 * brightness)
        top = (1 - mix) * top + mix * fog
    params = np.array(
        [
            beta,
            SKY_HAZE_DISTANCE,
            w.wetness / 100.0,
            HEADLIGHTS if w.is_night else 0.0,
            HEADLIGHT_RANGE,
            w.precipitation / 100.0,
            config.mount_z,
            EGO_HALF_LENGTH - config.mount_x,  # [m] camera to the lamps, along the axis
        ]
    )
    f32 = np.float32
    return _Look(
        top.astype(f32), fog.astype(f32), np.array(GRASS, f32), (brightness * tint).astype(f32), params
    )


@dataclass(frozen=True)
class _Grid:
    """Static triangles sorted by grid cell, with each cell's centre and reach."""

    tris: _mesh.Triangles
    cell_ptr: np.ndarray  # (C + 1,) int64
    cell_xy: np.ndarray  # (C, 2) float64 [m]
    cell_reach: np.ndarray  # (C,) float64 [m]
    grid: np.ndarray  # (5,) x0, y0, cell, nx, ny
    order: np.ndarray  # (S,) sorted position -> input triangle index


def _bucket(tris: _mesh.Triangles, cell: float) -> _Grid:
    xy = tris.xyz[:, :, :2]
    centroid = xy.mean(axis=1)
    lo = centroid.min(axis=0) - cell if len(tris) else np.zeros(2)
    hi = centroid.max(axis=0) + cell if len(tris) else np.ones(2)
    nx, ny = (np.ceil((hi - lo) / cell).astype(np.int64) + 1).tolist()
    ix = ((centroid[:, 0] - lo[0]) // cell).astype(np.int64)
    iy = ((centroid[:, 1] - lo[1]) // cell).astype(np.int64)
    cid = ix * ny + iy
    order = np.argsort(cid, kind="stable")
    counts = np.bincount(cid, minlength=nx * ny)
    ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    gx, gy = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    cell_xy = np.stack([lo[0] + (gx.ravel() + 0.5) * cell, lo[1] + (gy.ravel() + 0.5) * cell], axis=1)
    reach = np.zeros(nx * ny)
    vert_dist = np.linalg.norm(xy - cell_xy[cid][:, None, :], axis=2).max(axis=1)
    np.maximum.at(reach, cid, vert_dist)
    sorted_tris = _mesh.Triangles(tris.xyz[order], tris.colour[order], tris.flags[order], tris.keep[order])
    grid = np.array([lo[0], lo[1], cell, nx, ny], np.float64)
    return _Grid(sorted_tris, ptr, cell_xy, reach, grid, order)


def _ray_lengths(config: CameraConfig) -> np.ndarray:
    """(H, W) float32 length of each pixel's ray per metre of depth along the optical axis."""
    h, w, f = config.height, config.width, config.focal
    u = (np.arange(w) + 0.5 - 0.5 * w) / f
    v = (np.arange(h) + 0.5 - 0.5 * h) / f
    return np.sqrt(1.0 + u[None, :] ** 2 + v[:, None] ** 2).astype(np.float32)


class FrontCamera:
    """Renders the front cameras of several vehicles of a snapshot in one call.

    The map's meshes (ground, markings, scenery, signal heads, stop signs) are built once here (about
    a second for a CARLA town); ``render`` builds the actors' boxes and rasterises every camera."""

    def __init__(self, config: CameraConfig, road_map: RoadMap, scenery: StaticScenery | None = None) -> None:
        self.config = config
        self.road_map = road_map
        fixed, lamps_tris, self._lamps = _mesh.signal_triangles(road_map)
        parts = [_mesh.ground_triangles(road_map), fixed]
        if scenery is not None:
            parts.append(_mesh.scenery_triangles(scenery))
        static = _mesh.Triangles.concat([*parts, lamps_tris])
        self._lamp_first = len(static) - len(lamps_tris)
        self._grid = _bucket(static, config.cell_size)
        # where each lamp's 10 triangles went after bucketing
        inverse = np.empty(len(static), np.int64)
        inverse[self._grid.order] = np.arange(len(static))
        self._lamp_tris = inverse[self._lamp_first :].reshape(-1, 10)
        self._ray_len = _ray_lengths(config)

    def with_config(self, config: CameraConfig) -> FrontCamera:
        """A camera of other size, field of view or mounting that shares this one's map meshes (built once
        per map, the costly part): e.g. several cameras per vehicle. The grid cell size must be the same."""
        if config.cell_size != self.config.cell_size:
            raise ValueError(
                f"cameras that share meshes need the same cell_size ({config.cell_size} != "
                f"{self.config.cell_size} m)"
            )
        other = copy.copy(self)
        other.config = config
        other._ray_len = _ray_lengths(config)
        return other

    @property
    def num_static_triangles(self) -> int:
        return len(self._grid.tris)

    def poses(self, snapshot: Snapshot, rows: np.ndarray) -> np.ndarray:
        """(n, 4) camera x, y, z [m] and yaw [rad] of the vehicles at ``rows``."""
        c = self.config
        yaw = snapshot.yaw[rows]
        x = snapshot.x[rows] + c.mount_x * np.cos(yaw)
        y = snapshot.y[rows] + c.mount_x * np.sin(yaw)
        return np.stack([x, y, np.full(len(rows), c.mount_z), yaw], axis=1).astype(np.float64)

    def render(
        self, snapshot: Snapshot, cav_rows: np.ndarray, weather: Weather, poses: np.ndarray | None = None
    ) -> np.ndarray:
        """(n, H, W, 3) uint8 RGB images of the front cameras of the vehicles at snapshot rows
        ``cav_rows`` (n,); ``poses`` as in :meth:`render_with_depth`."""
        return self.render_with_depth(snapshot, cav_rows, weather, poses)[0]

    def render_with_depth(
        self, snapshot: Snapshot, cav_rows: np.ndarray, weather: Weather, poses: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Images (n, H, W, 3) uint8 and depth buffers (n, H, W) float32 [m] (z along the optical axis,
        +inf for sky) of the cameras of the vehicles at ``cav_rows``; ``poses`` (n, 4): camera x, y, z [m]
        and yaw [rad] (level) where they are not the config's mounting (:meth:`poses`), e.g. a camera
        beside the axis or looking sideways. Each camera leaves out its own vehicle's box."""
        c = self.config
        cav_rows = np.asarray(cav_rows, np.int64).reshape(-1)
        poses = self.poses(snapshot, cav_rows) if poses is None else np.asarray(poses, np.float64)
        if poses.shape != (len(cav_rows), 4):
            raise ValueError(f"camera poses must have shape ({len(cav_rows)}, 4), got {poses.shape}")
        n = len(cav_rows)
        look = weather_look(weather, c)
        # actors: every valid one, each camera skips its own vehicle
        actor_rows = np.flatnonzero(snapshot.valid)
        actor_tris, actor_ptr = _mesh.actor_triangles(snapshot, actor_rows)
        slot = np.full(snapshot.num_actors, -1, np.int64)
        slot[actor_rows] = np.arange(len(actor_rows))
        skip = slot[cav_rows]
        actor_xy = np.stack([snapshot.x[actor_rows], snapshot.y[actor_rows]], axis=1)
        reach = 0.5 * np.hypot(snapshot.length[actor_rows], snapshot.width[actor_rows]) + 1.0
        # static colours with the lamps of this tick
        colour = self._grid.tris.colour
        if len(self._lamp_tris):
            colour = colour.copy()
            colour[self._lamp_tris] = _mesh.lamp_colours(self._lamps, snapshot.tls_state)[:, None, :]
        g, a = self._grid, actor_tris
        f = c.focal
        seeds = (_mesh.id_hash(snapshot.ids[cav_rows]) * 7919 + snapshot.step) & 0x7FFFFFFF
        out = np.empty((n, c.height, c.width, 3), np.uint8)
        depth = np.empty((n, c.height, c.width), np.float32)
        render_batch(
            np.ascontiguousarray(poses),
            skip,
            np.array([f, f, 0.5 * c.width, 0.5 * c.height]),
            np.array([c.near, c.max_range, math.radians(0.5 * c.fov_deg)]),
            (g.tris.xyz, colour, g.tris.flags, g.tris.keep),
            (g.cell_ptr, g.cell_xy, g.cell_reach),
            g.grid,
            (a.xyz, a.colour, a.flags, a.keep),
            (actor_ptr, actor_xy, reach),
            (look.sky_top, look.sky_horizon, look.grass, look.light),
            look.params,
            self._ray_len,
            seeds.astype(np.int64),
            out,
            depth,
        )
        return out, depth
