"""Synthetic shards in the dataset's schema, for tests and benchmarks of the training pipeline.

Every column is filled with values of the right type, shape and range (images of the camera's and the
BEV's sizes, encoded as the collector encodes them; arcs of constant curvature and speed as path and
speed-waypoint labels; sentences of the commentary templates' kind), so that reading, decoding, batching
and training run exactly as on collected data. The rows are not driving: nothing here is a measurement of
a model's driving. Collected data: ``cmudrive data collect`` (``docs/data.md``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cmudrive.data.labels import PATH_POINTS, SPEED_POINTS
from cmudrive.data.schema import COLUMNS, encode_bev, encode_image, features
from cmudrive.data.shards import ShardWriter
from cmudrive.sensors.occupancy import OccupancyConfig

_COMMENTARY = (
    "Stay on the route. Keep your speed.",
    "Stay on the route. Speed up.",
    "Turn left at the junction ahead. Slow down behind the red car ahead.",
    "Turn right at the junction ahead. Come to a stop for the red light.",
    "Stay on the route. Slow down for the pedestrian in blue ahead on the right.",
)


def synthetic_row(route_id: str, index: int, rng: np.random.Generator, num_cavs: int = 4) -> dict[str, Any]:
    """One row of ``route_id``: CAV ``index % num_cavs`` on an arc of random curvature at a random speed."""
    occ = OccupancyConfig()
    cav = index % num_cavs
    speed = float(rng.uniform(0.0, 12.0))  # [m/s]
    curvature = float(rng.uniform(-0.04, 0.04))  # [1/m]
    s = np.arange(PATH_POINTS, dtype=np.float64)  # [m]
    t = np.arange(1, SPEED_POINTS + 1) * 0.25 * speed  # [m] arc length after 0.25 s steps
    camera = np.clip(rng.normal(110, 40, (128, 256, 3)), 0, 255).astype(np.uint8)
    camera[64:] = (90, 90, 95)  # a road below the horizon
    packed = np.zeros(occ.shape, np.uint8)
    for _ in range(rng.integers(0, 6)):
        r, c = rng.integers(0, occ.shape[0] - 10), rng.integers(0, occ.shape[1] - 5)
        packed[r : r + 10, c : c + 5] = 1 << int(rng.integers(0, 4))
    partner_label = int((cav + 1) % num_cavs) if rng.random() < 0.1 else -1
    others = [
        [float(k), float(rng.uniform(-40, 60)), float(rng.uniform(-10, 10)), 0.0]
        for k in range(num_cavs)
        if k != cav
    ]
    return {
        "route_id": route_id,
        "scenario_type": "",
        "weather": "ClearNoon",
        "town": "synthetic",
        "num_cavs": num_cavs,
        "cav": cav,
        "tick": 5 * (index // num_cavs),
        "time": 0.25 * (index // num_cavs),
        "view": [0.0, 0.0, 0.0],
        "driver": "expert",
        "camera": encode_image(camera, "JPEG"),
        "occupancy": packed,
        "merged_occupancy": packed,
        "merged_bev": encode_bev(packed, occ),
        "partner": (cav + 1) % num_cavs,
        "speed": speed,
        "target_points": np.array(
            [[20.0, 20.0 * 20.0 * curvature / 2], [60.0, 60.0 * 60.0 * curvature / 2]], np.float32
        ),
        "other_cavs": others,
        "path": _arc(s, curvature),
        "speed_waypoints": _arc(t, curvature),
        "throttle": 0.5,
        "steer": float(np.clip(-2.5 * curvature * 10, -1, 1)),
        "brake": 0.0,
        "reason": "NONE",
        "object_id": "",
        "object_kind": "",
        "object_distance": float("nan"),
        "target_speed": speed,
        "desired_speed": speed,
        "commentary": _COMMENTARY[int(rng.integers(len(_COMMENTARY)))],
        "communication": f"CAV {partner_label} can see the pedestrian, which is hidden from our camera."
        if partner_label >= 0
        else "",
        "partner_label": partner_label,
        "route_action": "follow",
        "speed_action": "keep",
    }


def write_synthetic_shards(out: Path | str, routes: int, rows_per_route: int, seed: int = 0) -> list[Path]:
    """``routes`` shards ``synthetic_<k>.parquet`` of ``rows_per_route`` rows each in ``out``."""
    schema = features().arrow_schema
    paths = []
    for k in range(routes):
        rng = np.random.default_rng([seed, k])
        rows = [synthetic_row(f"synthetic_{k}", i, rng) for i in range(rows_per_route)]
        writer = ShardWriter(Path(out), f"synthetic_{k}", schema)
        writer.write({c: [r[c] for r in rows] for c in COLUMNS})
        paths.append(writer.close())
    return paths


def _arc(s: np.ndarray, curvature: float) -> np.ndarray:
    """(n, 2) points at arc lengths ``s`` [m] of a circle of ``curvature`` [1/m] (+ = left) from the origin,
    heading along x."""
    if abs(curvature) < 1e-9:
        return np.stack([s, np.zeros_like(s)], axis=1).astype(np.float32)
    r = 1.0 / curvature
    return np.stack([r * np.sin(s / r), r * (1 - np.cos(s / r))], axis=1).astype(np.float32)
