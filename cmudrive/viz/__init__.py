"""Pictures: road plans, route figures with their scenarios' plans, BEV frames of a running world, and
videos made of them."""

from cmudrive.viz.bev import CAV_COLOURS, BevRenderer, BevView, cav_colour
from cmudrive.viz.map_plot import draw_map, draw_route, save_map_figure
from cmudrive.viz.route_plot import draw_route_plan, save_route_figure
from cmudrive.viz.video import write_video

__all__ = [
    "CAV_COLOURS",
    "BevRenderer",
    "BevView",
    "cav_colour",
    "draw_map",
    "draw_route",
    "draw_route_plan",
    "save_map_figure",
    "save_route_figure",
    "write_video",
]
