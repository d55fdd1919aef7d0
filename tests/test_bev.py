"""BEV frames of named scenes on the mini map (signalised junction C at (200, 0)), and videos of them."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from cmudrive.maps import LaneKind, RoadMap
from cmudrive.sim.snapshot import SIGNAL_BRAKELIGHT, ActorKind, Role, Snapshot
from cmudrive.viz.bev import BRAKE_COLOUR, CAV_COLOURS, BevRenderer, BevView
from cmudrive.viz.map_plot import LANE_COLOURS, SIGNAL_COLOURS
from cmudrive.viz.video import write_video

PPM = 10.0  # [px/m]
AROUND_C = (140.0, -60.0, 260.0, 60.0)  # [m] pre-rendered area: junction C and its approaches
WC2_CENTRE_Y = -1.6  # [m] the left eastbound lane W->C runs along y = -1.6 (x 0 .. ~193)
CN1_CENTRE_X = 201.6  # [m] the northbound lane C->N runs along x = 201.6


def rgb(colour: str) -> tuple[int, int, int]:
    return int(colour[1:3], 16), int(colour[3:5], 16), int(colour[5:7], 16)


def colour_at(frame: np.ndarray, view: BevView, xy: tuple[float, float]) -> tuple[int, int, int]:
    row, col = view.pixel_index(np.array(xy))
    r, g, b = frame[row, col].tolist()
    return r, g, b


def scene(tls_state: str = "", **columns: object) -> Snapshot:
    cols = {k: np.asarray(v) for k, v in columns.items()}
    return Snapshot.from_rows(0, 1.0, np.array([tls_state] if tls_state else [""]), **cols)


@pytest.fixture(scope="module")
def renderer(mini: RoadMap) -> BevRenderer:
    return BevRenderer(mini, pixels_per_meter=PPM, bounds=AROUND_C)


@pytest.fixture(scope="module")
def all_red(mini: RoadMap) -> str:
    return "r" * len(str(mini.phase_state[0]))


def test_cav_is_drawn_in_its_colour_on_the_road(renderer: BevRenderer, all_red: str) -> None:
    """A CAV on the left eastbound lane: its centre pixel has CAV 0's colour, 5 m ahead is asphalt."""
    snap = scene(all_red, ids=["cav0"], role=np.array([Role.CAV], np.int8), x=[170.0], y=[WC2_CENTRE_Y])
    frame = renderer.render(snap)
    view = renderer.view()
    assert frame.shape == (*renderer.background.shape[:2], 3) and frame.dtype == np.uint8
    assert colour_at(frame, view, (170.0, WC2_CENTRE_Y)) == rgb(CAV_COLOURS[0])
    assert colour_at(frame, view, (175.0, WC2_CENTRE_Y)) == rgb(LANE_COLOURS[LaneKind.DRIVING])
    # the background itself is untouched by rendering
    assert colour_at(renderer.background, view, (170.0, WC2_CENTRE_Y)) == rgb(LANE_COLOURS[LaneKind.DRIVING])


def test_cav_colour_follows_its_id_and_invalid_rows_are_not_drawn(renderer: BevRenderer) -> None:
    snap = scene(
        ids=["cav3", "ghost"],
        role=np.array([Role.CAV, Role.BACKGROUND], np.int8),
        x=[170.0, 160.0],
        y=[WC2_CENTRE_Y, WC2_CENTRE_Y],
        valid=[True, False],
    )
    frame = renderer.render(snap)
    view = renderer.view()
    assert colour_at(frame, view, (170.0, WC2_CENTRE_Y)) == rgb(CAV_COLOURS[3])
    assert colour_at(frame, view, (160.0, WC2_CENTRE_Y)) == rgb(LANE_COLOURS[LaneKind.DRIVING])


def test_car_heading_north_covers_north_not_east(renderer: BevRenderer) -> None:
    """A 4.5 m x 1.9 m car turned 90 degrees extends 2.25 m north-south and only 0.95 m east-west."""
    x, y = CN1_CENTRE_X, 30.0
    snap = scene(x=[x], y=[y], yaw=[np.pi / 2], kind=np.array([ActorKind.CAR], np.int8))
    frame = renderer.render(snap)
    view = renderer.view()
    body = colour_at(frame, view, (x, y))
    assert body != rgb(LANE_COLOURS[LaneKind.DRIVING])
    assert colour_at(frame, view, (x - 0.5, y + 1.8)) == body  # north (beside the heading tick)
    assert colour_at(frame, view, (x - 0.5, y - 1.8)) == body  # south
    assert colour_at(frame, view, (x + 1.8, y - 0.5)) != body  # east
    assert colour_at(frame, view, (x - 1.8, y - 0.5)) != body  # west


@pytest.mark.parametrize(
    ("x", "y", "yaw", "rear", "front"),
    [
        (170.0, WC2_CENTRE_Y, 0.0, (-2.1, 0.75), (2.1, 0.75)),  # heading east: the rear is 2.25 m west
        (CN1_CENTRE_X, 30.0, np.pi / 2, (0.75, -2.1), (0.75, 2.1)),  # heading north: the rear is south
    ],
)
def test_brake_lights_at_the_rear_only_while_braking(
    renderer: BevRenderer, x: float, y: float, yaw: float, rear: tuple, front: tuple
) -> None:
    brake_red = rgb(BRAKE_COLOUR)
    for signals, expect_red in ((SIGNAL_BRAKELIGHT, True), (0, False)):
        snap = scene(x=[x], y=[y], yaw=[yaw], signals=np.array([signals], np.int32))
        frame = renderer.render(snap)
        assert (colour_at(frame, renderer.view(), (x + rear[0], y + rear[1])) == brake_red) == expect_red
        assert colour_at(frame, renderer.view(), (x + front[0], y + front[1])) != brake_red


def _stop_line_colours(mini: RoadMap, renderer: BevRenderer, frame: np.ndarray, lane: str) -> list:
    k = int(np.flatnonzero(mini.stop_lane == mini.lane(lane))[0])
    right, left = mini.stop_xy[k]
    return [
        colour_at(frame, renderer.view(), tuple(right + t * (left - right))) for t in np.linspace(0.1, 0.9, 9)
    ]


@pytest.mark.parametrize("state_char", ["r", "G"])
def test_signal_state_colours_the_stop_line(mini: RoadMap, renderer: BevRenderer, state_char: str) -> None:
    """The traffic light's current state string, not its program, colours the bar on the stop line."""
    state = state_char * len(str(mini.phase_state[0]))
    frame = renderer.render(scene(state, x=[150.0], y=[50.0]))
    colours = _stop_line_colours(mini, renderer, frame, "WC_1")  # two signals: right turn, straight
    expected, other = (rgb(SIGNAL_COLOURS["r"]), rgb(SIGNAL_COLOURS["G"]))[:: 1 if state_char == "r" else -1]
    assert colours.count(expected) >= 6
    assert other not in colours


def test_follow_crop_has_the_requested_size_and_is_centred(renderer: BevRenderer, all_red: str) -> None:
    snap = scene(all_red, ids=["cav0"], role=np.array([Role.CAV], np.int8), x=[185.0], y=[WC2_CENTRE_Y])
    frame = renderer.render(snap, center="cav0", size_m=60.0, title="follow cav0")
    assert frame.shape == (600, 600, 3)
    assert tuple(frame[300, 300]) == rgb(CAV_COLOURS[0])
    view = renderer.view((185.0, WC2_CENTRE_Y), 60.0)
    assert view.bounds == pytest.approx((155.0, -31.6, 215.0, 28.4), abs=0.1)
    # a window reaching past the pre-rendered area keeps its size, filled with ground colour outside
    edge = renderer.render(snap, center=(140.0, 60.0), size_m=30.0)
    assert edge.shape == (300, 300, 3)


def test_pixel_convention_north_up_x_right(renderer: BevRenderer) -> None:
    view = renderer.view()
    xmin, ymin, xmax, ymax = view.bounds
    assert view.pixel_index(np.array([xmin + 0.01, ymax - 0.01])).tolist() == [0, 0]
    assert view.pixel_index(np.array([xmax - 0.01, ymin + 0.01])).tolist() == [
        view.height - 1,
        view.width - 1,
    ]
    assert view.pixel_index(np.array([xmin + 1.0, ymax - 2.0])).tolist() == [int(2 * PPM), int(PPM)]


def test_whole_map_frame_with_routes_and_every_kind(mini: RoadMap) -> None:
    """Every kind and role renders without error on the default whole-map renderer."""
    kinds = np.array(list(ActorKind), np.int8)
    n = len(kinds)
    snap = scene(
        "G" * len(str(mini.phase_state[0])),
        ids=[f"cav{i}" if i < 2 else f"a{i}" for i in range(n)],
        kind=kinds,
        role=np.array([Role.CAV, Role.CAV] + [Role.SCENARIO] * (n - 2), np.int8),
        x=150.0 + 6.0 * np.arange(n),
        y=np.full(n, WC2_CENTRE_Y),
        signals=np.full(n, SIGNAL_BRAKELIGHT | (1 << 11), np.int32),
    )
    renderer = BevRenderer(mini, pixels_per_meter=1.5)
    routes = [mini.polyline(mini.lane("WC_2")), None, np.array([[200.0, 0.0], [200.0, 100.0]])]
    frame = renderer.render(snap, routes=routes, highlight=["cav1"], title="all kinds")
    assert frame.shape == renderer.background.shape
    assert np.any(frame != renderer.background)


def _moving_frames(renderer: BevRenderer, n: int = 5) -> list[np.ndarray]:
    frames = []
    for i in range(n):
        snap = scene(ids=["cav0"], role=np.array([Role.CAV], np.int8), x=[170.0 + 2.0 * i], y=[WC2_CENTRE_Y])
        frames.append(renderer.render(snap, center=(175.0, 0.0), size_m=20.0))
    return frames


def test_gif_has_every_frame(renderer: BevRenderer, tmp_path: Path) -> None:
    iio = pytest.importorskip("imageio.v3", reason="imageio (the video writer) is not installed")

    path = write_video(_moving_frames(renderer), tmp_path / "clip.gif", fps=10)
    frames = iio.imread(path, index=None)
    assert frames.shape[:3] == (5, 200, 200)


@pytest.mark.skipif(
    importlib.util.find_spec("imageio") is None or importlib.util.find_spec("imageio_ffmpeg") is None,
    reason="imageio-ffmpeg (the mp4 writer of imageio) is not installed",
)
def test_mp4_has_every_frame(renderer: BevRenderer, tmp_path: Path) -> None:
    import imageio.v3 as iio

    path = write_video(_moving_frames(renderer), tmp_path / "clip.mp4", fps=20)
    frames = np.stack(list(iio.imiter(path, plugin="FFMPEG")))
    assert frames.shape == (5, 200, 200, 3)


def test_mp4_without_ffmpeg_plugin_names_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # importing it now raises ImportError
    with pytest.raises(ImportError, match=r"clip\.mp4.*imageio-ffmpeg"):
        write_video([np.zeros((8, 8, 3), np.uint8)], tmp_path / "clip.mp4")


def test_unknown_suffix_or_no_frames_is_refused(tmp_path: Path) -> None:
    frame = np.zeros((8, 8, 3), np.uint8)
    with pytest.raises(ValueError, match=r"clip\.avi"):
        write_video([frame], tmp_path / "clip.avi")
    with pytest.raises(ValueError, match=r"empty\.gif"):
        write_video([], tmp_path / "empty.gif")
    with pytest.raises(ValueError, match="frame 1"):
        write_video([frame, np.zeros((9, 8, 3), np.uint8)], tmp_path / "sizes.gif")
