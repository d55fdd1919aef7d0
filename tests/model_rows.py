"""Hand-built dataset rows for the model tests (the columns of the V2V-VLA training set)."""

from __future__ import annotations

from typing import Any

import numpy as np
from PIL import Image


def make_row(i: int, seed: int = 0) -> dict[str, Any]:
    """Row ``i``: random camera (256 x 128) and merged BEV (128 wide x 192 tall), a straight path bending
    with ``i``, CAV 3 named as partner and the expert stopping on odd rows."""
    rng = np.random.default_rng(seed + i)
    forward = np.stack([np.arange(1, 21, dtype=float), 0.05 * i * np.arange(1, 21) ** 1.5 / 10], axis=1)
    return {
        "camera": Image.fromarray(rng.integers(0, 256, (128, 256, 3), dtype=np.uint8)),
        "merged_bev": Image.fromarray(rng.integers(0, 256, (192, 128, 3), dtype=np.uint8)),
        "speed": 2.0 + i,
        "standing": -1.0,  # [s] it moves (cmudrive.model.row.MOVING)
        "target_points": [[12.0, 0.5 * i], [35.0, -1.5 * i]],
        "other_cavs": [[3, 12.0, -3.5, 0.1], [7, 95.0, 0.0, 0.0], [2, -6.0, 1.0, 3.1]][: 1 + i % 3],
        "path": forward,
        "speed_waypoints": np.stack([np.arange(1, 11) * (0.5 + 0.2 * i), np.zeros(10)], axis=1),
        "target_speed": 0.0 if i % 2 else 2.5 + i,  # [m/s] the expert stops on odd rows
        "desired_speed": 0.0 if i % 2 else 8.0 + i,  # [m/s] what its rules allow: the speed query's target
        "commentary": ["Follow the route. Accelerate.", "Turn left. Stop now because of the red light."][
            i % 2
        ],
        "communication": "CAV 3 can see the pedestrian." if i % 2 else "",
        "partner_label": 3 if i % 2 else -1,
        "partner": 3,
    }


def rows(n: int, seed: int = 0) -> list[dict[str, Any]]:
    return [make_row(i, seed) for i in range(n)]
