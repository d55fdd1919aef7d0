"""The static layer of BEV frames: the view onto the map (:class:`BevView`) and the road plan drawn once
with matplotlib (lanes, junctions, markings, stop signs, buildings, guardrails, street lights), plus the
signal bars' places on the traffic-light stop lines. :class:`~cmudrive.viz.bev.BevRenderer` draws actors
over a copy of this layer every frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.figure import Figure

from cmudrive.maps.model import TURN_ORDER, RoadMap, StopKind, TurnDir
from cmudrive.maps.scenery import SceneryKind, StaticScenery
from cmudrive.maps.surfaces import junction_polygons, marking_lines
from cmudrive.viz.map_plot import (
    BACKGROUND,
    BUILDING_EDGE,
    JUNCTION_COLOUR,
    SCENERY_COLOURS,
    lane_polygons,
    scenery_shapes,
)

if TYPE_CHECKING:
    from matplotlib.axes import Axes

# road markings, in metres so that they scale with the zoom
EDGE_LINE_WIDTH = 0.15  # [m]
LANE_LINE_WIDTH = 0.12  # [m]
LANE_LINE_DASH = (3.0, 5.0)  # [m] dash, gap
CENTRE_LINE_WIDTH = 0.18  # [m]
STOP_LINE_WIDTH = 0.4  # [m]
ZEBRA_COLOUR = "#e9e9e9"
STOP_SIGN_RADIUS = 0.7  # [m]
STOP_SIGN_OFFSET = 1.0  # [m] beyond the right end of the stop line
STOP_SIGN_COLOUR = "#c4161c"
SIGNAL_BAR_WIDTH = 0.8  # [m] along the lane
SIGNAL_BAR_GAP = 0.2  # [m] between the parts of one stop line
POLE_RADIUS = 0.3  # [m] street lights are drawn as dots at least this large (and at least 1.5 px)
RAIL_WIDTH = 0.4  # [m] guardrail line width (at least 1 px), a little wider than the box


@dataclass(frozen=True)
class BevView:
    """The world rectangle a frame shows and its pixel grid (north up, x right)."""

    x_min: float  # [m] world x of the left image edge
    y_max: float  # [m] world y of the top image edge
    width: int  # [px]
    height: int  # [px]
    pixels_per_meter: float  # [px/m]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """xmin, ymin, xmax, ymax [m]."""
        ppm = self.pixels_per_meter
        return self.x_min, self.y_max - self.height / ppm, self.x_min + self.width / ppm, self.y_max

    def to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) world points [m] -> (..., 2) continuous image coordinates (column, row) [px]; the
        pixel (r, c) spans [c, c + 1) x [r, r + 1)."""
        xy = np.asarray(xy, dtype=np.float64)
        col = (xy[..., 0] - self.x_min) * self.pixels_per_meter
        row = (self.y_max - xy[..., 1]) * self.pixels_per_meter
        return np.stack([col, row], axis=-1)

    def pixel_index(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) world points [m] -> (..., 2) int (row, column) of the pixel containing each point."""
        cr = np.floor(self.to_pixel(xy)).astype(np.int64)
        return cr[..., ::-1]


def draw_map_layer(road_map: RoadMap, view: BevView, scenery: StaticScenery, markings: bool) -> np.ndarray:
    """(H, W, 3) uint8: the road plan of ``view`` (lanes, junctions, markings, stop signs, scenery), drawn
    once with matplotlib at 1 px per point."""
    m = road_map
    dpi = 72.0  # 1 point = 1 pixel, so line widths in points are widths in pixels
    fig = Figure(figsize=(view.width / dpi, view.height / dpi), dpi=dpi, facecolor=BACKGROUND)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_axis_off()
    xmin, ymin, xmax, ymax = view.bounds
    ax.set_xlim(xmin, xmax)
    ax.set_ylim(ymin, ymax)
    px = view.pixels_per_meter

    def lw(metres: float) -> float:
        return max(metres * px, 1.0)

    with matplotlib.rc_context({"lines.scale_dashes": False, "path.simplify": False}):
        ax.add_collection(PolyCollection(junction_polygons(m), facecolors=JUNCTION_COLOUR, linewidths=0))
        polys, colours, zebra = lane_polygons(m)
        # an edge in the fill colour closes the anti-aliasing seams between neighbouring lanes
        ax.add_collection(PolyCollection(polys, facecolors=colours, edgecolors=colours, linewidths=1.0))
        if markings:
            solid, dashed, centre, stop = marking_lines(m)
            dash = (0.0, (LANE_LINE_DASH[0] * px, LANE_LINE_DASH[1] * px))
            ax.add_collection(LineCollection(solid, colors="white", linewidths=lw(EDGE_LINE_WIDTH)))
            ax.add_collection(
                LineCollection(dashed, colors="white", linewidths=lw(LANE_LINE_WIDTH), linestyles=[dash])
            )
            ax.add_collection(LineCollection(centre, colors="#f2c40c", linewidths=lw(CENTRE_LINE_WIDTH)))
            ax.add_collection(PolyCollection(zebra, facecolors=ZEBRA_COLOUR, linewidths=0))
            ax.add_collection(LineCollection(stop, colors="white", linewidths=lw(STOP_LINE_WIDTH)))
        ax.add_collection(
            PolyCollection(
                _stop_signs(m), facecolors=STOP_SIGN_COLOUR, edgecolors="white", linewidths=lw(0.1)
            )
        )
        _draw_scenery(ax, scenery, lw, px)
        canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    if rgba.shape[:2] != (view.height, view.width):  # pragma: no cover - guards the dpi arithmetic
        raise RuntimeError(f"background is {rgba.shape[:2]}, expected {(view.height, view.width)}")
    return np.ascontiguousarray(rgba[..., :3])


def _draw_scenery(ax: Axes, scenery: StaticScenery, lw: Callable[[float], float], ppm: float) -> None:
    """Buildings filled grey-brown, guardrails as lines, street lights as dark dots."""
    areas, colours, poles, rails = scenery_shapes(scenery)
    ax.add_collection(PolyCollection(areas, facecolors=colours, edgecolors=BUILDING_EDGE, linewidths=lw(0.2)))
    ax.add_collection(
        LineCollection(rails, colors=SCENERY_COLOURS[SceneryKind.GUARDRAIL], linewidths=lw(RAIL_WIDTH))
    )
    if len(poles):
        radius = max(POLE_RADIUS * ppm, 1.5)  # [px] = [pt] at 72 dpi
        ax.scatter(
            poles[:, 0],
            poles[:, 1],
            s=(2.0 * radius) ** 2,
            c=SCENERY_COLOURS[SceneryKind.POLE],
            linewidths=0,
        )


def _stop_signs(road_map: RoadMap) -> list[np.ndarray]:
    """Octagons (8, 2) [m] beside the right end of every stop-sign and all-way-stop line."""
    m = road_map
    out = []
    angles = np.pi / 8 + np.arange(8) * np.pi / 4
    ring = STOP_SIGN_RADIUS * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    for k in np.flatnonzero(m.stop_kind != StopKind.TRAFFIC_LIGHT).tolist():
        right, left = m.stop_xy[k]
        along = (right - left) / max(float(np.linalg.norm(right - left)), 1e-9)
        out.append(right + (STOP_SIGN_OFFSET + STOP_SIGN_RADIUS) * along + ring)
    return out


def signal_bars(road_map: RoadMap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per traffic-light stop line, one bar per distinct signal of the lane's links, laid out from the
    right end of the line by turn direction (right turns right, left turns left). Returns quads
    (M, 4, 2) [m], and each bar's traffic light and signal index (M,)."""
    m = road_map
    quads: list[np.ndarray] = []
    tls_of: list[int] = []
    index_of: list[int] = []
    for k in np.flatnonzero(m.stop_kind == StopKind.TRAFFIC_LIGHT).tolist():
        lane, tls = int(m.stop_lane[k]), int(m.stop_tls[k])
        links = np.flatnonzero((m.link_from == lane) & (m.link_tls == tls))
        turn_order = [TURN_ORDER[TurnDir(int(m.link_dir[i]))] for i in links]
        links = links[np.argsort(turn_order, kind="stable")]
        signals = list(dict.fromkeys(int(m.link_tls_index[i]) for i in links))  # unique, in order
        if not signals:
            signals = [-1]
        right, left = m.stop_xy[k]
        length = float(np.linalg.norm(left - right))
        along = (left - right) / max(length, 1e-9)
        back = np.array([along[1], -along[0]])  # upstream along the lane (the line runs right to left)
        gap = SIGNAL_BAR_GAP if len(signals) > 1 else 0.0
        part = (length - gap * (len(signals) - 1)) / len(signals)
        for j, sig in enumerate(signals):
            a = right + along * j * (part + gap)
            b = a + along * part
            half = 0.5 * SIGNAL_BAR_WIDTH * back
            quads.append(np.array([a - half, b - half, b + half, a + half]))
            tls_of.append(tls)
            index_of.append(sig)
    if not quads:
        return np.zeros((0, 4, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.array(quads), np.array(tls_of), np.array(index_of)
