"""One video frame of what a CAV perceives: front camera | own occupancy | merged occupancy | BEV.

Every panel is scaled (nearest neighbour, so cells stay crisp) to a common height and labelled; the
occupancy panels are :func:`cmudrive.sensors.occupancy_to_rgb` images (ego driving up, vehicles blue,
pedestrians red, cyclists amber, static grey, the ego green).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from PIL import Image, ImageDraw

PANEL_HEIGHT = 256  # [px]
GAP = 4  # [px] between panels
LABEL_BG = (0, 0, 0)
LABEL_FG = (255, 255, 255)


def _scaled(image: np.ndarray, height: int) -> Image.Image:
    h, w = image.shape[:2]
    width = max(1, round(w * height / h))
    return Image.fromarray(np.ascontiguousarray(image)).resize((width, height), Image.Resampling.NEAREST)


def sensor_row(panels: Sequence[tuple[str, np.ndarray | None]], height: int = PANEL_HEIGHT) -> np.ndarray:
    """Panels (label, (H, W, 3) uint8 image or None to skip) side by side at ``height`` px, labelled in
    their top-left corners; returns (height, total width, 3) uint8."""
    images = [(label, _scaled(img, height)) for label, img in panels if img is not None]
    if not images:
        raise ValueError("sensor_row needs at least one image")
    width = sum(im.width for _, im in images) + GAP * (len(images) - 1)
    canvas = Image.new("RGB", (width, height), (40, 40, 40))
    draw = ImageDraw.Draw(canvas)
    x = 0
    for label, im in images:
        canvas.paste(im, (x, 0))
        if label:
            box = draw.textbbox((x + 4, 3), label)
            draw.rectangle((box[0] - 2, box[1] - 1, box[2] + 2, box[3] + 1), fill=LABEL_BG)
            draw.text((x + 4, 3), label, fill=LABEL_FG)
        x += im.width + GAP
    return np.asarray(canvas).copy()


def stack_rows(rows: Sequence[np.ndarray]) -> np.ndarray:
    """Rows of possibly different widths stacked top to bottom, padded on the right with dark grey."""
    width = max(r.shape[1] for r in rows)
    out = np.full((sum(r.shape[0] for r in rows) + GAP * (len(rows) - 1), width, 3), 40, np.uint8)
    y = 0
    for r in rows:
        out[y : y + r.shape[0], : r.shape[1]] = r
        y += r.shape[0] + GAP
    return out
