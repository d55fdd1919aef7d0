"""Fast bird's-eye-view (BEV) frames of a running world, and videos made of them.

Why our own renderer: sumo-gui can take screenshots, but it is an interactive program that is not
scriptable headless at simulation speed, and it knows nothing of our CAVs' roles, routes or indices.
Redrawing a matplotlib figure per frame costs ~250 ms for a 1000 x 1000 px frame with 200 actors (2
cores), more than 10x our budget of 20 ms. So the static road plan is drawn **once** with matplotlib
(anti-aliased, with the lane polygons, colours and markings of :mod:`cmudrive.viz.map_plot`; that layer and
the view onto it are :mod:`cmudrive.viz.bev_map`) into an RGB
array with a known world-to-pixel transform, and each frame copies that array (or a window of it) and
draws the dynamic layer (actors, signal states, routes, text) with Pillow's ``ImageDraw``: geometry is
computed for all actors at once in numpy, then a few C draw calls per actor, ~5-15 ms per frame.

Pixel convention: north up, x to the right. A frame covers the world rectangle of its
:class:`BevView`; the pixel at (row ``r``, column ``c``) covers world
``x in [x_min + c / ppm, x_min + (c + 1) / ppm)`` and ``y in (y_max - (r + 1) / ppm, y_max - r / ppm]``,
with ``ppm`` pixels per metre. ``BevView.pixel_index`` maps world points to (row, col).

Colours: the road plan as in :mod:`cmudrive.viz.map_plot` (grey asphalt, beige pavements, white and
yellow markings, zebra crossings, red octagons at stop signs, light green ground; static scenery: buildings
grey-brown, guardrails light grey lines, street lights dark dots); traffic lights as bars
on their stop lines in the current signal colour (red, amber, green; grey when off or unknown), split
into one part per signal when a lane's movements have their own; CAVs in 16 distinct bright colours,
labelled with their index ("0".."15"); background vehicles grey-blue (trucks, vans and buses a darker
grey-blue and as large as their boxes); scenario vehicles warm grey; pedestrians pink dots; bicycles
and motorcycles green; emergency vehicles red with a roof light bar that flashes blue/white while the
siren is on; props orange. Every vehicle has a heading tick at its front and red brake lights at its
rear while braking.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from matplotlib import font_manager
from matplotlib.colors import to_rgb
from PIL import Image, ImageDraw, ImageFont

from cmudrive.maps.model import RoadMap
from cmudrive.maps.scenery import StaticScenery
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot
from cmudrive.viz.bev_map import SIGNAL_BAR_WIDTH, BevView, draw_map_layer, signal_bars
from cmudrive.viz.map_plot import (
    BACKGROUND,
    JUNCTION_COLOUR,
    signal_colour,
)

RGB = tuple[int, int, int]

DEFAULT_PIXELS_PER_METER = 5.0  # [px/m]: a 200 m x 200 m map is a 1000 x 1000 px frame
MAP_MARGIN = 10.0  # [m] ground drawn around the map's bounds
MAX_BACKGROUND_PIXELS = 64_000_000  # [px] the pre-rendered map (192 MB); use `bounds` or a lower ppm
MAX_BACKGROUND_SIDE = 16_384  # [px] per side (Agg's limits are near)

CAV_COLOURS: tuple[str, ...] = (
    "#2196f3",  # 0 blue
    "#ff2e8a",  # 1 pink
    "#35d04a",  # 2 green
    "#ffe23b",  # 3 yellow
    "#b04be0",  # 4 purple
    "#17d8f0",  # 5 cyan
    "#c9e53a",  # 6 lime
    "#6f7dff",  # 7 periwinkle
    "#ff8fc4",  # 8 light pink
    "#00b894",  # 9 teal
    "#e0b3ff",  # 10 lavender
    "#8dff6a",  # 11 light green
    "#7ff5ff",  # 12 ice blue
    "#fff199",  # 13 pale yellow
    "#f55fe8",  # 14 orchid
    "#4dffc3",  # 15 mint
)
KIND_COLOURS: dict[ActorKind, str] = {
    ActorKind.CAR: "#8fa6c4",  # grey-blue
    ActorKind.VAN: "#7489a8",
    ActorKind.TRUCK: "#677a96",
    ActorKind.BUS: "#677a96",
    ActorKind.MOTORCYCLE: "#3c8d40",
    ActorKind.BICYCLE: "#3c8d40",
    ActorKind.PEDESTRIAN: "#ff7eb0",
    ActorKind.EMERGENCY: "#d32020",
    ActorKind.PROP: "#ff8c1a",
}
SCENARIO_COLOUR = "#b59a86"  # scripted vehicles (adversaries, flows)
PROP_COLOUR = KIND_COLOURS[ActorKind.PROP]
BRAKE_COLOUR = "#ff1010"
SIREN_COLOURS = ("#1f5bff", "#ffffff")  # the two halves of the light bar; they swap while flashing
SIREN_PERIOD = 0.5  # [s] a full flash cycle
HIGHLIGHT_COLOUR = "#ffffff"
HIGHLIGHT_MARGIN = 0.7  # [m] around the highlighted actor's box
RING_WIDTH = 2  # [px] highlight rings and siren glow (drawn as closed lines: Pillow's wide polygon outline
# rasterises a mask of the whole frame)
TEXT_COLOUR = "#ffffff"
LABEL_PADDING = 3  # [px] around the digits of a CAV's index badge
PANEL_COLOUR = "#141414"  # behind overlay text, blended
PANEL_ALPHA = 0.65
ROUTE_WIDTH = 0.6  # [m]
ROUTE_BLEND = 0.65  # share of the CAV colour in a route line (the rest is asphalt grey)

PEDESTRIAN_RADIUS = 0.35  # [m] at least
HEADING_TICK_FROM = 0.35  # fraction of the half length where the tick starts (front half)
HEADING_TICK_WIDTH = 0.3  # [m]
BRAKE_LIGHT_SIZE = (0.35, 0.45)  # [m] along, across the rear of the box

_LAYER = {  # drawing order: lower first
    ActorKind.PROP: 0,
    ActorKind.PEDESTRIAN: 1,
    ActorKind.BICYCLE: 2,
    ActorKind.MOTORCYCLE: 2,
    ActorKind.CAR: 3,
    ActorKind.VAN: 3,
    ActorKind.TRUCK: 3,
    ActorKind.BUS: 3,
    ActorKind.EMERGENCY: 4,
}
CAV_LAYER = 5


def _rgb(colour: str) -> RGB:
    r, g, b = to_rgb(colour)
    return round(255 * r), round(255 * g), round(255 * b)


def _contrast(colour: RGB) -> RGB:
    """Black or white, whichever reads better on ``colour``."""
    luma = 0.299 * colour[0] + 0.587 * colour[1] + 0.114 * colour[2]
    return (20, 20, 20) if luma > 140 else (245, 245, 245)


def cav_colour(index: int) -> str:
    """Colour of CAV ``index`` (cycles after 16)."""
    return CAV_COLOURS[index % len(CAV_COLOURS)]


class BevRenderer:
    """Renders :class:`Snapshot` s of one map as RGB frames; the map is drawn once, at construction."""

    def __init__(
        self,
        road_map: RoadMap,
        pixels_per_meter: float = DEFAULT_PIXELS_PER_METER,
        *,
        bounds: Sequence[float] | None = None,
        markings: bool = True,
        show_time: bool = True,
        scale_bar: bool = True,
        font_px: int = 13,  # [px]
        scenery: StaticScenery | bool = True,
    ) -> None:
        """``bounds`` (xmin, ymin, xmax, ymax [m]) limits the pre-rendered area (default: the whole map
        plus a margin); ``show_time`` and ``scale_bar`` switch the overlays; ``font_px`` sizes all text;
        ``scenery`` is the static scenery drawn on the map (True: the map's own,
        :func:`cmudrive.maps.load_scenery`; False: none)."""
        if pixels_per_meter <= 0:
            raise ValueError(f"pixels_per_meter must be positive, got {pixels_per_meter}")
        self.road_map = road_map
        self.pixels_per_meter = float(pixels_per_meter)
        self.show_time = show_time
        self.scale_bar = scale_bar
        self.font_px = font_px
        if bounds is None:
            xmin, ymin, xmax, ymax = (float(v) for v in road_map.bounds)
            xmin, ymin = xmin - MAP_MARGIN, ymin - MAP_MARGIN
            xmax, ymax = xmax + MAP_MARGIN, ymax + MAP_MARGIN
        else:
            xmin, ymin, xmax, ymax = (float(v) for v in bounds)
        width = max(1, int(np.ceil((xmax - xmin) * self.pixels_per_meter)))
        height = max(1, int(np.ceil((ymax - ymin) * self.pixels_per_meter)))
        if width * height > MAX_BACKGROUND_PIXELS or max(width, height) > MAX_BACKGROUND_SIDE:
            raise ValueError(
                f"the BEV of map {road_map.name!r} would be {width} x {height} px at {pixels_per_meter} "
                "px/m; pass a lower pixels_per_meter, or `bounds` to render a part of it"
            )
        self.full_view = BevView(xmin, ymax, width, height, self.pixels_per_meter)
        if scenery is True:
            from cmudrive.maps.cache import load_scenery

            scenery = load_scenery(road_map)
        self.scenery = scenery if isinstance(scenery, StaticScenery) else StaticScenery.empty()
        self.background = draw_map_layer(road_map, self.full_view, self.scenery, markings)  # (H, W, 3) uint8
        self.background.flags.writeable = False
        self._bg_rgb = _rgb(BACKGROUND)
        self._signal_quads, self._signal_tls, self._signal_index = signal_bars(road_map)
        self._sprites: dict[tuple[str, RGB], Image.Image] = {}  # CAV labels, rendered on first use

    # ------------------------------------------------------------------ views
    def view(
        self, center: Sequence[float] | np.ndarray | None = None, size_m: float | None = None
    ) -> BevView:
        """The view of a frame: the whole background when both are None, else a ``size_m`` [m] square (the
        background's size when None) around ``center`` [m] (the map's centre when None). The window snaps to
        the background's pixel grid, so its centre is within half a pixel of ``center``."""
        if center is None and size_m is None:
            return self.full_view
        full, ppm = self.full_view, self.pixels_per_meter
        if center is None:
            xmin, ymin, xmax, ymax = full.bounds
            center = (0.5 * (xmin + xmax), 0.5 * (ymin + ymax))
        if size_m is None:
            width, height = full.width, full.height
        else:
            if size_m <= 0:
                raise ValueError(f"size_m must be positive, got {size_m}")
            width = height = max(1, round(size_m * ppm))
        cx, cy = float(center[0]), float(center[1])
        col0 = round((cx - full.x_min) * ppm - 0.5 * width)
        row0 = round((full.y_max - cy) * ppm - 0.5 * height)
        return BevView(full.x_min + col0 / ppm, full.y_max - row0 / ppm, width, height, ppm)

    def _window(self, view: BevView) -> Image.Image:
        """A copy of the background under ``view``, ground-coloured outside the pre-rendered area. (Numpy
        slicing + ``Image.fromarray`` is ~5x faster than Pillow's own copy or crop on large frames.)"""
        full = self.full_view
        col0 = round((view.x_min - full.x_min) * self.pixels_per_meter)
        row0 = round((full.y_max - view.y_max) * self.pixels_per_meter)
        c0, r0 = max(col0, 0), max(row0, 0)
        c1, r1 = min(col0 + view.width, full.width), min(row0 + view.height, full.height)
        if (c0, r0, c1, r1) == (col0, row0, col0 + view.width, row0 + view.height):
            return Image.fromarray(np.ascontiguousarray(self.background[r0:r1, c0:c1]))
        frame = np.empty((view.height, view.width, 3), np.uint8)
        frame[:] = self._bg_rgb
        if c0 < c1 and r0 < r1:
            frame[r0 - row0 : r1 - row0, c0 - col0 : c1 - col0] = self.background[r0:r1, c0:c1]
        return Image.fromarray(frame)

    # ------------------------------------------------------------------ frames
    def render(
        self,
        snap: Snapshot,
        *,
        center: Sequence[float] | np.ndarray | str | None = None,
        size_m: float | None = None,
        routes: Sequence[np.ndarray | None] | None = None,
        highlight: Sequence[str] | np.ndarray | None = None,
        title: str | None = None,
        links: Sequence[tuple[str, str]] | None = None,
    ) -> np.ndarray:
        """One frame (H, W, 3) uint8 of ``snap``.

        ``center`` ([m], or an actor id to follow) and ``size_m`` [m] crop a square window (whole map when
        both are None); ``routes[i]`` is an (n, 2) polyline [m] drawn in the colour of CAV ``i``;
        ``highlight`` (actor ids, an (A,) bool mask or indices) rings actors in white; ``title`` and the
        simulation time are written in the top-left corner; ``links`` (pairs of actor ids, e.g. a CAV and
        its V2V partner) are drawn as arrows from the first to the second in the first one's colour.
        """
        if isinstance(center, str):
            i = snap.index_of(center)
            center = (float(snap.x[i]), float(snap.y[i]))
        view = self.view(center, size_m)
        image = self._window(view)
        draw = ImageDraw.Draw(image)
        self._draw_signals(draw, snap.tls_state, view)
        if routes:
            self._draw_routes(draw, routes, view)
        self._draw_actors(image, draw, snap, view, ring=self._highlight_mask(snap, highlight))
        if links:
            self._draw_links(draw, snap, links, view)
        text = f"t = {snap.time:.2f} s" if self.show_time else ""
        if title:
            text = f"{title}   {text}" if text else title
        if text:
            self._panel_text(image, draw, (6, 6), text)
        if self.scale_bar:
            self._draw_scale_bar(image, draw, view)
        return np.asarray(image).copy()  # writeable; np.array(image) is ~4x slower on large frames

    @cached_property
    def _font(self) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
        return _load_font(self.font_px, bold=False)

    @cached_property
    def _badge_font(self) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
        return _load_font(self.font_px + 2, bold=True)

    def _draw_signals(self, draw: ImageDraw.ImageDraw, tls_state: np.ndarray, view: BevView) -> None:
        """The bars on the traffic-light stop lines, in the colour of their signal in ``tls_state``."""
        if len(self._signal_quads) == 0:
            return
        quads = view.to_pixel(self._signal_quads) - 0.5  # (M, 4, 2) Pillow coordinates
        visible = _in_view(quads.mean(axis=1), view, margin_px=4 * SIGNAL_BAR_WIDTH * self.pixels_per_meter)
        states = [str(s) for s in np.asarray(tls_state).tolist()]
        for i in np.flatnonzero(visible).tolist():
            t, sig = int(self._signal_tls[i]), int(self._signal_index[i])
            state = states[t] if 0 <= t < len(states) else ""
            char = state[sig] if 0 <= sig < len(state) else "?"
            colour = _SIGNAL_RGB.get(char, _UNKNOWN_SIGNAL_RGB)
            draw.polygon(quads[i].ravel().tolist(), fill=colour, outline=_DARK_RGB)

    def _draw_routes(
        self, draw: ImageDraw.ImageDraw, routes: Sequence[np.ndarray | None], view: BevView
    ) -> None:
        """Route ``i`` in a muted shade of CAV ``i``'s colour, with a dot at its goal."""
        width = max(2, round(ROUTE_WIDTH * self.pixels_per_meter))
        r = 1.5 * width
        for i, route in enumerate(routes):
            if route is None or len(route) < 2:
                continue
            colour = _ROUTE_RGB[i % len(_ROUTE_RGB)]
            pts = view.to_pixel(np.asarray(route, dtype=np.float64)[:, :2]) - 0.5
            draw.line(pts.ravel().tolist(), fill=colour, width=width, joint="curve")
            ex, ey = pts[-1].tolist()
            draw.ellipse((ex - r, ey - r, ex + r, ey + r), fill=colour, outline=_DARK_RGB)

    def _draw_links(
        self, draw: ImageDraw.ImageDraw, snap: Snapshot, links: Sequence[tuple[str, str]], view: BevView
    ) -> None:
        """An arrow per (from, to) pair of actor ids, ending short of the receiver's centre, coloured as
        the first actor when it is a CAV ("cavK"), white otherwise; pairs with an id not in ``snap`` are
        skipped."""
        index = {str(a): i for i, a in enumerate(snap.ids)}
        width = max(2, round(0.35 * self.pixels_per_meter))
        head = 4.0 * width
        for a, b in links:
            if a not in index or b not in index:
                continue
            p = view.to_pixel(snap.xy[[index[a], index[b]]]) - 0.5
            d = p[1] - p[0]
            length = float(np.hypot(*d))
            if length < 2.0 * head:
                continue
            u = d / length
            tip = p[1] - u * 0.5 * float(snap.width[index[b]]) * self.pixels_per_meter
            colour = (
                _rgb(cav_colour(int(a[3:]))) if a.startswith("cav") and a[3:].isdigit() else (255, 255, 255)
            )
            draw.line([*p[0].tolist(), *tip.tolist()], fill=colour, width=width)
            normal = np.array([-u[1], u[0]])
            wing = [tip - u * head + normal * 0.5 * head, tip, tip - u * head - normal * 0.5 * head]
            draw.polygon([tuple(w.tolist()) for w in wing], fill=colour)

    @staticmethod
    def _highlight_mask(snap: Snapshot, highlight: Sequence[str] | np.ndarray | None) -> np.ndarray:
        """(A,) bool from actor ids, a bool mask or integer indices."""
        mask = np.zeros(snap.num_actors, bool)
        if highlight is None:
            return mask
        arr = np.asarray(highlight)
        if arr.dtype == bool:
            return arr.copy()
        if arr.dtype.kind in "iu":
            mask[arr] = True
            return mask
        return np.isin(snap.ids, arr.astype(str))

    def _draw_actors(
        self, image: Image.Image, draw: ImageDraw.ImageDraw, snap: Snapshot, view: BevView, ring: np.ndarray
    ) -> None:
        """All valid actors in view, lowest layer first. Geometry and colours are computed for all actors
        at once; the loops only issue Pillow's draw calls (a few microseconds each)."""
        ppm = self.pixels_per_meter
        reach = 0.5 * np.hypot(snap.length, snap.width) * ppm + 2.0  # [px] a box's radius
        centres = view.to_pixel(snap.xy) - 0.5  # Pillow's coordinates: pixel centres at integers
        sel = np.flatnonzero(snap.valid & _in_view(centres, view, margin_px=reach))
        if len(sel) == 0:
            return
        kind = np.clip(snap.kind.astype(np.int64), 0, len(ActorKind) - 1)
        layer = np.where(snap.role == Role.CAV, CAV_LAYER, _LAYER_OF_KIND[kind])
        sel = sel[np.argsort(layer[sel], kind="stable")]
        kind, role = kind[sel], snap.role[sel]
        is_cav = role == Role.CAV
        cav_index = _cav_indices(snap, sel, is_cav)
        colour = _colour_codes(kind, role, cav_index)  # (n,) rows of _PALETTE
        fills, outlines, contrasts = (_as_tuples(table[colour]) for table in (_PALETTE, _OUTLINE, _CONTRAST))
        box = _Boxes.of(snap, sel, centres[sel], ppm)

        body = box.rects()
        tick_from = box.c + box.fwd * (HEADING_TICK_FROM * box.hl)[:, None]
        tick_to = box.c + box.fwd * (box.hl - 0.5)[:, None]
        ticks = np.concatenate([tick_from, tick_to], axis=1).tolist()
        tick_w = max(1, round(HEADING_TICK_WIDTH * ppm))
        r = np.maximum(np.maximum(box.hw, PEDESTRIAN_RADIUS * ppm), 2.0)
        dots = np.concatenate([box.c - r[:, None], box.c + r[:, None]], axis=1).tolist()
        ped = kind == ActorKind.PEDESTRIAN
        vehicle = ~ped & (kind != ActorKind.PROP)  # has a front, brake lights, maybe a siren
        for j, (is_ped, is_vehicle) in enumerate(zip(ped.tolist(), vehicle.tolist(), strict=True)):
            if is_ped:
                draw.ellipse(dots[j], fill=fills[j], outline=outlines[j])
                continue
            draw.polygon(body[j], fill=fills[j], outline=outlines[j])
            if is_vehicle:
                draw.line(ticks[j], fill=contrasts[j], width=tick_w)

        braking = box.subset(snap.brake_light[sel] & vehicle)
        lamp_l, lamp_w = (max(v * ppm, 1.5) for v in BRAKE_LIGHT_SIZE)
        for side in (1.0, -1.0):  # a lamp in each rear corner
            lon, lat = lamp_l / 2 - braking.hl, side * (braking.hw - lamp_w / 2)
            for lamp in braking.rects(lon, lat, lamp_l / 2, lamp_w / 2):
                draw.polygon(lamp, fill=_BRAKE_RGB)
        sirens = box.subset(snap.siren[sel] & vehicle)
        flash = int(snap.time / (0.5 * SIREN_PERIOD)) % 2  # the light bar's halves swap every half period
        for side, bar_colour in zip((1.0, -1.0), _SIREN_RGB[flash:] + _SIREN_RGB[:flash], strict=True):
            half_w = 0.4 * sirens.hw
            for half in sirens.rects(0.0, side * half_w, np.maximum(0.12 * sirens.hl, 1.5), half_w):
                draw.polygon(half, fill=bar_colour)
        if flash == 0:  # the blue half of the cycle: a blue glow around the vehicle
            for glow in sirens.rects(grow=0.5 * ppm):
                draw.line([*glow, glow[0], glow[1]], fill=_SIREN_RGB[0], width=RING_WIDTH)
        for outline in box.subset(ring[sel]).rects(grow=HIGHLIGHT_MARGIN * ppm):
            draw.line([*outline, outline[0], outline[1]], fill=_HIGHLIGHT_RGB, width=RING_WIDTH)
        for j in np.flatnonzero(is_cav).tolist():
            top = min(body[j][1::2])  # the box's top edge [px]; the label sits above it
            self._label(image, (float(box.c[j, 0]), top - 2.0), str(cav_index[j]), fills[j])

    def _label(self, image: Image.Image, bottom_centre: tuple[float, float], text: str, colour: RGB) -> None:
        """Paste a CAV's index as a badge in its colour, centred above ``bottom_centre``."""
        sprite = self._sprites.get((text, colour))
        if sprite is None:  # drawn once per (text, colour): glyph rendering is the costly part
            left, top, right, bottom = self._badge_font.getbbox(text)
            pad = LABEL_PADDING
            size = (max(int(right - left), int(bottom - top)) + 2 * pad + 1, int(bottom - top) + 2 * pad + 1)
            sprite = Image.new("RGBA", size, (0, 0, 0, 0))
            draw = ImageDraw.Draw(sprite)
            draw.rounded_rectangle(
                (0, 0, size[0] - 1, size[1] - 1), radius=size[1] // 2, fill=colour, outline=_DARK_RGB
            )
            draw.text(
                (size[0] / 2, size[1] / 2), text, fill=_contrast(colour), font=self._badge_font, anchor="mm"
            )
            self._sprites[(text, colour)] = sprite
        x, y = bottom_centre
        image.paste(sprite, (round(x - 0.5 * sprite.width), round(y - sprite.height)), sprite)

    def _panel_text(
        self, image: Image.Image, draw: ImageDraw.ImageDraw, xy: tuple[int, int], text: str
    ) -> None:
        left, top, right, bottom = (round(v) for v in draw.textbbox(xy, text, font=self._font))
        _shade(image, (left - 4, top - 3, right + 4, bottom + 3))
        draw.text(xy, text, fill=_TEXT_RGB, font=self._font)

    def _draw_scale_bar(self, image: Image.Image, draw: ImageDraw.ImageDraw, view: BevView) -> None:
        width_m = view.width / self.pixels_per_meter
        nice = [v for v in (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000) if v <= 0.2 * width_m]
        if not nice:
            return
        metres = nice[-1]
        bar = metres * self.pixels_per_meter
        x0, y0 = 10.0, view.height - 12.0
        label = f"{metres} m"
        _, top, right, bottom = (
            round(v) for v in draw.textbbox((x0 + bar + 6, y0), label, font=self._font, anchor="lm")
        )
        _shade(image, (int(x0) - 5, min(top, int(y0) - 5) - 3, right + 5, max(bottom, int(y0) + 5) + 3))
        draw.rectangle((x0, y0 - 2, x0 + bar, y0 + 2), fill=(245, 245, 245))
        draw.text((x0 + bar + 6, y0), label, fill=_TEXT_RGB, font=self._font, anchor="lm")


# colour table of the dynamic layer: rows 0-15 the CAVs, then one row per ActorKind, then scenario vehicles
_PALETTE = np.array(
    [_rgb(c) for c in CAV_COLOURS] + [_rgb(KIND_COLOURS[k]) for k in ActorKind] + [_rgb(SCENARIO_COLOUR)],
    dtype=np.int64,
)
_KIND_ROW = len(CAV_COLOURS)  # row of ActorKind 0
_SCENARIO_ROW = _KIND_ROW + len(ActorKind)
_OUTLINE = np.round(_PALETTE * 0.45).astype(np.int64)  # darker edge of each fill
_CONTRAST = np.array([_contrast((r, g, b)) for r, g, b in _PALETTE.tolist()], dtype=np.int64)
_LAYER_OF_KIND = np.array([_LAYER[k] for k in ActorKind])
_VEHICLES = np.array([ActorKind.CAR, ActorKind.VAN, ActorKind.TRUCK, ActorKind.BUS])
_SIGNAL_RGB: dict[str, RGB] = {ch: _rgb(signal_colour(ch)) for ch in "rygGsuoO"}
_UNKNOWN_SIGNAL_RGB = _rgb(signal_colour("?"))
_BRAKE_RGB = _rgb(BRAKE_COLOUR)
_SIREN_RGB: tuple[RGB, ...] = tuple(_rgb(c) for c in SIREN_COLOURS)
_HIGHLIGHT_RGB = _rgb(HIGHLIGHT_COLOUR)
_TEXT_RGB = _rgb(TEXT_COLOUR)
_DARK_RGB = (25, 25, 25)  # outlines of signal bars and route goals
_ROUTE_RGB: tuple[RGB, ...] = tuple(  # muted CAV colours: mixed with asphalt grey
    (
        round(ROUTE_BLEND * r + (1 - ROUTE_BLEND) * ar),
        round(ROUTE_BLEND * g + (1 - ROUTE_BLEND) * ag),
        round(ROUTE_BLEND * b + (1 - ROUTE_BLEND) * ab),
    )
    for (r, g, b), (ar, ag, ab) in ((_rgb(c), _rgb(JUNCTION_COLOUR)) for c in CAV_COLOURS)
)


def _colour_codes(kind: np.ndarray, role: np.ndarray, cav_index: np.ndarray) -> np.ndarray:
    """(n,) row of ``_PALETTE`` per actor: CAVs by index, props orange, scripted vehicles warm grey, the rest
    by kind."""
    code = _KIND_ROW + kind
    code = np.where((role == Role.SCENARIO) & np.isin(kind, _VEHICLES), _SCENARIO_ROW, code)
    code = np.where(role == Role.PROP, _KIND_ROW + ActorKind.PROP, code)
    return np.where(role == Role.CAV, np.mod(cav_index, len(CAV_COLOURS)), code)


def _load_font(size_px: int, bold: bool) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    """DejaVu Sans, which matplotlib ships, else Pillow's default font."""
    try:
        path = font_manager.findfont(
            font_manager.FontProperties(family="DejaVu Sans", weight="bold" if bold else "normal"),
            fallback_to_default=False,
        )
        return ImageFont.truetype(path, size_px)
    except (ValueError, OSError, ImportError):
        pass
    try:
        return ImageFont.load_default(size=size_px)
    except (TypeError, OSError, ImportError):  # Pillow < 10.1 or without FreeType: the bitmap font
        return ImageFont.load_default()


def _cav_indices(snap: Snapshot, sel: np.ndarray, is_cav: np.ndarray) -> np.ndarray:
    """(n,) CAV index of each selected actor from its id ("cav3" -> 3), else its rank among the CAVs; -1 for
    actors that are not CAVs."""
    out = np.full(len(sel), -1, np.int64)
    cav_rank = np.cumsum(snap.role == Role.CAV) - 1
    for j in np.flatnonzero(is_cav).tolist():
        match = re.search(r"(\d+)$", str(snap.ids[sel[j]]))
        out[j] = int(match.group(1)) if match else int(cav_rank[sel[j]])
    return out


def _as_tuples(rgb: np.ndarray) -> list[RGB]:
    return [(r, g, b) for r, g, b in rgb.tolist()]


@dataclass(frozen=True)
class _Boxes:
    """Oriented boxes in Pillow's pixel coordinates (rows grow southwards): centres (n, 2), unit forward
    and left axes (n, 2), half length and half width (n,) [px]."""

    c: np.ndarray
    fwd: np.ndarray
    left: np.ndarray
    hl: np.ndarray
    hw: np.ndarray

    @staticmethod
    def of(snap: Snapshot, sel: np.ndarray, centres_px: np.ndarray, ppm: float) -> _Boxes:
        fwd = np.stack([np.cos(snap.yaw[sel]), -np.sin(snap.yaw[sel])], axis=1)
        left = np.stack([fwd[:, 1], -fwd[:, 0]], axis=1)
        return _Boxes(centres_px, fwd, left, 0.5 * snap.length[sel] * ppm, 0.5 * snap.width[sel] * ppm)

    def subset(self, mask: np.ndarray) -> _Boxes:
        return _Boxes(self.c[mask], self.fwd[mask], self.left[mask], self.hl[mask], self.hw[mask])

    def rects(
        self,
        lon: float | np.ndarray = 0.0,
        lat: float | np.ndarray = 0.0,
        half_l: float | np.ndarray | None = None,
        half_w: float | np.ndarray | None = None,
        grow: float = 0.0,
    ) -> list[list[float]]:
        """Flat corners [x0, y0, ..., x3, y3] of one rectangle per box, centred ``lon`` ahead of and ``lat``
        left of the box's centre, with half sizes ``half_l`` and ``half_w`` (default: the box's own) plus
        ``grow``, all in pixels."""
        n = len(self.c)
        hl = np.broadcast_to(self.hl if half_l is None else half_l, (n,)) + grow
        hw = np.broadcast_to(self.hw if half_w is None else half_w, (n,)) + grow
        lon_n, lat_n = np.broadcast_to(lon, (n,)), np.broadcast_to(lat, (n,))
        mid = self.c + self.fwd * lon_n[:, None] + self.left * lat_n[:, None]
        a, b = self.fwd * hl[:, None], self.left * hw[:, None]
        return np.concatenate([mid + a + b, mid + a - b, mid - a - b, mid - a + b], axis=1).tolist()


def _in_view(points_px: np.ndarray, view: BevView, margin_px: float | np.ndarray) -> np.ndarray:
    col, row = points_px[..., 0], points_px[..., 1]
    return (
        (col > -margin_px)
        & (col < view.width + margin_px)
        & (row > -margin_px)
        & (row < view.height + margin_px)
    )


def _shade(image: Image.Image, box: tuple[int, int, int, int]) -> None:
    """Darken a rectangle of ``image`` towards the panel colour (a translucent text panel)."""
    x0, y0 = max(box[0], 0), max(box[1], 0)
    x1, y1 = min(box[2], image.width), min(box[3], image.height)
    if x0 >= x1 or y0 >= y1:
        return
    region = image.crop((x0, y0, x1, y1))
    panel = Image.new("RGB", region.size, _rgb(PANEL_COLOUR))
    image.paste(Image.blend(region, panel, PANEL_ALPHA), (x0, y0))


# ---------------------------------------------------------------------- videos
