"""Camera-rotation augmentation for training V2V-VLA: a sample as if the ego had been turned by ``dyaw``.

SimLingo shifts and rotates the camera (+-1.5 m lateral, +-20 deg yaw) with a second image rendered in
CARLA at the shifted pose, and moves the labels into the new frame, so that the model sees itself off the
path and learns to steer back. Our dataset keeps one camera image per sample and no depth, so only what a
single image determines exactly is done here:

- the new ego frame is the old one **rotated by ``dyaw`` about the camera** (``mount_x`` = 1.5 m behind
  the vehicle centre): a camera that only rotates about its own centre sees a homography of the old image
  (``K R K^-1``, exact at every depth for our level pinhole camera). The vehicle centre therefore moves
  too, by ``1.5 m x (cos dyaw - 1, sin dyaw)`` (0.51 m sideways at 20 deg): a small lateral offset comes
  with the rotation, consistently in the image and in the labels;
- the columns the rotated camera sees but the old one did not (up to ``f tan(dyaw)`` px at the image
  centre, ~33 px of 256 at 20 deg) are black: there is nothing to fill them with;
- path, speed waypoints, target points and other CAVs (positions and yaws) are moved into the new frame by
  the same rigid transform; speed and the language labels are unchanged (a turned car still has to do the
  same thing; the path label already says how to get back);
- the merged BEV image is re-drawn in the new frame from the stored occupancy grid (``merged_occupancy``,
  packed class bits): warped with the V2V warp (:func:`cmudrive.v2v.warp.warp_to_ego`, nearest cell) and
  drawn again, with the row contract's palette (:func:`cmudrive.sensors.occupancy.packed_to_rgb`), ego box
  upright; cells that come into view from outside the old grid are empty, and so are the cells the old
  ego box covered (the image never showed what lies under the box, and the rotated one does not either).

Not modelled: a lateral shift without rotation (it needs the scene's depth, i.e. re-rendering), and the
parallax of a camera that turns about the vehicle centre instead of itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from PIL import Image

from cmudrive.sensors.camera import CameraConfig
from cmudrive.sensors.occupancy import OccupancyConfig, ego_box, pack_occupancy, packed_to_rgb
from cmudrive.v2v.warp import warp_to_ego

# (n, 2) point columns of a row, ego frame [m], that move with the frame
_POINT_KEYS = ("path", "speed_waypoints", "target_points")


@dataclass(frozen=True)
class YawAugment:
    """Rotate a sample with probability ``prob`` by a yaw drawn uniformly from +-``max_yaw_deg``."""

    prob: float = 0.5  # [-] share of training samples that are rotated
    max_yaw_deg: float = 20.0  # [deg] SimLingo's yaw range

    def __post_init__(self) -> None:
        if not 0.0 <= self.prob <= 1.0:
            raise ValueError(f"augmentation prob must be in [0, 1], got {self.prob}")
        if not 0.0 <= self.max_yaw_deg < 45.0:
            raise ValueError(f"max_yaw_deg must be in [0, 45), got {self.max_yaw_deg}")

    def draw(self, rng: np.random.Generator) -> float:
        """[rad] the rotation of one sample, 0 for the samples left as they are."""
        if self.prob == 0.0 or rng.random() >= self.prob:
            return 0.0
        return math.radians(rng.uniform(-self.max_yaw_deg, self.max_yaw_deg))


def rotated_frame(dyaw: float, mount_x: float) -> np.ndarray:
    """(3,) pose (x, y [m], yaw [rad]) of the new ego frame in the old one: turned by ``dyaw`` (+ = left)
    about the camera at (``mount_x``, 0)."""
    c, s = math.cos(dyaw), math.sin(dyaw)
    return np.array([mount_x - (c * mount_x), -(s * mount_x), dyaw])


def to_frame(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(..., 2) points of the old ego frame expressed in the frame at ``pose`` (x, y, yaw in the old)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    d = np.asarray(points, np.float64) - pose[:2]
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


def rotate_camera(image: Image.Image, dyaw: float, fov_deg: float) -> Image.Image:
    """The image of a level pinhole camera (principal point at the centre, horizontal ``fov_deg``) turned by
    ``dyaw`` (+ = left) about its own centre: the homography K R K^-1; unseen pixels are black."""
    w, h = image.size
    f = 0.5 * w / math.tan(math.radians(0.5 * fov_deg))
    k = np.array([[f, 0.0, 0.5 * w], [0.0, f, 0.5 * h], [0.0, 0.0, 1.0]])
    c, s = math.cos(dyaw), math.sin(dyaw)
    # a ray (x right, y down, z forward) of the new camera in the old camera's axes: turning the camera
    # left by dyaw moves a ray dyaw to the left, i.e. x_old = x cos - z sin, z_old = x sin + z cos
    rot = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
    hom = k @ rot @ np.linalg.inv(k)  # new pixel -> old pixel (what PIL's PERSPECTIVE asks for)
    hom /= hom[2, 2]
    coeffs = tuple(float(v) for v in hom.flatten()[:8])
    return image.transform((w, h), Image.Transform.PERSPECTIVE, coeffs, Image.Resampling.BILINEAR)


def rotate_occupancy(
    packed: np.ndarray, pose: np.ndarray, config: OccupancyConfig | None = None
) -> np.ndarray:
    """(H, W) packed occupancy (the ``merged_occupancy`` column) seen from the frame at ``pose`` (in the
    old ego frame): nearest-cell warp of every class; the old ego box's cells and cells from outside the
    old grid are empty."""
    config = config or OccupancyConfig()
    packed = np.array(packed, np.uint8)
    rows, cols = ego_box(config)
    packed[rows, cols] = 0  # hidden under the ego box in the stored image: hidden after the rotation too
    bits = ((packed[None, :, :] >> np.arange(4, dtype=np.uint8)[:, None, None]) & 1).astype(bool)
    warped = warp_to_ego(bits[None], np.zeros((1, 3)), pose[None], config)[0]  # (C, H, W)
    return pack_occupancy(warped)


def rotate_sample(
    row: dict[str, Any],
    dyaw: float,
    camera: CameraConfig | None = None,
    occupancy: OccupancyConfig | None = None,
) -> dict[str, Any]:
    """A copy of a dataset row as seen by the ego turned by ``dyaw`` [rad] (+ = left) about its camera; a
    row with a ``merged_bev`` needs its ``merged_occupancy`` grid (the BEV is re-drawn from it)."""
    if dyaw == 0.0:
        return row
    camera = camera or CameraConfig()
    pose = rotated_frame(dyaw, camera.mount_x)
    out = dict(row)
    out["camera"] = rotate_camera(_pil(row["camera"]), dyaw, camera.fov_deg)
    if row.get("merged_bev") is not None:
        if row.get("merged_occupancy") is None:
            raise ValueError("rotating the merged BEV needs its grid: load the merged_occupancy column")
        grid = rotate_occupancy(np.asarray(row["merged_occupancy"], np.uint8), pose, occupancy)
        out["merged_occupancy"] = grid
        out["merged_bev"] = Image.fromarray(packed_to_rgb(grid, occupancy))
    for key in _POINT_KEYS:
        if row.get(key) is not None:
            out[key] = to_frame(np.asarray(row[key], np.float64), pose).astype(np.float32)
    others = row.get("other_cavs")
    if others:
        arr = np.asarray(others, np.float64).reshape(-1, 4)
        moved = to_frame(arr[:, 1:3], pose)
        yaw = (arr[:, 3] - dyaw + np.pi) % (2 * np.pi) - np.pi
        out["other_cavs"] = [[a, x, y, t] for a, (x, y), t in zip(arr[:, 0], moved, yaw, strict=True)]
    return out


def _pil(image: Any) -> Image.Image:
    return image if isinstance(image, Image.Image) else Image.fromarray(np.asarray(image, np.uint8))
