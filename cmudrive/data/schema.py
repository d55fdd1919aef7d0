"""The dataset's columns (one row per CAV per sample tick), their Hugging Face ``datasets`` features, and the
encoding of images and occupancy grids (``docs/data.md`` documents every column).

Images are stored encoded (``datasets.Image``: a struct of the file bytes and a null path): the camera as
JPEG (``CAMERA_FORMAT``, quality ``JPEG_QUALITY``; ``docs/data.md`` has the size and speed measurements
behind the choice), the merged BEV as PNG (flat colours, lossless and small). Occupancy grids are ``(H, W)``
uint8 arrays with one bit per class (bit k = :class:`~cmudrive.sensors.OccupancyClass` k: 1 vehicle,
2 pedestrian, 4 cyclist, 8 static), so overlapping classes survive; :func:`unpack_occupancy` turns them
back into the sensors' ``(4, H, W)`` bool layout.

Fixed-shape arrays (grids, waypoints) are nested fixed-size lists (``datasets.List(..., length=...)``):
plain Arrow types, so the features' Arrow schema (with the ``huggingface`` metadata that gives
``load_dataset`` the features back) pickles to a worker that writes shards without importing ``datasets``
(a ~1 s import per route's fresh process); ``with_format("numpy")`` returns them as ``(n, H, W)`` arrays.
"""

from __future__ import annotations

import io
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image

from cmudrive.data.labels import PATH_POINTS, SPEED_POINTS
from cmudrive.sensors import NUM_CLASSES, OccupancyConfig
from cmudrive.sensors.occupancy import PALETTE, occupancy_codes
from cmudrive.sensors.occupancy import pack_occupancy as pack_occupancy  # the bit masks live with the
from cmudrive.sensors.occupancy import packed_to_rgb as packed_to_rgb  # sensors' image: one palette

if TYPE_CHECKING:
    import datasets

CAMERA_FORMAT = "JPEG"
JPEG_QUALITY = 90  # [-] PIL's scale; see docs/data.md for the size / speed / error trade-off
PNG_COMPRESS_LEVEL = 1  # zlib level for the BEV PNGs: level 6 saves ~10 % more at ~3x the time

EXPERT_DRIVER = "expert"  # the driver column of rows whose states the expert drove into itself
METADATA = (
    "route_id",
    "scenario_type",
    "weather",
    "town",
    "num_cavs",
    "cav",
    "tick",
    "time",
    "view",
    "driver",
)
INPUTS = (
    "camera",
    "occupancy",
    "merged_occupancy",
    "merged_bev",
    "partner",
    "speed",
    "target_points",
    "other_cavs",
)
LABELS = (
    "path",
    "speed_waypoints",
    "throttle",
    "steer",
    "brake",
    "reason",
    "object_id",
    "object_kind",
    "object_distance",
    "target_speed",
    "desired_speed",
)
LANGUAGE = ("commentary", "communication", "partner_label", "route_action", "speed_action")
COLUMNS = METADATA + INPUTS + LABELS + LANGUAGE


def features(occupancy: OccupancyConfig | None = None) -> datasets.Features:
    """The ``datasets.Features`` of a shard, for the occupancy grid size of ``occupancy``."""
    import datasets

    h, w = (occupancy or OccupancyConfig()).shape
    f32, i32, text = datasets.Value("float32"), datasets.Value("int32"), datasets.Value("string")

    def array(rows: int, cols: int, dtype: str) -> datasets.List:
        return datasets.List(datasets.List(datasets.Value(dtype), length=cols), length=rows)

    spec = {
        "route_id": text,
        "scenario_type": text,
        "weather": text,
        "town": text,
        "num_cavs": i32,
        "cav": i32,
        "tick": i32,
        "time": f32,
        "view": datasets.List(f32, length=3),  # x, y [m], yaw [rad] of the view in the CAV's frame
        "driver": text,  # who drove: "expert", else the agent whose states the expert labelled
        "camera": datasets.Image(),
        "occupancy": array(h, w, "uint8"),
        "merged_occupancy": array(h, w, "uint8"),
        "merged_bev": datasets.Image(mode="RGB"),  # stored as a palette PNG, decoded to RGB
        "partner": i32,
        "speed": f32,
        "target_points": array(2, 2, "float32"),
        "other_cavs": datasets.List(datasets.List(f32, length=4)),
        "path": array(PATH_POINTS, 2, "float32"),
        "speed_waypoints": array(SPEED_POINTS, 2, "float32"),
        "throttle": f32,
        "steer": f32,
        "brake": f32,
        "reason": text,
        "object_id": text,
        "object_kind": text,
        "object_distance": f32,
        "target_speed": f32,
        "desired_speed": f32,
        "commentary": text,
        "communication": text,
        "partner_label": i32,
        "route_action": text,
        "speed_action": text,
    }
    assert tuple(spec) == COLUMNS
    return datasets.Features(spec)


def encode_image(rgb: np.ndarray, fmt: str) -> dict[str, bytes | None]:
    """(H, W, 3) uint8 -> the ``datasets.Image`` storage of the encoded file."""
    buf = io.BytesIO()
    image = Image.fromarray(rgb)
    if fmt == "JPEG":
        image.save(buf, "JPEG", quality=JPEG_QUALITY)
    elif fmt == "PNG":
        image.save(buf, "PNG", compress_level=PNG_COMPRESS_LEVEL)
    else:
        raise ValueError(f"image format {fmt!r}: use JPEG or PNG")
    return {"bytes": buf.getvalue(), "path": None}


def unpack_occupancy(packed: np.ndarray, num_classes: int = NUM_CLASSES) -> np.ndarray:
    """(..., H, W) uint8 bit masks -> (..., C, H, W) bool (the sensors' layout)."""
    packed = np.asarray(packed, np.uint8)
    bits = np.arange(num_classes, dtype=np.uint8).reshape((num_classes, 1, 1))
    return ((packed[..., None, :, :] >> bits) & 1).astype(bool)


def encode_bev(packed: np.ndarray, config: OccupancyConfig | None = None) -> dict[str, bytes | None]:
    """(H, W) packed merged occupancy -> the ``datasets.Image`` storage of its RGB rendering, as a palette
    PNG: one byte per pixel to compress instead of three, and the same pixels once decoded as RGB."""
    image = Image.fromarray(occupancy_codes(packed, config), mode="L")
    image.putpalette(PALETTE.tobytes())
    buf = io.BytesIO()
    image.save(buf, "PNG", compress_level=PNG_COMPRESS_LEVEL)
    return {"bytes": buf.getvalue(), "path": None}
