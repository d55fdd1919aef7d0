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
from cmudrive.sensors import NUM_CLASSES, OccupancyClass, OccupancyConfig
from cmudrive.sensors.occupancy import BACKGROUND_COLOUR, CLASS_COLOURS, EGO_COLOUR

if TYPE_CHECKING:
    import datasets

CAMERA_FORMAT = "JPEG"
JPEG_QUALITY = 90  # [-] PIL's scale; see docs/data.md for the size / speed / error trade-off
PNG_COMPRESS_LEVEL = 1  # zlib level for the BEV PNGs: level 6 saves ~10 % more at ~3x the time

METADATA = ("route_id", "scenario_type", "weather", "town", "num_cavs", "cav", "tick", "time")
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


def pack_occupancy(grid: np.ndarray) -> np.ndarray:
    """(..., C, H, W) bool -> (..., H, W) uint8, bit k set where class k is occupied."""
    grid = np.asarray(grid, bool)
    out = np.zeros(grid.shape[:-3] + grid.shape[-2:], np.uint8)
    for k in range(grid.shape[-3]):
        out |= grid[..., k, :, :].astype(np.uint8) << k
    return out


def unpack_occupancy(packed: np.ndarray, num_classes: int = NUM_CLASSES) -> np.ndarray:
    """(..., H, W) uint8 bit masks -> (..., C, H, W) bool (the sensors' layout)."""
    packed = np.asarray(packed, np.uint8)
    bits = np.arange(num_classes, dtype=np.uint8).reshape((num_classes, 1, 1))
    return ((packed[..., None, :, :] >> bits) & 1).astype(bool)


EGO_INDEX = 1 << NUM_CLASSES  # palette index of the ego's own box in the BEV image


def _palette() -> np.ndarray:
    """(2^C + 1, 3) uint8: the colour of each packed cell value as ``occupancy_to_rgb`` paints it (the class
    drawn last wins: static, cyclist, pedestrian, then vehicle), and the ego's colour at EGO_INDEX."""
    lut = np.empty((EGO_INDEX + 1, 3), np.uint8)
    lut[:] = BACKGROUND_COLOUR
    order = (OccupancyClass.STATIC, OccupancyClass.CYCLIST, OccupancyClass.PEDESTRIAN, OccupancyClass.VEHICLE)
    for code in range(EGO_INDEX):
        for k in order:
            if code >> int(k) & 1:
                lut[code] = CLASS_COLOURS[k]
    lut[EGO_INDEX] = EGO_COLOUR
    return lut


PALETTE = _palette()


def bev_indices(packed: np.ndarray, config: OccupancyConfig | None = None) -> np.ndarray:
    """(..., H, W) packed occupancy -> palette indices (uint8) with the ego's 4.9 x 2.1 m box drawn."""
    config = config or OccupancyConfig()
    index = np.array(packed, np.uint8)
    xs, ys = config.cell_centres()
    rows = np.flatnonzero(np.abs(xs) <= 2.45)  # the box of cmudrive.sensors.occupancy_to_rgb
    cols = np.flatnonzero(np.abs(ys) <= 1.05)
    index[..., rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1] = EGO_INDEX
    return index


def packed_to_rgb(packed: np.ndarray, config: OccupancyConfig | None = None) -> np.ndarray:
    """(..., H, W) packed occupancy -> (..., H, W, 3) uint8: the image ``occupancy_to_rgb`` draws of the
    unpacked grids (ego box included)."""
    return PALETTE[bev_indices(packed, config)]


def encode_bev(packed: np.ndarray, config: OccupancyConfig | None = None) -> dict[str, bytes | None]:
    """(H, W) packed merged occupancy -> the ``datasets.Image`` storage of its RGB rendering, as a palette
    PNG: one byte per pixel to compress instead of three, and the same pixels once decoded as RGB."""
    image = Image.fromarray(bev_indices(packed, config), mode="L")
    image.putpalette(PALETTE.tobytes())
    buf = io.BytesIO()
    image.save(buf, "PNG", compress_level=PNG_COMPRESS_LEVEL)
    return {"bytes": buf.getvalue(), "path": None}
