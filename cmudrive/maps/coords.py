"""Conversion between CARLA world coordinates and our map frame.

Our map frame is SUMO's network frame: right-handed, x east, y north, z up, metres; a heading (yaw) is
in radians, counter-clockwise from +x. CARLA's world frame (Unreal Engine) is left-handed: x forward
(east), y to the right (south), z up, metres; its yaw is in degrees, clockwise from +x seen from above.

Networks imported from OpenDRIVE keep the .xodr coordinates unshifted (``import_map`` passes
``--offset.disable-normalization``), so a network x, y equals the OpenDRIVE x, y, and CARLA places an
OpenDRIVE point (x, y) at world (x, -y). The transform is therefore a mirror in y:

    x_map = x_carla            y_map = -y_carla            z_map = z_carla
    yaw_map_rad = -radians(yaw_carla_deg)        yaw_carla_deg = -degrees(yaw_map_rad)

Output yaws are wrapped to [-pi, pi) and [-180, 180) degrees. Example: CARLA's Town01 spawn point
(338.98, 226.75) with yaw -90 deg (driving towards smaller CARLA y) is map (338.98, -226.75) with yaw
+pi/2 (driving north).

Networks imported from OpenStreetMap are projected to UTM by netconvert and shifted to a local
origin (the network's ``netOffset``); there, "CARLA coordinates" simply mean that network frame mirrored
in y, with no geographic meaning beyond it.

All functions are vectorised: points are arrays of shape (..., 2) or (..., 3), yaws of shape (...) or
scalars; inputs are never modified.

A vehicle's own frame (the ego frame of labels, target points and model rows: x forward, y left, metres,
origin at the vehicle's centre): :func:`to_ego`.
"""

from __future__ import annotations

from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def _mirror_y(points: ArrayLike) -> FloatArray:
    """Return a float copy of ``points`` (shape (..., 2) or (..., 3)) with y negated."""
    out = np.array(points, dtype=np.float64, copy=True)
    if out.ndim == 0 or out.shape[-1] not in (2, 3):
        raise ValueError(f"points must have shape (..., 2) or (..., 3), got {out.shape}")
    out[..., 1] *= -1.0
    return out


def carla_yaw_to_map(yaw_deg: ArrayLike) -> FloatArray:
    """CARLA yaw [deg, clockwise from +x] -> map yaw [rad, counter-clockwise from +x] in [-pi, pi)."""
    yaw = -np.radians(np.asarray(yaw_deg, dtype=np.float64))
    return np.asarray((yaw + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


def map_yaw_to_carla(yaw_rad: ArrayLike) -> FloatArray:
    """Map yaw [rad, counter-clockwise from +x] -> CARLA yaw [deg, clockwise from +x] in [-180, 180)."""
    yaw = -np.degrees(np.asarray(yaw_rad, dtype=np.float64))
    return np.asarray((yaw + 180.0) % 360.0 - 180.0, dtype=np.float64)


@overload
def carla_to_map(xy_or_xyz: ArrayLike, yaw_deg: None = None) -> FloatArray: ...
@overload
def carla_to_map(xy_or_xyz: ArrayLike, yaw_deg: ArrayLike) -> tuple[FloatArray, FloatArray]: ...
def carla_to_map(
    xy_or_xyz: ArrayLike, yaw_deg: ArrayLike | None = None
) -> FloatArray | tuple[FloatArray, FloatArray]:
    """CARLA world points (..., 2|3) [m] -> map points; with ``yaw_deg`` also the map yaw [rad]."""
    points = _mirror_y(xy_or_xyz)
    if yaw_deg is None:
        return points
    return points, carla_yaw_to_map(yaw_deg)


@overload
def map_to_carla(xy_or_xyz: ArrayLike, yaw_rad: None = None) -> FloatArray: ...
@overload
def map_to_carla(xy_or_xyz: ArrayLike, yaw_rad: ArrayLike) -> tuple[FloatArray, FloatArray]: ...
def map_to_carla(
    xy_or_xyz: ArrayLike, yaw_rad: ArrayLike | None = None
) -> FloatArray | tuple[FloatArray, FloatArray]:
    """Map points (..., 2|3) [m] -> CARLA world points; with ``yaw_rad`` also the CARLA yaw [deg]."""
    points = _mirror_y(xy_or_xyz)
    if yaw_rad is None:
        return points
    return points, map_yaw_to_carla(yaw_rad)


def to_ego(
    xy: np.ndarray, x: float | np.ndarray, y: float | np.ndarray, yaw: float | np.ndarray
) -> np.ndarray:
    """(..., 2) map-frame points -> the frame of a vehicle at (x, y) heading ``yaw`` (x forward, y left);
    x, y, yaw may be arrays that broadcast against ``xy[..., 0]``."""
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = xy[..., 0] - x, xy[..., 1] - y
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)
