"""A picture of dataset samples (``cmudrive data show DIR -o grid.png``): per sample its front camera with the
path label projected onto the road, the merged BEV it sees with the path (line) and speed waypoints (dots),
and its metadata and sentences.

Samples are chosen at random (seeded) among the shards' rows, ``count / len(types)`` per scenario type of
``types`` when given, preferring samples where the CAV is moving or the expert names a reason (4x), and
above all samples with a communication sentence (17x, they are rare), so the grid shows labels at work.
"""

from __future__ import annotations

import io
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
from PIL import Image

from cmudrive.data.shards import shard_paths
from cmudrive.sensors import CameraConfig, OccupancyConfig

PICK = ("route_id", "scenario_type", "speed", "reason", "communication")
SHOWN = (
    "route_id",
    "scenario_type",
    "weather",
    "town",
    "num_cavs",
    "cav",
    "tick",
    "camera",
    "merged_bev",
    "partner",
    "speed",
    "path",
    "speed_waypoints",
    "target_points",
    "reason",
    "commentary",
    "communication",
)


def pick_samples(
    out: Path, count: int, types: Sequence[str] | None = None, seed: int = 0
) -> list[tuple[Path, int]]:
    """(shard, row) of the samples to show (module docstring)."""
    rng = np.random.default_rng(seed)
    candidates: list[tuple[Path, int, str, float]] = []  # shard, row, type, weight
    for f in shard_paths(out):
        t = pq.read_table(f, columns=list(PICK)).to_pydict()
        for r in range(len(t["route_id"])):
            interesting = (
                t["speed"][r] > 1.0 or t["reason"][r] not in ("NONE", "ROAD") or t["communication"][r]
            )
            candidates.append((f, r, t["scenario_type"][r], 4.0 if interesting else 1.0))
    if types:
        unknown = sorted(set(types) - {c[2] for c in candidates})
        if unknown:
            raise ValueError(f"no sample of scenario type(s) {', '.join(unknown)} in {out}")
        groups = [[c for c in candidates if c[2] == t] for t in types]
        per = max(1, count // len(types))
        chosen = [_draw(g, per, rng) for g in groups]
        return [(f, r) for group in chosen for f, r, _, _ in group]
    if not candidates:
        raise ValueError(f"{out}: no sample")
    return [(f, r) for f, r, _, _ in _draw(candidates, count, rng)]


def _draw(
    items: list[tuple[Path, int, str, float]], k: int, rng: np.random.Generator
) -> list[tuple[Path, int, str, float]]:
    w = np.array([i[3] for i in items])
    idx = rng.choice(len(items), size=min(k, len(items)), replace=False, p=w / w.sum())
    return [items[i] for i in sorted(idx)]


def read_rows(picks: Sequence[tuple[Path, int]]) -> list[dict[str, Any]]:
    rows = []
    for f, r in picks:
        t = pq.read_table(f, columns=list(SHOWN)).slice(r, 1).to_pylist()[0]
        rows.append(t)
    return rows


def _image(cell: dict[str, Any]) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(cell["bytes"])).convert("RGB"))


def bev_pixels(xy: np.ndarray, config: OccupancyConfig) -> np.ndarray:
    """Ego-frame points (x forward, y left [m]) -> (column, row) pixel coordinates of the BEV image."""
    col = (config.side - xy[:, 1]) / config.resolution - 0.5
    row = (config.ahead - xy[:, 0]) / config.resolution - 0.5
    return np.stack([col, row], axis=1)


def camera_pixels(xy: np.ndarray, config: CameraConfig) -> np.ndarray:
    """Ego-frame road points (z = 0) -> (u, v) pixel coordinates of the front camera as matplotlib places
    them (pixel centres at integers; the renderer's are at + 0.5); NaN behind the camera."""
    forward = xy[:, 0] - config.mount_x
    right = -xy[:, 1]
    down = np.full(len(xy), config.mount_z)
    ok = forward > config.near
    f = config.focal
    u = np.where(ok, 0.5 * config.width + f * right / np.where(ok, forward, 1.0) - 0.5, np.nan)
    v = np.where(ok, 0.5 * config.height + f * down / np.where(ok, forward, 1.0) - 0.5, np.nan)
    return np.stack([u, v], axis=1)


def save_grid(
    out: Path,
    output: Path,
    count: int = 8,
    types: Sequence[str] | None = None,
    seed: int = 0,
    columns: int = 2,
) -> Path:
    """Draw ``count`` samples of the dataset in ``out`` into ``output`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_rows(pick_samples(out, count, types, seed))
    occ, cam = OccupancyConfig(), CameraConfig()
    grid_rows = -(-len(rows) // columns)
    # per sample: camera (2:1) beside the BEV (2:3, both rows), the text under the camera
    fig = plt.figure(figsize=(7.4 * columns, 3.3 * grid_rows + 0.3), dpi=110)
    outer = fig.add_gridspec(
        grid_rows, columns, wspace=0.06, hspace=0.12, top=0.99, bottom=0.3 / fig.get_figheight()
    )
    for k, s in enumerate(rows):
        inner = outer[k // columns, k % columns].subgridspec(
            2, 2, width_ratios=[2.4, 1.0], height_ratios=[2.55, 0.75], wspace=0.03, hspace=0.04
        )
        ax_cam = fig.add_subplot(inner[0, 0])
        ax_bev = fig.add_subplot(inner[:, 1])
        ax_txt = fig.add_subplot(inner[1, 0])
        path = np.asarray(s["path"], float)
        speed_wp = np.asarray(s["speed_waypoints"], float)
        ax_cam.imshow(_image(s["camera"]))
        uv = camera_pixels(path, cam)
        ax_cam.plot(uv[:, 0], uv[:, 1], "-", color="#00e5ff", lw=1.5)
        ax_cam.set_xlim(0, cam.width)
        ax_cam.set_ylim(cam.height, 0)
        ax_bev.imshow(_image(s["merged_bev"]))
        p = bev_pixels(path, occ)
        w = bev_pixels(speed_wp, occ)
        t = bev_pixels(np.asarray(s["target_points"], float), occ)
        ax_bev.plot(p[:, 0], p[:, 1], "-", color="#00e5ff", lw=1.5)
        ax_bev.plot(w[:, 0], w[:, 1], "o", color="#ff4fd8", ms=2.5)
        ax_bev.plot(t[:, 0], t[:, 1], "x", color="white", ms=5)
        ax_bev.set_xlim(-0.5, occ.shape[1] - 0.5)
        ax_bev.set_ylim(occ.shape[0] - 0.5, -0.5)
        partner = f", partner CAV {s['partner']}" if s["partner"] >= 0 else ""
        lines = [
            f"{s['route_id']}  CAV {s['cav']}/{s['num_cavs']}  tick {s['tick']}",
            f"{s['town']}, {s['weather']}; {s['speed']:.1f} m/s, {s['reason']}{partner}",
            *textwrap.wrap(s["commentary"], 66),
        ]
        if s["communication"]:
            lines += textwrap.wrap("Comm: " + s["communication"], 66)
        ax_txt.text(0.0, 1.0, "\n".join(lines), va="top", ha="left", fontsize=6.5, family="monospace")
        for ax in (ax_cam, ax_bev, ax_txt):
            ax.set_xticks([])
            ax.set_yticks([])
        ax_txt.axis("off")
    fig.text(
        0.5,
        0.0,
        "cyan: path label (20 points, 1 m apart)   magenta: speed waypoints (0.25 s apart)   "
        "x: next two route target points   BEV: merged occupancy (blue vehicles, red pedestrians, "
        "amber cyclists, grey static, green ego)",
        ha="center",
        va="bottom",
        fontsize=7,
    )
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(output, bbox_inches="tight")
    plt.close(fig)
    return output
