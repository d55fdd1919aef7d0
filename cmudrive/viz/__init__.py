"""Pictures: road plans, BEV frames of a running world, and videos made of them."""

from cmudrive.viz.bev import CAV_COLOURS, BevRenderer, BevView, cav_colour
from cmudrive.viz.map_plot import draw_map, draw_route, save_map_figure
from cmudrive.viz.video import write_video

__all__ = [
    "CAV_COLOURS",
    "BevRenderer",
    "BevView",
    "cav_colour",
    "draw_map",
    "draw_route",
    "save_map_figure",
    "write_video",
]
