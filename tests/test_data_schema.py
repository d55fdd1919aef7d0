"""The dataset's encodings: occupancy bit masks, the BEV image, the Arrow table builder, the features."""

from __future__ import annotations

import io
import math

import datasets
import numpy as np
import pyarrow as pa
from PIL import Image

from cmudrive.data.schema import (
    COLUMNS,
    encode_bev,
    encode_image,
    features,
    pack_occupancy,
    packed_to_rgb,
    unpack_occupancy,
)
from cmudrive.data.shards import to_table
from cmudrive.sensors import OccupancyConfig, occupancy_to_rgb


def random_grids(n: int, seed: int = 0, density: float = 0.05) -> np.ndarray:
    return np.random.default_rng(seed).random((n, 4, 192, 128)) < density


def test_occupancy_bit_masks_round_trip_with_overlapping_classes() -> None:
    grids = random_grids(3, density=0.5)  # many cells hold two or more classes
    packed = pack_occupancy(grids)
    assert packed.shape == (3, 192, 128) and packed.dtype == np.uint8
    assert np.array_equal(unpack_occupancy(packed), grids)
    assert packed[grids[:, 0] & ~grids[:, 1:].any(axis=1)].tolist() == [1] * int(
        (grids[:, 0] & ~grids[:, 1:].any(axis=1)).sum()
    )


def test_bev_image_is_the_sensors_rendering() -> None:
    grids = random_grids(4, seed=1)
    expected = occupancy_to_rgb(grids)
    packed = pack_occupancy(grids)
    assert np.array_equal(packed_to_rgb(packed), expected)
    for k in range(4):  # the stored palette PNG decodes to the same RGB pixels
        stored = encode_bev(packed[k])
        decoded = datasets.Image(mode="RGB").decode_example(stored)
        assert np.array_equal(np.asarray(decoded), expected[k])


def test_camera_jpeg_is_close_to_the_image() -> None:
    """A sky-to-road gradient (what most of a camera frame is): JPEG at quality 90 is within a grey level or
    two on average (on our rendered frames: 1.1, docs/data.md)."""
    v, u = np.meshgrid(np.linspace(0.0, 1.0, 128), np.linspace(0.0, 1.0, 256), indexing="ij")
    rgb = (255 * np.clip(np.stack([v, 0.5 * v + 0.3 * u, 1.0 - v], axis=2), 0, 1)).astype(np.uint8)
    stored = encode_image(rgb, "JPEG")
    decoded = np.asarray(Image.open(io.BytesIO(stored["bytes"])).convert("RGB"))
    assert decoded.shape == (128, 256, 3)
    assert np.abs(decoded.astype(int) - rgb).mean() < 2.0
    assert len(stored["bytes"]) < rgb.nbytes / 10


def rows(n: int) -> dict[str, list]:
    rng = np.random.default_rng(3)
    grids = pack_occupancy(random_grids(n, seed=4))
    image = encode_image(np.zeros((128, 256, 3), np.uint8), "JPEG")
    return {
        "route_id": ["r"] * n,
        "scenario_type": ["Accident"] * n,
        "weather": ["ClearNoon"] * n,
        "town": ["downtown"] * n,
        "num_cavs": [3] * n,
        "cav": list(range(n)),
        "tick": [5 * i for i in range(n)],
        "time": [0.25 * i for i in range(n)],
        "view": [[0.0, 0.0, 0.0], [0.0, 1.0, 0.1], [0.0, 0.0, 0.0]][:n],
        "driver": ["expert", "v2v-vla", "expert"][:n],
        "camera": [image] * n,
        "occupancy": list(grids),
        "merged_occupancy": list(grids[::-1]),
        "merged_bev": [encode_bev(g) for g in grids],
        "partner": [-1, 1, 0][:n],
        "speed": rng.random(n).tolist(),
        "target_points": list(rng.random((n, 2, 2)).astype(np.float32)),
        "other_cavs": [[[1.0, 2.0, 3.0, 0.1]], [], [[0.0, -4.0, 1.0, 3.0], [2.0, 5.0, 5.0, 0.0]]][:n],
        "path": list(rng.random((n, 20, 2)).astype(np.float32)),
        "speed_waypoints": list(rng.random((n, 10, 2)).astype(np.float32)),
        "throttle": [0.5] * n,
        "steer": [0.0] * n,
        "brake": [0.0] * n,
        "reason": ["NONE", "RED_LIGHT", "PEDESTRIAN"][:n],
        "object_id": ["", "", "ped3"][:n],
        "object_kind": ["", "", "PEDESTRIAN"][:n],
        "object_distance": [math.nan, 12.0, 7.5][:n],
        "target_speed": [8.0] * n,
        "desired_speed": [8.3] * n,
        "commentary": ["Stay on the route. Keep the current speed."] * n,
        "communication": [
            "",
            "",
            "CAV 0 can see the pedestrian in red ahead, which is hidden from our camera.",
        ][:n],
        "partner_label": [-1, -1, 0][:n],
        "route_action": ["follow"] * n,
        "speed_action": ["keep"] * n,
    }


def test_table_builder_matches_datasets_from_dict() -> None:
    f = features()
    data = rows(3)
    ours = to_table(data, f.arrow_schema)
    theirs = datasets.Dataset.from_dict(data, features=f).data.table
    assert ours.schema.equals(theirs.schema, check_metadata=True)
    assert datasets.Features.from_arrow_schema(ours.schema) == f  # the metadata gives the features back
    assert ours.column_names == list(COLUMNS)
    for name in COLUMNS:  # (to_pylist: NaN == NaN in Python's list equality of the same object is not
        a, b = ours.column(name).to_pylist(), theirs.column(name).to_pylist()  # guaranteed: compare as text)
        assert repr(a) == repr(b), name


def test_features_cover_the_columns_with_their_shapes() -> None:
    f = features(OccupancyConfig(ahead=32.0, behind=16.0, side=16.0))
    assert list(f) == list(COLUMNS)
    assert f.arrow_schema.field("occupancy").type == pa.list_(pa.list_(pa.uint8(), 64), 96)
    assert f.arrow_schema.field("path").type == pa.list_(pa.list_(pa.float32(), 2), 20)
    assert f.arrow_schema.field("speed_waypoints").type == pa.list_(pa.list_(pa.float32(), 2), 10)
    assert isinstance(f["camera"], datasets.Image) and f["merged_bev"].mode == "RGB"
    assert f.arrow_schema.field("other_cavs").type == pa.list_(pa.list_(pa.float32(), 4))
