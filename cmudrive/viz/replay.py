"""Replay a recorded route (``cmudrive.bench.route_log``) as a BEV video, with each CAV's route and its
infractions marked: a ring and a short label at the event position, visible for a few seconds from the
event's tick (collisions red, red lights and stop signs orange, driving outside the route's lanes yellow,
other failures grey). A minimum-speed record is not an infraction (it costs nothing, Bench2Drive records it
for the efficiency score), so it gets another shape: a blue downward triangle labelled "too slow", not a
ring that reads like a collision. A legend in the top-right corner names the marks the log contains.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont
from rich.progress import Progress

from cmudrive.bench.route_log import RouteLog, RouteLogError, load_route_log

if TYPE_CHECKING:
    from cmudrive.maps import RoadMap
    from cmudrive.viz.bev import BevRenderer, BevView

MARKER_RADIUS = 3.0  # [m] ring around an infraction's position
MARKER_MIN_RADIUS = 8.0  # [px] the ring is never smaller than this
MARKER_LINE = 3  # [px] ring width
MAX_FRAME_PX = 1600  # [px] longest side of an overview frame; a followed window is half of it
OVERVIEW_MARGIN = 60.0  # [m] around the CAVs' routes and tracks in an overview
MAX_OVERVIEW_PPM = 4.0  # [px/m]
FOLLOW_MARGIN = 10.0  # [m] pre-rendered beyond the followed window's reach

COLLISION_COLOUR = (255, 48, 48)  # red
LIGHT_COLOUR = (255, 150, 20)  # orange: red lights and stop signs
LANE_COLOUR = (255, 221, 0)  # yellow: driving outside the route's lanes
OTHER_COLOUR = (235, 235, 235)  # anything else (route deviation, blocked, timeouts, ...)
SLOW_COLOUR = (90, 175, 255)  # light blue: a minimum-speed record ("too slow"), drawn as a triangle
SLOW_KEY = "min_speed_infractions"  # recorded only (factor 1): not a penalised infraction
SHORT_LABELS: dict[str, str] = {
    "collisions_pedestrian": "hit pedestrian",
    "collisions_vehicle": "hit vehicle",
    "collisions_layout": "hit layout",
    "red_light": "red light",
    "stop_infraction": "stop sign",
    "outside_route_lanes": "outside lane",
    "yield_emergency_vehicle_infractions": "no yield to EV",
    "scenario_timeouts": "scenario timeout",
    "min_speed_infractions": "too slow",
    "route_dev": "route deviation",
    "vehicle_blocked": "blocked",
    "route_timeout": "timeout",
}
LABEL_PANEL = (25, 25, 25)  # behind a marker's label


def event_colour(key: str) -> tuple[int, int, int]:
    """Marker colour of an infraction key: collisions red, red light / stop orange, outside lane yellow,
    too slow light blue, anything else light grey."""
    if key == SLOW_KEY:
        return SLOW_COLOUR
    if key.startswith("collision"):
        return COLLISION_COLOUR
    if key in ("red_light", "stop_infraction"):
        return LIGHT_COLOUR
    if key == "outside_route_lanes":
        return LANE_COLOUR
    return OTHER_COLOUR


# legend rows: (what the row names, the colour, whether the mark is the "too slow" triangle); a row is
# shown when one of the log's events has that colour
LEGEND_ROWS: tuple[tuple[str, tuple[int, int, int], bool], ...] = (
    ("collision", COLLISION_COLOUR, False),
    ("red light / stop", LIGHT_COLOUR, False),
    ("outside lanes", LANE_COLOUR, False),
    ("deviation, blocked, timeout", OTHER_COLOUR, False),
    ("too slow (no penalty)", SLOW_COLOUR, True),
)


# ---------------------------------------------------------------------- replay
def replay(
    log_path: str | Path,
    out: Path,
    town_map: RoadMap | None = None,
    follow: int | None = None,
    window: float = 100.0,
    fps: int = 20,
    every: int = 1,
    pixels_per_meter: float | None = None,
) -> Path:
    """Render a route log as a BEV video (``.mp4`` or ``.gif``) and return its path.

    The map is ``town_map`` or ``load_map(log.town)``. Without ``follow`` a frame shows the area of all
    CAV routes and tracks; with ``follow`` a ``window``-metre square follows that CAV (held at its last
    position once it has left). Every CAV's route is drawn, and each infraction is marked at its position
    for ``EVENT_SECONDS`` from its tick. ``every`` renders every n-th tick (at ``fps``, the video then
    plays ``every`` times faster than real time).
    """
    from cmudrive.maps import load_map

    log = load_route_log(log_path)
    if every < 1:
        raise ValueError(f"replay of {log.path}: every must be >= 1, got {every}")
    if log.num_ticks == 0:
        raise RouteLogError(f"route log {log.path} has no ticks to replay")
    if follow is not None and not 0 <= follow < log.num_cavs:
        raise ValueError(f"replay of {log.path}: no CAV {follow} (the log has {log.num_cavs})")
    road_map = town_map if town_map is not None else load_map(log.town)
    renderer, centres = replay_renderer(log, road_map, follow, window, pixels_per_meter)
    size_m = window if follow is not None else None
    title = f"{log.route_id}  {road_map.name}"
    ticks = range(0, log.num_ticks, every)

    def frames() -> Iterator[np.ndarray]:
        with Progress(transient=True) as progress:
            task = progress.add_task(f"replay {log.route_id}", total=len(ticks))
            for k in ticks:
                centre = None if centres is None else centres[k]
                yield render_replay_frame(log, renderer, k, center=centre, size_m=size_m, title=title)
                progress.advance(task)

    from cmudrive.viz.video import write_video

    return write_video(frames(), out, fps=fps)


def replay_renderer(
    log: RouteLog,
    road_map: RoadMap,
    follow: int | None = None,
    window: float = 100.0,
    pixels_per_meter: float | None = None,
) -> tuple[BevRenderer, np.ndarray | None]:
    """A renderer whose pre-rendered area covers what the replay shows, and with ``follow`` the (T, 2)
    centre [m] of each tick's window (the CAV, held at its last known position)."""
    from cmudrive.viz.bev import MAX_BACKGROUND_PIXELS, MAX_BACKGROUND_SIDE, BevRenderer

    tracks = [log.cav_xy(i) for i in range(log.num_cavs)] if follow is None else [log.cav_xy(follow)]
    routes = log.cav_routes if follow is None else [log.cav_routes[follow]]
    pts = np.concatenate([np.zeros((0, 2)), *routes, *tracks])
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:  # nothing to frame: the whole map
        lo, hi = np.array(road_map.bounds[:2], float), np.array(road_map.bounds[2:], float)
        pts = np.stack([lo, hi])
    if follow is None:
        lo, hi = pts.min(axis=0) - OVERVIEW_MARGIN, pts.max(axis=0) + OVERVIEW_MARGIN
        ppm = pixels_per_meter or min(MAX_OVERVIEW_PPM, MAX_FRAME_PX / float(np.max(hi - lo)))
        return BevRenderer(road_map, ppm, bounds=(lo[0], lo[1], hi[0], hi[1])), None
    reach = 0.5 * np.sqrt(2.0) * window + FOLLOW_MARGIN
    lo, hi = pts.min(axis=0) - reach, pts.max(axis=0) + reach
    extent = hi - lo
    ppm = pixels_per_meter or min(
        0.5 * MAX_FRAME_PX / window,
        0.99 * MAX_BACKGROUND_SIDE / float(np.max(extent)),
        0.99 * float(np.sqrt(MAX_BACKGROUND_PIXELS / np.prod(extent))),
    )
    centres = _hold_last(log.cav_xy(follow))
    if centres is None:  # the CAV was never recorded: its route's start, else the framed area
        start = log.cav_routes[follow][0] if len(log.cav_routes[follow]) else 0.5 * (lo + hi)
        centres = np.broadcast_to(start, (log.num_ticks, 2))
    return BevRenderer(road_map, ppm, bounds=(lo[0], lo[1], hi[0], hi[1])), centres


def render_replay_frame(
    log: RouteLog,
    renderer: BevRenderer,
    tick: int,
    *,
    center: np.ndarray | Sequence[float] | None = None,
    size_m: float | None = None,
    title: str | None = None,
) -> np.ndarray:
    """One (H, W, 3) uint8 frame of log tick ``tick``: the BEV, every CAV's route and the markers of the
    events active at that tick."""
    frame = renderer.render(
        log.snapshot(tick), center=center, size_m=size_m, routes=log.cav_routes, title=title
    )
    events = log.active_events(tick)
    if events:
        frame = draw_events(frame, renderer.view(center, size_m), events, font_px=renderer.font_px)
    return draw_legend(frame, [str(e["key"]) for e in log.events], font_px=renderer.font_px)


def draw_events(
    frame: np.ndarray, view: BevView, events: Sequence[dict[str, Any]], font_px: int = 13
) -> np.ndarray:
    """``frame`` with a ring at each event's position in its colour (:func:`event_colour`), a triangle for a
    minimum-speed record, and a short label ("CAV 0: red light") on a dark panel beside it; labels of
    events at one spot are stacked."""
    image = Image.fromarray(frame)
    draw = ImageDraw.Draw(image)
    font = _font(font_px)
    r = max(MARKER_RADIUS * view.pixels_per_meter, MARKER_MIN_RADIUS)
    stacked: dict[tuple[int, int], int] = {}
    for ev in events:
        cx, cy = (view.to_pixel(np.array([ev["x"], ev["y"]], dtype=np.float64)) - 0.5).tolist()
        colour = event_colour(str(ev["key"]))
        if ev["key"] == SLOW_KEY:
            _triangle(draw, cx, cy, r, colour)
        else:
            draw.ellipse((cx - r, cy - r, cx + r, cy + r), outline=colour, width=MARKER_LINE)
            draw.ellipse((cx - 2, cy - 2, cx + 2, cy + 2), fill=colour)
        spot = (round(cx), round(cy))
        line = stacked.get(spot, 0)
        stacked[spot] = line + 1
        label = f"CAV {ev['cav']}: {SHORT_LABELS.get(str(ev['key']), str(ev['key']))}"
        xy = (cx + 0.75 * r + 3, cy - 0.75 * r - (line + 1) * (font_px + 4))
        left, top, right, bottom = draw.textbbox(xy, label, font=font)
        draw.rectangle((left - 3, top - 2, right + 3, bottom + 2), fill=LABEL_PANEL, outline=colour)
        draw.text(xy, label, fill=colour, font=font)
    return np.asarray(image).copy()


def _triangle(
    draw: ImageDraw.ImageDraw, cx: float, cy: float, r: float, colour: tuple[int, int, int]
) -> None:
    """A downward-pointing hollow triangle of circumradius ``r`` [px] centred on (cx, cy)."""
    corners = [(cx - 0.87 * r, cy - 0.5 * r), (cx + 0.87 * r, cy - 0.5 * r), (cx, cy + r)]
    draw.polygon(corners, outline=colour, width=MARKER_LINE)


def legend_rows(keys: Sequence[str]) -> list[tuple[str, tuple[int, int, int], bool]]:
    """The legend rows (text, colour, triangle?) of the marks that events with ``keys`` get, in
    ``LEGEND_ROWS`` order."""
    shown = {event_colour(k) for k in keys}
    return [row for row in LEGEND_ROWS if row[1] in shown]


def legend_box(frame_width: int, keys: Sequence[str], font_px: int = 13) -> tuple[int, int, int, int] | None:
    """Pixel box (left, top, right, bottom) of the legend :func:`draw_legend` draws on a frame
    ``frame_width`` px wide; None when it draws none."""
    rows = legend_rows(keys)
    if not rows:
        return None
    font = _font(font_px)
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    text = max(probe.textlength(t, font=font) for t, _, _ in rows)
    width = round(text + font_px + 18)
    left = max(frame_width - width - 8, 0)
    return left, 8, left + width, 8 + (font_px + 6) * len(rows) + 6


def draw_legend(frame: np.ndarray, keys: Sequence[str], font_px: int = 13) -> np.ndarray:
    """``frame`` with a legend panel in its top-right corner: one row per kind of mark among ``keys`` (the
    infraction keys of the log's events), its symbol in its colour; ``frame`` itself when ``keys`` is
    empty."""
    box = legend_box(frame.shape[1], keys, font_px)
    if box is None:
        return frame
    image = Image.fromarray(frame)
    draw = ImageDraw.Draw(image)
    font = _font(font_px)
    line = font_px + 6  # [px] row height
    sym = 0.5 * font_px  # [px] symbol circumradius
    draw.rectangle(box, fill=LABEL_PANEL)
    for i, (text, colour, slow) in enumerate(legend_rows(keys)):
        cx, cy = box[0] + 6 + sym, box[1] + 3 + line * (i + 0.5)
        if slow:
            _triangle(draw, cx, cy, sym, colour)
        else:
            draw.ellipse((cx - sym, cy - sym, cx + sym, cy + sym), outline=colour, width=2)
        draw.text((cx + sym + 6, cy), text, fill=colour, font=font, anchor="lm")
    return np.asarray(image).copy()


@lru_cache(maxsize=8)
def _font(size_px: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    try:
        return ImageFont.load_default(size=size_px)
    except (TypeError, OSError, ImportError):  # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def _hold_last(track: np.ndarray) -> np.ndarray | None:
    """(T, 2) ``track`` with NaN rows replaced by the last known position (the first before it appears);
    None when it is never known."""
    known = np.all(np.isfinite(track), axis=1)
    if not known.any():
        return None
    idx = np.maximum.accumulate(np.where(known, np.arange(len(track)), -1))
    idx[idx < 0] = int(np.flatnonzero(known)[0])
    return track[idx]
