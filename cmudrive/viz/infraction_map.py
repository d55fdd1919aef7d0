"""Where infractions happened: a town's road plan (:func:`cmudrive.viz.map_plot.draw_map`) with one marker
per infraction record, its shape naming the kind and its colour the run (or group of runs) it came from.

The comparison report draws one such map per town. Places are the records' map-frame ``x``, ``y`` (the
frame the road plan is drawn in); a record without a finite place is not drawn and is counted apart. A
minimum-speed record is not an infraction (it costs nothing) and is drawn hollow, labelled "too slow".
The view is cut to the area around the markers, so that a few infractions in a large town stay visible.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from matplotlib.artist import Artist
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from cmudrive.viz.map_plot import draw_map

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from cmudrive.maps.model import RoadMap

# infraction key -> (matplotlib marker, legend text), in legend order
KIND_MARKERS: dict[str, tuple[str, str]] = {
    "collisions_vehicle": ("X", "collision: vehicle"),
    "collisions_pedestrian": ("P", "collision: pedestrian"),
    "collisions_layout": ("D", "collision: layout"),
    "red_light": ("^", "red light"),
    "stop_infraction": ("8", "stop sign"),
    "outside_route_lanes": ("p", "outside route lanes"),
    "yield_emergency_vehicle_infractions": ("<", "no yield to emergency vehicle"),
    "scenario_timeouts": ("h", "scenario timeout"),
    "route_dev": (">", "route deviation"),
    "vehicle_blocked": ("s", "blocked"),
    "route_timeout": ("*", "route timeout"),
    "min_speed_infractions": ("v", "too slow (min. speed, no penalty)"),
}
HOLLOW = frozenset({"min_speed_infractions"})  # drawn as outlines: recorded, not penalised
GROUP_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2")
MARKER_SIZE = 80.0  # [pt^2] an infraction
HOLLOW_SIZE = 40.0  # [pt^2] a min-speed record: smaller, it is no infraction
MARGIN = 40.0  # [m] around the markers
MIN_SPAN = 160.0  # [m] shortest side of the view
MIN_ASPECT, MAX_ASPECT = 0.55, 1.2  # [-] height / width of the view
DPI = 110  # [dots/inch]
AXES_WIDTH = 6.5  # [in] of the map; its height follows the view's aspect
LEGEND_WIDTH = 3.0  # [in] beside it
GID_PREFIX = "infraction:"  # gid of each marker collection: infraction:<key>:<group index>


@dataclass(frozen=True)
class InfractionPoint:
    """One infraction record to draw."""

    group: int  # index of the run group (colour)
    key: str  # infraction key (marker)
    x: float  # map frame [m]
    y: float  # map frame [m]


def group_colour(group: int) -> str:
    return GROUP_COLOURS[group % len(GROUP_COLOURS)]


def draw_infractions(ax: Axes, points: Sequence[InfractionPoint]) -> dict[tuple[int, str], int]:
    """Scatter ``points`` onto ``ax`` (one collection per group and kind, gid ``infraction:<key>:<group>``);
    returns the markers drawn per (group, key). Points without a finite place are skipped."""
    counts: dict[tuple[int, str], list[tuple[float, float]]] = {}
    for p in points:
        if math.isfinite(p.x) and math.isfinite(p.y):
            counts.setdefault((p.group, p.key), []).append((p.x, p.y))
    order = list(KIND_MARKERS)
    for (group, key), xy in sorted(counts.items(), key=lambda kv: (_rank(order, kv[0][1]), kv[0][0])):
        marker = KIND_MARKERS.get(key, ("o", key))[0]
        colour = group_colour(group)
        hollow = key in HOLLOW
        ax.scatter(
            [p[0] for p in xy],
            [p[1] for p in xy],
            s=HOLLOW_SIZE if hollow else MARKER_SIZE,
            marker=marker,
            facecolors="none" if hollow else colour,
            edgecolors=colour if hollow else "white",
            linewidths=1.1 if hollow else 0.7,
            alpha=0.75 if hollow else 0.95,
            zorder=10 if hollow else 11,
            gid=f"{GID_PREFIX}{key}:{group}",
        )
    return {k: len(v) for k, v in counts.items()}


def _rank(order: list[str], key: str) -> int:
    return order.index(key) if key in order else len(order)


def legend_handles(counts: dict[tuple[int, str], int], labels: Sequence[str]) -> list[Artist]:
    """Legend entries: a colour patch per group drawn (its label), then a marker per kind drawn (grey)."""
    handles: list[Artist] = [
        Patch(color=group_colour(g), label=labels[g]) for g in sorted({g for g, _ in counts})
    ]
    for key in sorted({k for _, k in counts}, key=lambda k: _rank(list(KIND_MARKERS), k)):
        marker, text = KIND_MARKERS.get(key, ("o", key))
        hollow = key in HOLLOW
        handles.append(
            Line2D(
                [],
                [],
                marker=marker,
                linestyle="",
                markersize=8,
                label=text,
                markerfacecolor="none" if hollow else "0.35",
                markeredgecolor="0.35",
            )
        )
    return handles


def focus(ax: Axes, road_map: RoadMap, points: Sequence[InfractionPoint]) -> None:
    """Limit the view to the markers plus ``MARGIN`` (at least ``MIN_SPAN`` square), inside the map."""
    xy = [(p.x, p.y) for p in points if math.isfinite(p.x) and math.isfinite(p.y)]
    if not xy:
        return
    xs, ys = [p[0] for p in xy], [p[1] for p in xy]
    xmin, ymin, xmax, ymax = road_map.bounds
    lo_x, hi_x = _span(min(xs), max(xs), xmin, xmax)
    lo_y, hi_y = _span(min(ys), max(ys), ymin, ymax)
    # a view far wider than tall (or the reverse) leaves the figure mostly blank: widen the short side
    dx, dy = hi_x - lo_x, hi_y - lo_y
    if dy < MIN_ASPECT * dx:
        lo_y, hi_y = lo_y - 0.5 * (MIN_ASPECT * dx - dy), hi_y + 0.5 * (MIN_ASPECT * dx - dy)
    elif dy > MAX_ASPECT * dx:
        lo_x, hi_x = lo_x - 0.5 * (dy / MAX_ASPECT - dx), hi_x + 0.5 * (dy / MAX_ASPECT - dx)
    ax.set_xlim(lo_x, hi_x)
    ax.set_ylim(lo_y, hi_y)


def _span(lo: float, hi: float, bound_lo: float, bound_hi: float) -> tuple[float, float]:
    lo, hi = lo - MARGIN, hi + MARGIN
    if hi - lo < MIN_SPAN:
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 0.5 * MIN_SPAN, mid + 0.5 * MIN_SPAN
    return max(lo, bound_lo - MARGIN), min(hi, bound_hi + MARGIN)


def save_infraction_map(
    path: str | Path,
    road_map: RoadMap,
    points: Sequence[InfractionPoint],
    labels: Sequence[str],
    title: str,
) -> dict[tuple[int, str], int]:
    """Draw ``road_map`` with ``points`` (``labels[g]``: group ``g``'s name in the legend) to a PNG;
    returns the markers drawn per (group, key)."""
    fig = Figure(dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    draw_map(road_map, ax)
    counts = draw_infractions(ax, points)
    focus(ax, road_map, points)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    aspect = (y1 - y0) / max(x1 - x0, 1.0)
    fig.set_size_inches(AXES_WIDTH + LEGEND_WIDTH, AXES_WIDTH * aspect + 0.8)
    ax.set_title(title)
    if counts:
        ax.legend(
            handles=legend_handles(counts, labels),
            loc="upper left",
            bbox_to_anchor=(1.01, 1.0),
            fontsize=8,
            frameon=False,
            title="colour: run · shape: kind",
            title_fontsize=8,
        )
    fig.savefig(path, dpi=DPI, bbox_inches="tight", pad_inches=0.1)  # tight: the legend beside the map
    return counts
