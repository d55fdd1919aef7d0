"""Draw a :class:`RoadMap` (and optionally a route) as a top-down road plan with matplotlib.

Lanes are filled polygons (centreline offset by half the width), coloured by kind; markings follow
road practice: solid white road edges, dashed white lines between same-direction lanes, a solid yellow
centre line between opposite directions, white stop lines, zebra crossings; traffic lights are drawn as
signal heads at their stop lines (in the colour of the program's first phase), stop signs as red
octagons beside the line.

The geometry (lane polygons and colours, crossing stripes, marking polylines, signal colours) comes from
small public helpers that the fast BEV renderer (:mod:`cmudrive.viz.bev`) shares.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from cmudrive.maps.model import LaneKind, RoadMap, StopKind
from cmudrive.maps.scenery import SceneryKind, StaticScenery
from cmudrive.maps.surfaces import (
    junction_polygons,
    lane_polygon,
    marking_lines,
    zebra_stripes,
)

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from cmudrive.maps.routing import Route

LANE_COLOURS = {
    LaneKind.DRIVING: "#5a5a5a",
    LaneKind.SIDEWALK: "#c9c2b5",
    LaneKind.BIKE: "#5f8f6a",
    LaneKind.PARKING: "#6f6f80",
    LaneKind.SHOULDER: "#807a70",
    LaneKind.WALKINGAREA: "#c9c2b5",
}
JUNCTION_COLOUR = "#5a5a5a"
BACKGROUND = "#d9e6cf"
SIGNAL_COLOURS = {
    "r": "#e0271f",
    "y": "#f2c40c",
    "g": "#35b23a",
    "G": "#35b23a",
    "s": "#e0271f",
    "u": "#f2a20c",
}
SIGNAL_UNKNOWN = "#999999"  # off ('o', 'O') or an unknown state character
SCENERY_COLOURS = {  # fill colours of static scenery footprints
    SceneryKind.BUILDING: "#a89580",  # grey-brown
    SceneryKind.WALL: "#8c8173",
    SceneryKind.POLE: "#3b3b3b",
    SceneryKind.GUARDRAIL: "#4f5a63",  # dark slate, to stand out beside the white edge line
    SceneryKind.TREE: "#3f7a3a",
    SceneryKind.OBJECT: "#7a6a8c",
}
BUILDING_EDGE = "#6e5f50"


def signal_colour(char: str) -> str:
    """Colour of a SUMO signal state character (r y g G s u; anything else, e.g. off 'o'/'O', is grey)."""
    return SIGNAL_COLOURS.get(char, SIGNAL_UNKNOWN)


def lane_polygons(m: RoadMap) -> tuple[list[np.ndarray], list[str], list[np.ndarray]]:
    """Lane surfaces in drawing order (pavements first, roads on top): polygons (n, 2) [m], their colours,
    and the zebra stripes (4, 2) [m] of the crossings (crossings have no surface polygon of their own)."""
    polys: list[np.ndarray] = []
    colours: list[str] = []
    zebra: list[np.ndarray] = []
    order = np.argsort(m.lane_kind == LaneKind.DRIVING, kind="stable")
    for lane in order.tolist():
        kind = LaneKind(int(m.lane_kind[lane]))
        if kind == LaneKind.CROSSING:
            zebra.extend(zebra_stripes(m, lane))
            continue
        poly = m.polyline(lane) if kind == LaneKind.WALKINGAREA else lane_polygon(m, lane)
        if len(poly) >= 3:
            polys.append(poly)
            colours.append(LANE_COLOURS[kind])
    return polys, colours, zebra


class SceneryShapes(NamedTuple):
    """Static scenery as drawing primitives [m]."""

    areas: list[np.ndarray]  # (4, 2) footprints of buildings, walls, trees, objects
    area_colours: list[str]
    poles: np.ndarray  # (p, 2) centres of poles
    rails: list[np.ndarray]  # (2, 2) guardrail segments, end to end along the box's length axis


def scenery_shapes(scenery: StaticScenery) -> SceneryShapes:
    """Buildings (and other footprints) as filled quadrilaterals, poles as points, guardrails as lines."""
    corners = scenery.corners()  # (S, 4, 2)
    pole = scenery.kind == SceneryKind.POLE
    rail = scenery.kind == SceneryKind.GUARDRAIL
    area = ~pole & ~rail
    half = (
        0.5
        * scenery.length[rail, None]
        * np.column_stack([np.cos(scenery.yaw[rail]), np.sin(scenery.yaw[rail])])
    )
    centre = np.column_stack([scenery.x[rail], scenery.y[rail]])
    rails = list(np.stack([centre - half, centre + half], axis=1))
    colours = [SCENERY_COLOURS[SceneryKind(int(k))] for k in scenery.kind[area]]
    return SceneryShapes(
        list(corners[area]), colours, np.column_stack([scenery.x[pole], scenery.y[pole]]), rails
    )


def draw_scenery(scenery: StaticScenery, ax: Axes) -> None:
    """Draw static scenery above the road plan (buildings filled, poles as dots, guardrails as lines)."""
    areas, colours, poles, rails = scenery_shapes(scenery)
    ax.add_collection(
        PolyCollection(areas, facecolors=colours, edgecolors=BUILDING_EDGE, linewidths=0.3, zorder=5)
    )
    ax.add_collection(
        LineCollection(rails, colors=SCENERY_COLOURS[SceneryKind.GUARDRAIL], linewidths=0.8, zorder=5)
    )
    if len(poles):
        ax.scatter(
            poles[:, 0], poles[:, 1], s=1.5, c=SCENERY_COLOURS[SceneryKind.POLE], linewidths=0, zorder=5
        )


def draw_map(m: RoadMap, ax: Axes, markings: bool = True, signals: bool = True) -> None:
    """Draw the road plan of ``m`` onto ``ax`` (equal aspect, metres)."""
    ax.set_facecolor(BACKGROUND)
    junction_polys = junction_polygons(m)
    ax.add_collection(PolyCollection(junction_polys, facecolors=JUNCTION_COLOUR, edgecolors="none", zorder=1))
    polys, colours, zebra = lane_polygons(m)
    ax.add_collection(PolyCollection(polys, facecolors=colours, edgecolors=colours, linewidths=0.2, zorder=2))
    if markings:
        _draw_markings(m, ax)
        ax.add_collection(PolyCollection(zebra, facecolors="white", edgecolors="none", zorder=4))
    if signals:
        _draw_controls(m, ax)
    xmin, ymin, xmax, ymax = m.bounds
    pad = 10.0
    ax.set_xlim(xmin - pad, xmax + pad)
    ax.set_ylim(ymin - pad, ymax + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def _draw_markings(m: RoadMap, ax: Axes) -> None:
    solid, dashed, centre, stop = marking_lines(m)
    ax.add_collection(LineCollection(solid, colors="white", linewidths=0.6, zorder=3))
    ax.add_collection(
        LineCollection(dashed, colors="white", linewidths=0.5, linestyles=(0, (4, 6)), zorder=3)
    )
    ax.add_collection(LineCollection(centre, colors="#f2c40c", linewidths=0.7, zorder=3))
    ax.add_collection(LineCollection(stop, colors="white", linewidths=1.4, zorder=4))


def _draw_controls(m: RoadMap, ax: Axes) -> None:
    lights = m.stop_kind == StopKind.TRAFFIC_LIGHT
    if np.any(lights):
        centres = m.stop_xy[lights].mean(axis=1)
        colours = []
        for k in np.flatnonzero(lights).tolist():
            tls, lane = int(m.stop_tls[k]), int(m.stop_lane[k])
            _, states = m.tls_phases(tls)
            links = np.flatnonzero((m.link_from == lane) & (m.link_tls == tls))
            char = str(states[0])[int(m.link_tls_index[links[0]])] if len(states) and len(links) else "r"
            colours.append(signal_colour(char))
        ax.scatter(
            centres[:, 0], centres[:, 1], s=14, c=colours, edgecolors="black", linewidths=0.4, zorder=6
        )
    signs = m.stop_kind != StopKind.TRAFFIC_LIGHT
    if np.any(signs):
        right_end = m.stop_xy[signs, 0]
        ax.scatter(
            right_end[:, 0],
            right_end[:, 1],
            s=22,
            marker="8",
            c="#c4161c",
            edgecolors="white",
            linewidths=0.5,
            zorder=6,
        )


def draw_route(ax: Axes, route: Route, colour: str = "#1f77e4", label: str | None = "route") -> None:
    ax.plot(route.xy[:, 0], route.xy[:, 1], color=colour, linewidth=2.0, alpha=0.85, zorder=7, label=label)
    (x0, y0), (x1, y1) = route.xy[0], route.xy[-1]
    ax.scatter(x0, y0, s=50, marker="o", color=colour, edgecolors="black", zorder=8)
    ax.scatter(x1, y1, s=80, marker="*", color=colour, edgecolors="black", zorder=8)


def legend_handles() -> list[Patch | Line2D]:
    return [
        Patch(color=LANE_COLOURS[LaneKind.DRIVING], label="driving lane / junction"),
        Patch(color=LANE_COLOURS[LaneKind.SIDEWALK], label="sidewalk"),
        Patch(color=LANE_COLOURS[LaneKind.PARKING], label="parking lane"),
        Patch(color=LANE_COLOURS[LaneKind.BIKE], label="bike lane"),
        Patch(color=SCENERY_COLOURS[SceneryKind.BUILDING], label="building"),
        Line2D([], [], color=SCENERY_COLOURS[SceneryKind.GUARDRAIL], label="guardrail"),
        Line2D([], [], color="#f2c40c", label="centre line (two-way)"),
        Line2D(
            [],
            [],
            marker="o",
            linestyle="",
            markerfacecolor=SIGNAL_COLOURS["G"],
            markeredgecolor="black",
            label="traffic light (phase 0)",
        ),
        Line2D(
            [],
            [],
            marker="8",
            linestyle="",
            markerfacecolor="#c4161c",
            markeredgecolor="white",
            label="stop sign / all-way stop",
        ),
    ]


def save_map_figure(
    m: RoadMap,
    out: str | Path,
    route: Route | None = None,
    title: str | None = None,
    dpi: int = 200,
    scenery: StaticScenery | bool = True,
) -> Path:
    """Render ``m`` (and ``route``) to a PNG; the figure scales with the map so lanes stay legible.
    ``scenery``: the static scenery to draw, True for the map's own (:func:`cmudrive.maps.load_scenery`),
    False for none."""
    if scenery is True:
        from cmudrive.maps.cache import load_scenery

        scenery = load_scenery(m)
    xmin, ymin, xmax, ymax = m.bounds
    width, height = max(xmax - xmin, 1.0), max(ymax - ymin, 1.0)
    scale = min(24.0 / width, 24.0 / height, 0.05)  # inches per metre
    fig, ax = plt.subplots(figsize=(max(width * scale, 6.0), max(height * scale, 6.0)))
    draw_map(m, ax)
    if isinstance(scenery, StaticScenery) and len(scenery):
        draw_scenery(scenery, ax)
        corners = scenery.corners().reshape(-1, 2)
        pad = 10.0  # [m], as draw_map's
        ax.set_xlim(min(xmin, corners[:, 0].min()) - pad, max(xmax, corners[:, 0].max()) + pad)
        ax.set_ylim(min(ymin, corners[:, 1].min()) - pad, max(ymax, corners[:, 1].max()) + pad)
    if route is not None:
        draw_route(ax, route)
    ax.set_title(title or f"{m.name}")
    ax.legend(handles=legend_handles(), loc="upper right", fontsize=7, framealpha=0.9)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return out
