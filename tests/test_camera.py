"""The front camera in physical terms: where things appear, what is not drawn, lights, weather, batching."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from cmudrive.maps import RoadMap, StopKind, load_map
from cmudrive.maps.scenery import SceneryKind, StaticScenery
from cmudrive.sensors.camera import CameraConfig, FrontCamera
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot
from cmudrive.sim.weather import WEATHERS

FAR = 5000.0  # [m] a place far outside the map: only the ground plane, sky and our actors are drawn
CONFIG = CameraConfig()
CY = CONFIG.height // 2


@pytest.fixture(scope="module")
def downtown() -> RoadMap:
    return load_map("downtown")


@pytest.fixture(scope="module")
def camera(downtown: RoadMap) -> FrontCamera:
    return FrontCamera(CONFIG, downtown)


def scene(*actors: dict, ego: dict | None = None, tls_state: np.ndarray | None = None) -> Snapshot:
    """A snapshot of an ego CAV (row 0; by default at (FAR, FAR) heading east), plus ``actors`` at x, y
    or at ``dx`` east and ``dy`` north of (FAR, FAR) [m]; other keys are Snapshot columns."""
    rows = [
        {
            "kind": ActorKind.CAR,
            "role": Role.CAV,
            "ids": "cav0",
            "x": FAR,
            "y": FAR,
            "length": 4.89,
            "width": 2.1,
            **(ego or {}),
        }
    ]
    for k, a in enumerate(actors):
        row = {"kind": ActorKind.CAR, "role": Role.BACKGROUND, "ids": f"v{k}", "length": 4.5, "width": 1.85}
        row.update({key: v for key, v in a.items() if key not in ("dx", "dy")})
        row.setdefault("x", FAR + a.get("dx", 0.0))
        row.setdefault("y", FAR + a.get("dy", 0.0))
        rows.append(row)
    keys = sorted({k for r in rows for k in r})
    defaults = {"yaw": 0.0, "kind": ActorKind.CAR, "role": Role.BACKGROUND, "length": 4.5, "width": 1.85}
    cols = {k: np.array([r.get(k, defaults.get(k, 0.0)) for r in rows]) for k in keys}
    for k, dtype in (("kind", np.int8), ("role", np.int8), ("signals", np.int32), ("lane", np.int32)):
        if k in cols:
            cols[k] = cols[k].astype(dtype)
    state = np.zeros(0, str) if tls_state is None else tls_state
    return Snapshot.from_rows(0, 0.0, state, **cols)


def drawn(camera: FrontCamera, snap: Snapshot, weather: str = "ClearNoon") -> tuple[np.ndarray, np.ndarray]:
    """Image of the ego's camera and the mask of pixels that differ in depth from the empty scene."""
    img, depth = camera.render_with_depth(snap, np.array([0]), WEATHERS[weather])
    _, empty = camera.render_with_depth(scene(), np.array([0]), WEATHERS[weather])
    return img[0], depth[0] != empty[0]


def car_ahead(distance: float) -> dict:
    """A 4.5 m car whose rear face is ``distance`` [m] in front of the camera (1.5 m behind the centre)."""
    return {"dx": CONFIG.mount_x + distance + 2.25}


def test_car_straight_ahead_is_centred_and_halves_in_height_with_twice_the_distance(camera: FrontCamera):
    heights = []
    for distance in (10.0, 20.0):
        _, mask = drawn(camera, scene(car_ahead(distance)))
        rows, cols = np.nonzero(mask)
        assert abs(0.5 * (cols.min() + cols.max() + 1) - CONFIG.width / 2) <= 1.0  # centred [px]
        heights.append(rows.max() - rows.min() + 1)
    assert 1.7 <= heights[0] / heights[1] <= 2.4
    # the car's bottom edge meets the road where a ground point 10 m ahead is: v - cy = f h / z
    assert heights[0] == pytest.approx(CONFIG.focal * (2.0 / 10.0 - 0.5 / 14.5), abs=2.0)


def test_a_car_to_the_left_appears_left_of_centre_where_the_pinhole_puts_it(camera: FrontCamera):
    """Heading east, +y (north) is to the left: no mirror image. A pole-thin pedestrian 20 m ahead and
    4 m left projects to u = cx - f 4 / 20."""
    ped = {"dx": CONFIG.mount_x + 20.0, "dy": 4.0, "kind": ActorKind.PEDESTRIAN, "length": 0.5, "width": 0.6}
    _, mask = drawn(camera, scene(ped))
    cols = np.nonzero(mask)[1]
    expected = CONFIG.width / 2 - CONFIG.focal * 4.0 / 20.0
    assert abs(0.5 * (cols.min() + cols.max() + 1) - expected) <= 1.5


def test_depth_is_distance_along_the_optical_axis(camera: FrontCamera):
    _, depth = camera.render_with_depth(scene(car_ahead(10.0)), np.array([0]), WEATHERS["ClearNoon"])
    centre = depth[0, CY + 10, CONFIG.width // 2]  # on the car's rear face
    assert centre == pytest.approx(10.0, rel=1e-3)
    bottom = depth[0, -1, 0]  # the ground plane in the bottom row
    assert bottom == pytest.approx(2.0 * CONFIG.focal / (CONFIG.height - 0.5 - CY), rel=1e-4)
    assert np.isinf(depth[0, 0, 0])  # sky


@pytest.mark.parametrize(
    "where",
    [
        {"dx": -12.0},  # behind the camera
        {"dx": 10.0, "dy": 30.0},  # 70 deg to the left, outside the 110 deg field of view
        {"dx": 10.0, "dy": -30.0},
        {"dx": 130.0},  # beyond max_range
    ],
)
def test_objects_behind_or_outside_the_field_of_view_draw_nothing(camera: FrontCamera, where: dict):
    img, mask = drawn(camera, scene(where))
    assert not mask.any()
    empty = camera.render(scene(), np.array([0]), WEATHERS["ClearNoon"])[0]
    np.testing.assert_array_equal(img, empty)


def test_object_crossing_the_camera_plane_is_clipped_not_lost(camera: FrontCamera):
    """A long truck beside and ahead of the camera: its triangles pass behind it and must still draw."""
    _, mask = drawn(
        camera, scene({"dx": 2.0, "dy": 3.5, "length": 12.0, "width": 2.5, "kind": ActorKind.BUS})
    )
    assert mask[:, : CONFIG.width // 2].mean() > 0.3  # fills much of the left half


def test_own_vehicle_is_not_drawn(camera: FrontCamera):
    snap = scene(car_ahead(15.0))
    without_ego = replace(snap, valid=np.array([False, True]))
    weather = WEATHERS["ClearNoon"]
    np.testing.assert_array_equal(
        camera.render(snap, np.array([0]), weather), camera.render(without_ego, np.array([0]), weather)
    )


def _before_light(
    m: RoadMap, distance: float, kind: StopKind = StopKind.TRAFFIC_LIGHT
) -> tuple[Snapshot, int]:
    """The ego ``distance`` [m] upstream of a stop line of ``kind``, on its lane; that line's light."""
    k = int(np.flatnonzero(m.stop_kind == kind)[0])
    xy = m.polyline(int(m.stop_lane[k]))
    d = (xy[-1] - xy[-2]) / np.linalg.norm(xy[-1] - xy[-2])
    p = xy[-1] - distance * d
    return scene(ego={"x": p[0], "y": p[1], "yaw": np.arctan2(d[1], d[0])}), int(m.stop_tls[k])


@pytest.mark.parametrize("char", ["r", "G"])
def test_traffic_light_ahead_shows_its_state(camera: FrontCamera, downtown: RoadMap, char: str):
    base, _ = _before_light(downtown, 12.0)
    states = np.array([char * len(s) for s in downtown.phase_state[downtown.tls_phase_ptr[:-1]]])
    snap = replace(base, tls_state=states)
    img = camera.render(snap, np.array([0]), WEATHERS["ClearNoon"])[0].astype(int)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    red = (r > 200) & (g < 90) & (b < 90)
    green = (g > 200) & (r < 120) & (b < 160)
    lit, dark = (red, green) if char == "r" else (green, red)
    assert lit[:CY].sum() >= 2  # lamps above the horizon (heads hang 2.3-3.3 m high)
    assert not dark.any()


def test_stop_sign_ahead_shows_a_red_plate(camera: FrontCamera, downtown: RoadMap):
    snap, _ = _before_light(downtown, 12.0, StopKind.ALLWAY_STOP)  # downtown's stops are all-way stops
    img = camera.render(snap, np.array([0]), WEATHERS["ClearNoon"])[0].astype(int)
    red = (img[..., 0] > 150) & (img[..., 1] < 50) & (img[..., 2] < 50)
    assert red[:CY, CONFIG.width // 2 :].sum() >= 4  # on the right, above the horizon (2.2 m high)


def scene_ego(m: RoadMap) -> Snapshot:
    """The ego 30 m before a traffic light with a car ahead at 30 m and a cyclist at 15 m."""
    snap, _ = _before_light(m, 30.0)
    c, s = np.cos(snap.yaw[0]), np.sin(snap.yaw[0])
    extra = [(30.0, 0.0, ActorKind.CAR, 4.5, 1.85), (15.0, 1.0, ActorKind.BICYCLE, 1.8, 0.65)]
    rows = [
        {
            "x": snap.x[0] + dx * c - dy * s,
            "y": snap.y[0] + dx * s + dy * c,
            "yaw": snap.yaw[0],
            "kind": k,
            "length": ln,
            "width": wd,
        }
        for dx, dy, k, ln, wd in extra
    ]
    return scene(*rows, ego={"x": snap.x[0], "y": snap.y[0], "yaw": snap.yaw[0]})


def luminance(img: np.ndarray) -> float:
    return float((img[..., :3].astype(float) @ np.array([0.2126, 0.7152, 0.0722])).mean())


def test_night_is_darker_than_noon(camera: FrontCamera, downtown: RoadMap):
    snap = scene_ego(downtown)
    noon = camera.render(snap, np.array([0]), WEATHERS["ClearNoon"])[0]
    night = camera.render(snap, np.array([0]), WEATHERS["ClearNight"])[0]
    assert luminance(night) < 0.4 * luminance(noon)


def test_fog_lowers_the_contrast_of_far_objects(camera: FrontCamera):
    snap = scene({"dx": 40.0, "kind": ActorKind.VAN, "length": 5.4, "width": 2.05})

    def contrast(weather: str) -> float:
        img, mask = drawn(camera, snap, weather)
        ring = np.zeros_like(mask)
        rows, cols = np.nonzero(mask)
        ring[rows.min() - 3 : rows.max() + 4, cols.min() - 3 : cols.max() + 4] = True
        pix = img.astype(float).mean(axis=2)
        return abs(pix[mask].mean() - pix[ring & ~mask].mean()) / 255.0

    assert contrast("FogMorning") < 0.5 * contrast("ClearNoon")


def test_rain_darkens_the_road(camera: FrontCamera, downtown: RoadMap):
    snap = scene_ego(downtown)
    img = {w: camera.render(snap, np.array([0]), WEATHERS[w])[0] for w in ("ClearNoon", "HardRainNoon")}
    bottom = slice(CONFIG.height - 20, None)  # the road right in front
    assert luminance(img["HardRainNoon"][bottom]) < 0.8 * luminance(img["ClearNoon"][bottom])


def test_batch_of_16_equals_each_camera_alone_and_is_deterministic(downtown: RoadMap):
    """16 CAVs along lanes of downtown (they see each other), rendered in rain (per-camera streaks)."""
    scenery = StaticScenery(
        np.full(3, SceneryKind.BUILDING, np.int8),
        np.array([100.0, 300.0, 500.0]),
        np.array([100.0, 300.0, 200.0]),
        np.zeros(3),
        np.full(3, 20.0),
        np.full(3, 15.0),
        np.full(3, 12.0),
    )
    cam = FrontCamera(CameraConfig(width=128, height=64), downtown, scenery)
    lanes = np.flatnonzero(downtown.lane_length > 40.0)[::7][:16]
    pts = np.array([downtown.polyline(int(ln))[:2] for ln in lanes])  # (16, 2, 2)
    d = pts[:, 1] - pts[:, 0]
    snap = Snapshot.from_rows(
        3,
        0.15,
        np.array(list(downtown.phase_state[downtown.tls_phase_ptr[:-1]])),
        ids=np.array([f"cav{i}" for i in range(16)]),
        role=np.zeros(16, np.int8),
        x=pts[:, 0, 0],
        y=pts[:, 0, 1],
        yaw=np.arctan2(d[:, 1], d[:, 0]),
    )
    rows = np.arange(16)
    weather = WEATHERS["HardRainNoon"]
    batch, depth = cam.render_with_depth(snap, rows, weather)
    assert batch.shape == (16, 64, 128, 3) and batch.dtype == np.uint8 and depth.shape == (16, 64, 128)
    for i in rows:
        alone, alone_depth = cam.render_with_depth(snap, np.array([i]), weather)
        np.testing.assert_array_equal(batch[i], alone[0])
        np.testing.assert_array_equal(depth[i], alone_depth[0])
    np.testing.assert_array_equal(batch, cam.render(snap, rows, weather))
    # and the same from a camera built anew
    again = FrontCamera(CameraConfig(width=128, height=64), downtown, scenery)
    np.testing.assert_array_equal(batch, again.render(snap, rows, weather))


def test_scenery_boxes_are_drawn(downtown: RoadMap):
    wall = StaticScenery(
        np.array([SceneryKind.WALL], np.int8),
        np.array([FAR + 12.0]),
        np.array([FAR]),
        np.array([np.pi / 2]),
        np.array([10.0]),
        np.array([0.3]),
        np.array([3.0]),
    )
    cam = FrontCamera(CONFIG, downtown, wall)
    _, depth = cam.render_with_depth(scene(), np.array([0]), WEATHERS["ClearNoon"])
    # the wall's face is 12 - 0.15 + 1.5 m ahead of the camera
    assert depth[0, CY, CONFIG.width // 2] == pytest.approx(13.35, rel=1e-3)


def test_config_rejects_nonsense():
    with pytest.raises(ValueError, match="fov"):
        CameraConfig(fov_deg=180.0)
    with pytest.raises(ValueError, match="resolution"):
        CameraConfig(width=1)
