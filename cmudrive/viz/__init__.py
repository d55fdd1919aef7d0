"""Pictures: road plans, route figures with their scenarios' plans, BEV frames of a running world, videos
made of them, and maps of where infractions happened."""

from cmudrive.viz.bev import CAV_COLOURS, BevRenderer, BevView, cav_colour
from cmudrive.viz.infraction_map import InfractionPoint, draw_infractions, save_infraction_map
from cmudrive.viz.map_plot import draw_map, draw_route, save_map_figure
from cmudrive.viz.route_plot import draw_route_plan, save_route_figure
from cmudrive.viz.video import write_video

__all__ = [
    "CAV_COLOURS",
    "BevRenderer",
    "BevView",
    "InfractionPoint",
    "cav_colour",
    "draw_infractions",
    "draw_map",
    "draw_route",
    "draw_route_plan",
    "save_infraction_map",
    "save_map_figure",
    "save_route_figure",
    "write_video",
]
