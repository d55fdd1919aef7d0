"""Draw one route like the paper's Figure 1: the map around it, each CAV's path as a solid arrow from start
to destination labelled with its id, the scenario's trigger point, and what the scenario will spawn
(actors as boxes at their planned poses, markers for cones, signs, patches and forced lights) and how it
moves (dashed arrows: a crosser's path, a cut-in, a flow from source to sink, an emergency vehicle's
approach).

The scenario items come from the scenarios themselves (:meth:`Scenario.plan`, placed by
:func:`cmudrive.bench.scenarios.plan_scenarios` as the evaluator places them), so the picture shows what
a run will do, not a second computation of it.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Polygon

from cmudrive.bench.scenarios import PlanItem, PlanPath, PlanPoint, plan_scenarios
from cmudrive.maps import RoadMap, Route, load_map
from cmudrive.maps.cache import load_scenery
from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.viz.bev import cav_colour
from cmudrive.viz.map_plot import draw_map, draw_scenery

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from cmudrive.bench.routes import RouteSpec

MARGIN = 35.0  # [m] of map shown around the routes and the scenario's items
TRIGGER_COLOUR = "#ffd400"
ACTOR_COLOUR = "#e8501c"  # scenario actors and their paths
PATH_COLOURS = {  # dashed paths by kind
    "flow": "#ff7f0e",
    "crossing": "#d62728",
    "cut_in": "#e8501c",
    "ride": "#2ca02c",
    "approach": "#c000c0",
    "invading": "#d62728",
    "drive_off": "#8c564b",
}
MARKERS = {  # plan points drawn as markers (over their footprint when they are actors): marker, colour, size
    "cone": ("^", "#ff8c00", 22),
    "warning_sign": ("v", "#ffd400", 40),
    "pedestrian": ("o", "#d62728", 40),
    "bicycle": ("o", "#2ca02c", 40),
    "car_door": ("|", "#e8501c", 40),
    "advertisement": ("s", "#9467bd", 30),
    "vending_machine": ("s", "#9467bd", 30),
    "patch": ("o", "#8b5a2b", 70),
    "light": ("s", "#35b23a", 45),
    "slot": ("D", "#ffffff", 40),
}
BOX_COLOURS = {"police": "#1f4fd6", "ambulance": "#c000c0"}  # other vehicles: ACTOR_COLOUR


def _box(p: PlanPoint) -> np.ndarray:
    """(4, 2) corners [m] of the actor type's footprint at the point's pose."""
    t = ACTOR_TYPES[p.kind]
    c, s = np.cos(p.yaw), np.sin(p.yaw)
    half = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * 0.5 * np.array([t.length, t.width])
    return p.xy + half @ np.array([[c, s], [-s, c]])


def _arrow(ax: Axes, xy: np.ndarray, colour: str, dashed: bool, width: float) -> None:
    """A polyline with an arrow head at its end (heading of the last ~3 m)."""
    style = (0, (5, 3)) if dashed else "-"
    z = 10 if dashed else 9  # scenario paths over the CAV routes they cross
    ax.plot(
        xy[:, 0], xy[:, 1], color=colour, linewidth=width, linestyle=style, zorder=z, solid_capstyle="round"
    )
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    back = np.searchsorted(np.cumsum(seg[::-1]), 3.0)
    tail = xy[max(len(xy) - 2 - int(back), 0)]
    ax.annotate(
        "", xy=tuple(xy[-1]), xytext=tuple(tail), zorder=10,
        arrowprops={"arrowstyle": "-|>", "color": colour, "lw": width, "mutation_scale": 14},
    )  # fmt: skip


def draw_plan(ax: Axes, items: list[PlanItem]) -> list[str]:
    """Draw a scenario's plan items; returns the kinds drawn (for the legend)."""
    kinds: list[str] = []
    for it in items:
        if isinstance(it, PlanPath):
            _arrow(ax, it.xy, PATH_COLOURS.get(it.kind, ACTOR_COLOUR), dashed=True, width=1.6)
        else:
            if it.kind in ACTOR_TYPES:
                colour = BOX_COLOURS.get(it.kind, ACTOR_COLOUR)
                ax.add_patch(Polygon(_box(it), closed=True, fc=colour, ec="black", lw=0.6, zorder=11))
            if it.kind in MARKERS:
                marker, colour, size = MARKERS[it.kind]
                ax.scatter(
                    it.xy[0],
                    it.xy[1],
                    marker=marker,
                    s=size,
                    c=colour,
                    edgecolors="black",
                    linewidths=0.6,
                    zorder=11,
                )
        if it.kind not in kinds:
            kinds.append(it.kind)
    return kinds


def _legend(kinds: list[str], paths: set[str], trigger: bool) -> list[Line2D]:
    star = Line2D([], [], marker="*", ls="", ms=13, mfc=TRIGGER_COLOUR, mec="black", label="trigger point")
    handles = [star] if trigger else []
    for kind in kinds:
        if kind in paths:
            colour = PATH_COLOURS.get(kind, ACTOR_COLOUR)
            handles.append(Line2D([], [], color=colour, ls=(0, (5, 3)), lw=1.6, label=f"{kind} path"))
        elif kind in MARKERS:
            marker, colour, _ = MARKERS[kind]
            handles.append(Line2D([], [], marker=marker, ls="", mfc=colour, mec="black", label=kind))
        else:
            colour = BOX_COLOURS.get(kind, ACTOR_COLOUR)
            handles.append(Line2D([], [], marker="s", ls="", mfc=colour, mec="black", label=kind))
    return handles


def _window(routes: list[Route], items: list[PlanItem], trigger: np.ndarray | None) -> np.ndarray:
    """(2, 2) [[x_min, y_min], [x_max, y_max]] of everything drawn, padded by MARGIN [m], made square."""
    pts = [r.xy for r in routes] + [np.atleast_2d(it.xy) for it in items]
    if trigger is not None:
        pts.append(trigger[None])
    allp = np.concatenate(pts)
    lo, hi = allp.min(axis=0) - MARGIN, allp.max(axis=0) + MARGIN
    centre, half = 0.5 * (lo + hi), 0.5 * float(np.max(hi - lo))
    return np.stack([centre - half, centre + half])


def draw_route_plan(ax: Axes, m: RoadMap, spec: RouteSpec, routes: list[Route], scenery: bool = True) -> None:
    """The route's picture onto ``ax`` (ScenarioError when its scenario cannot be placed)."""
    manager = plan_scenarios(spec, m, routes)
    items: list[PlanItem] = [it for sc in manager.scenarios for it in sc.plan()]
    trigger = manager.scenarios[0].trigger_xy if manager.scenarios else None
    draw_map(m, ax)
    if scenery:
        draw_scenery(load_scenery(m), ax)
    for i, r in enumerate(routes):
        colour = cav_colour(i)
        _arrow(ax, r.xy, colour, dashed=False, width=2.0)
        ax.scatter(r.xy[0, 0], r.xy[0, 1], s=40, c=colour, edgecolors="black", linewidths=0.8, zorder=12)
        box = {"boxstyle": "round,pad=0.15", "fc": colour, "ec": "none", "alpha": 0.85}
        offset = (6, 4) if i % 2 == 0 else (-38, -12)  # [pt] alternate sides: CAVs often start abreast
        ax.annotate(
            f"CAV {i}", tuple(r.xy[0]), xytext=offset, textcoords="offset points", fontsize=8, zorder=8,
            fontweight="bold", bbox=box,
        )  # fmt: skip
    kinds = draw_plan(ax, items)
    if trigger is not None:
        ax.scatter(
            trigger[0],
            trigger[1],
            marker="*",
            s=260,
            c=TRIGGER_COLOUR,
            edgecolors="black",
            linewidths=0.8,
            zorder=14,
        )
    paths = {it.kind for it in items if isinstance(it, PlanPath)}
    window = _window(routes, items, trigger)
    ax.set_xlim(window[0, 0], window[1, 0])
    ax.set_ylim(window[0, 1], window[1, 1])
    handles = _legend(kinds, paths, trigger is not None)
    if handles:
        ax.legend(handles=handles, loc="upper right", fontsize=7, framealpha=0.9)
    kind = spec.scenarios[0].type if spec.scenarios else "no scenario"
    note = "" if manager.simulated is not False else " (not simulated)"
    ax.set_title(f"route {spec.id}: {kind}{note} on {m.name}, {len(routes)} CAVs", fontsize=10)


def save_route_figure(spec: RouteSpec, out: str | Path, dpi: int = 110, size: float = 7.0) -> Path:
    """Render ``spec`` to a PNG of ``size`` inches square (MapError, RouteSpecError or ScenarioError when the
    route cannot be placed)."""
    m = load_map(spec.town_path())
    routes = spec.dense_routes(m)
    fig, ax = plt.subplots(figsize=(size, size))
    try:
        draw_route_plan(ax, m, spec, routes)
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=dpi, bbox_inches="tight")
    finally:
        plt.close(fig)
    return out
