"""A leaderboard agent's sensor suite: the ``sensors()`` list checked, and its readings made from the
world's snapshot, batched over the CAVs that carry it.

Provided (data as the leaderboard's sensor interface hands it to ``run_step``):

- ``sensor.camera.rgb``: (height, width, 4) uint8 BGRA, alpha 255, rendered by our rasteriser
  (:class:`cmudrive.sensors.FrontCamera`) at the requested mounting, size and horizontal field of view.
  Level cameras only (roll = pitch = 0): the rasteriser has no tilt. Drawn up to 100 m, as our front
  camera (``CameraConfig.max_range``).
- ``sensor.speedometer``: ``{"speed": v}``, the vehicle's speed along its heading [m/s].
- ``sensor.other.gnss``: (3,) float64 latitude [deg], longitude [deg], altitude [m] of the sensor, with
  CARLA's geo reference convention (:mod:`cmudrive.leaderboard.geo`); no noise (the leaderboard adds
  ~0.5 m of it in CARLA).
- ``sensor.other.imu``: (7,) float64 accelerometer x, y, z [m/s^2], gyroscope x, y, z [rad/s], compass
  [rad], in the sensor's frame with CARLA's axes (x forward, y right, z up): the accelerometer reads
  the vehicle's acceleration at the sensor (along the heading from the dynamics, plus the turn's
  centripetal and angular terms) plus 9.81 m/s^2 up, as CARLA's does; the gyroscope's z is the yaw
  rate, positive turning right (CARLA is left-handed); the compass is the sensor's heading clockwise
  from north in [0, 2 pi). Yaw rate and its change come from the last two ticks (0 at the first).

Refused before any route starts, naming the sensor's id and type: every other type (LiDAR, radar,
semantic / depth / instance cameras, the MAP track's ``sensor.opendrive_map``, ...), tilted cameras and
IMUs, and what the leaderboard itself refuses (a duplicated id, a mounting more than 3 m from the vehicle's
origin, more sensors of a type than it allows).

Mounting: the pose ``x y z roll pitch yaw`` is in the vehicle's frame with CARLA's axes (x forward,
y right, z up; yaw clockwise, degrees), relative to the vehicle's centre on the road.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cmudrive.leaderboard.geo import GeoReference, map_to_gnss
from cmudrive.sensors.camera import CameraConfig, FrontCamera
from cmudrive.sim.snapshot import Snapshot
from cmudrive.sim.weather import Weather

CAMERA = "sensor.camera.rgb"
SPEEDOMETER = "sensor.speedometer"
GNSS = "sensor.other.gnss"
IMU = "sensor.other.imu"
PROVIDED = (CAMERA, SPEEDOMETER, GNSS, IMU)
# the leaderboard's allowed types and how many of each an agent may carry (Leaderboard 2.0, SENSORS track)
LEADERBOARD_LIMITS: Mapping[str, int] = {
    CAMERA: 8,
    "sensor.lidar.ray_cast": 2,
    "sensor.other.radar": 4,
    GNSS: 1,
    IMU: 1,
    "sensor.opendrive_map": 1,
    SPEEDOMETER: 1,
}
MAX_MOUNT_RADIUS = 3.0  # [m] the leaderboard's limit on a sensor's distance from the vehicle's origin
GRAVITY = 9.81  # [m/s^2] added to the accelerometer's z, as CARLA's IMU does
WHY_NOT = {
    "sensor.lidar.ray_cast": "cmudrive simulates no LiDAR",
    "sensor.other.radar": "cmudrive simulates no radar",
    "sensor.opendrive_map": "cmudrive's maps are SUMO networks, it has no OpenDRIVE map to give (MAP track)",
}


class SensorError(ValueError):
    """A sensor the adapter cannot provide, or that the leaderboard would refuse; names its id."""


@dataclass(frozen=True)
class SensorSpec:
    """One entry of ``sensors()``; pose in the vehicle frame, CARLA's axes [m, deg]."""

    type: str
    id: str
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    width: int = 0  # [px] cameras only
    height: int = 0  # [px]
    fov: float = 0.0  # [deg] horizontal

    @property
    def mount_yaw(self) -> float:
        """[rad] counter-clockwise from the vehicle's heading (our map convention)."""
        return -math.radians(self.yaw)

    @property
    def offset(self) -> np.ndarray:
        """(2,) [m] position in the vehicle frame, x forward, y left (our convention)."""
        return np.array([self.x, -self.y])


def parse_sensors(raw: object, where: str) -> tuple[SensorSpec, ...]:
    """The checked sensor suite of ``sensors()``'s return value ``raw``; SensorError naming ``where``
    (the agent file and class) and the sensor's id and type for anything we cannot or must not give."""
    if not isinstance(raw, list | tuple):
        raise SensorError(f"{where}: sensors() must return a list of sensor dicts, got {type(raw).__name__}")
    specs: list[SensorSpec] = []
    for k, entry in enumerate(raw):
        if not isinstance(entry, Mapping) or "type" not in entry or "id" not in entry:
            raise SensorError(
                f"{where}: sensor {k} of sensors() is not a dict with 'type' and 'id': {entry!r}"
            )
        specs.append(_parse_one(entry, where))
    ids = [s.id for s in specs]
    for s in specs:
        if ids.count(s.id) > 1:
            raise SensorError(
                f"{where}: sensor id {s.id!r} is used {ids.count(s.id)} times (ids must be unique)"
            )
    for kind, limit in LEADERBOARD_LIMITS.items():
        count = sum(s.type == kind for s in specs)
        if count > limit:
            raise SensorError(f"{where}: {count} sensors of type {kind}, the leaderboard allows {limit}")
    return tuple(specs)


def _parse_one(entry: Mapping[str, Any], where: str) -> SensorSpec:
    kind, sid = str(entry["type"]), str(entry["id"])
    name = f"{where}: sensor {sid!r} ({kind})"
    if kind not in PROVIDED:
        known = ", ".join(PROVIDED)
        reason = WHY_NOT.get(kind, "not a sensor cmudrive simulates")
        raise SensorError(f"{name} cannot be provided: {reason} (provided: {known})")
    try:
        pose = {k: float(entry.get(k, 0.0)) for k in ("x", "y", "z", "roll", "pitch", "yaw")}
    except (TypeError, ValueError) as exc:
        raise SensorError(f"{name}: its pose x y z roll pitch yaw must be numbers: {exc}") from None
    if not all(math.isfinite(v) for v in pose.values()):
        raise SensorError(f"{name}: its pose has a value that is not finite: {pose}")
    if math.hypot(pose["x"], pose["y"], pose["z"]) > MAX_MOUNT_RADIUS:
        raise SensorError(
            f"{name} is mounted more than {MAX_MOUNT_RADIUS} m from the vehicle (leaderboard rule)"
        )
    if kind in (CAMERA, IMU) and (pose["roll"] != 0.0 or pose["pitch"] != 0.0):
        raise SensorError(
            f"{name} is tilted (roll {pose['roll']}, pitch {pose['pitch']} deg): cmudrive's cameras and "
            "vehicles are level, only yaw can be set"
        )
    mount = (pose["x"], pose["y"], pose["z"], pose["roll"], pose["pitch"], pose["yaw"])
    if kind != CAMERA:
        return SensorSpec(kind, sid, *mount)
    try:
        width, height, fov = int(entry["width"]), int(entry["height"]), float(entry["fov"])
        CameraConfig(width=width, height=height, fov_deg=fov)  # its own range checks
    except KeyError as exc:
        raise SensorError(f"{name} needs width, height and fov: {exc} is missing") from None
    except (TypeError, ValueError) as exc:
        raise SensorError(f"{name}: {exc}") from None
    return SensorSpec(kind, sid, *mount, width, height, fov)


def camera_poses(snap: Snapshot, rows: np.ndarray, spec: SensorSpec) -> np.ndarray:
    """(n, 4) map-frame x, y, z [m] and yaw [rad] of the camera ``spec`` on the vehicles at ``rows``."""
    z = np.full((len(rows), 1), spec.z)
    yaw = (snap.yaw[rows] + spec.mount_yaw)[:, None]
    return np.concatenate([sensor_xy(snap, rows, spec), z, yaw], axis=1)


def sensor_xy(snap: Snapshot, rows: np.ndarray, spec: SensorSpec) -> np.ndarray:
    """(n, 2) map-frame position [m] of the sensor on the vehicles at ``rows``."""
    yaw = snap.yaw[rows]
    c, s = np.cos(yaw), np.sin(yaw)
    fx, fy = spec.offset
    return np.stack([snap.x[rows] + c * fx - s * fy, snap.y[rows] + s * fx + c * fy], axis=1)


def compass(yaw: np.ndarray) -> np.ndarray:
    """CARLA's compass [rad]: heading clockwise from north (map +y), in [0, 2 pi), of map yaws [rad]."""
    return np.asarray((0.5 * np.pi - yaw) % (2.0 * np.pi))


class ImuTracker:
    """Yaw rate and its change per CAV from the last ticks, for the IMU (gyroscope, centripetal terms)."""

    def __init__(self, num_cavs: int) -> None:
        self.last_time = np.full(num_cavs, np.nan)  # [s] NaN: not seen yet
        self.last_yaw = np.zeros(num_cavs)  # [rad]
        self.rate = np.zeros(num_cavs)  # [rad/s] counter-clockwise
        self.rate_change = np.zeros(num_cavs)  # [rad/s^2]

    def update(self, cav: np.ndarray, time: float, yaw: np.ndarray) -> None:
        """Advance the CAVs ``cav`` (n,) to ``time`` [s] at headings ``yaw`` (n,); once per time."""
        dt = time - self.last_time[cav]
        seen = np.isfinite(dt) & (dt > 0.0)
        turn = (yaw - self.last_yaw[cav] + np.pi) % (2.0 * np.pi) - np.pi
        rate = np.where(seen, turn / np.where(seen, dt, 1.0), 0.0)
        prev = self.rate[cav]
        self.rate_change[cav] = np.where(seen, (rate - prev) / np.where(seen, dt, 1.0), 0.0)
        self.rate[cav] = rate
        self.last_yaw[cav] = yaw
        self.last_time[cav] = time


def imu_readings(
    snap: Snapshot, rows: np.ndarray, rate: np.ndarray, rate_change: np.ndarray, spec: SensorSpec
) -> np.ndarray:
    """(n, 7) IMU readings (module docstring) of the sensor ``spec`` on the vehicles at ``rows``, whose
    yaw rates ``rate`` [rad/s] (n,) changed by ``rate_change`` [rad/s^2] (counter-clockwise +)."""
    v, a = snap.speed[rows], snap.accel[rows]
    rx, ry = spec.offset  # vehicle frame, y left
    # acceleration of the sensor point in the vehicle frame (x forward, y left): the centre's (along the
    # heading, and v * rate toward the turn's centre) + rate_change x r - rate^2 r
    ax = a - rate_change * ry - rate**2 * rx
    ay = v * rate + rate_change * rx - rate**2 * ry
    c, s = math.cos(spec.mount_yaw), math.sin(spec.mount_yaw)
    sx, sy = c * ax + s * ay, -s * ax + c * ay  # in the sensor's frame
    zero = np.zeros(len(rows))
    return np.stack(
        [
            sx,
            -sy,
            np.full(len(rows), GRAVITY),
            zero,
            zero,
            -rate,
            compass(snap.yaw[rows] + spec.mount_yaw),
        ],
        axis=1,
    )


class SensorRig:
    """Reads one sensor suite for any of a route's CAVs that carry it. The cameras share the map's meshes
    (``base_camera``, built once per route)."""

    def __init__(
        self,
        specs: Sequence[SensorSpec],
        base_camera: FrontCamera | None,
        weather: Weather,
        geo: GeoReference,
    ) -> None:
        self.specs = tuple(specs)
        self.weather, self.geo = weather, geo
        self.cameras: dict[str, FrontCamera] = {}
        for s in self.specs:
            if s.type == CAMERA:
                assert base_camera is not None, "a camera needs the map's meshes"
                config = CameraConfig(width=s.width, height=s.height, fov_deg=s.fov, mount_x=s.x, mount_z=s.z)
                self.cameras[s.id] = base_camera.with_config(config)

    def read(
        self, snap: Snapshot, rows: np.ndarray, imu: tuple[np.ndarray, np.ndarray] | None = None
    ) -> dict[str, list[Any]]:
        """Sensor id -> one reading per vehicle at ``rows`` (n,); ``imu``: the vehicles' yaw rates and
        their changes (:class:`ImuTracker`), needed when the suite has an IMU."""
        out: dict[str, list[Any]] = {}
        for s in self.specs:
            if s.type == CAMERA:
                rgb = self.cameras[s.id].render(snap, rows, self.weather, camera_poses(snap, rows, s))
                out[s.id] = list(to_bgra(rgb))
            elif s.type == SPEEDOMETER:
                out[s.id] = [{"speed": float(v)} for v in snap.speed[rows]]
            elif s.type == GNSS:
                z = np.nan_to_num(snap.z[rows], nan=0.0) + s.z
                out[s.id] = list(map_to_gnss(sensor_xy(snap, rows, s), z, self.geo))
            elif s.type == IMU:
                assert imu is not None, "the IMU needs the yaw rates"
                out[s.id] = list(imu_readings(snap, rows, imu[0], imu[1], s))
        return out


def to_bgra(rgb: np.ndarray) -> np.ndarray:
    """(..., H, W, 3) uint8 RGB -> (..., H, W, 4) uint8 BGRA with alpha 255, CARLA's camera layout."""
    alpha = np.full((*rgb.shape[:-1], 1), 255, np.uint8)
    return np.concatenate([rgb[..., ::-1], alpha], axis=-1)


__all__ = [
    "PROVIDED",
    "ImuTracker",
    "SensorError",
    "SensorRig",
    "SensorSpec",
    "camera_poses",
    "compass",
    "imu_readings",
    "parse_sensors",
    "to_bgra",
]
