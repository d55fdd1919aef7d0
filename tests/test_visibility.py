"""Visibility: field of view, weather range, and 2D occlusion by vehicles and scenery."""

import numpy as np
import pytest

from cmudrive.maps.scenery import SceneryKind, StaticScenery
from cmudrive.sensors import VisibilityConfig, compute_visibility
from cmudrive.sim import ActorKind, Snapshot


def scene(xy, kinds=None, yaw=None, length=None, width=None):
    xy = np.asarray(xy, float)
    n = len(xy)
    cols = {"x": xy[:, 0], "y": xy[:, 1]}
    if kinds is not None:
        cols["kind"] = np.asarray(kinds, np.int8)
    if yaw is not None:
        cols["yaw"] = np.asarray(yaw, float)
    if length is not None:
        cols["length"] = np.asarray(length, float)
        cols["width"] = np.asarray(width, float)
    return Snapshot.from_rows(0, 0.0, [], **cols) if n else None


CAR, PED, BIKE = ActorKind.CAR, ActorKind.PEDESTRIAN, ActorKind.BICYCLE


def seen(snap, rows=(0,), rng=120.0, scenery=None):
    return compute_visibility(snap, np.asarray(rows), rng, scenery).actors


def test_field_of_view_is_110_degrees_from_the_camera_behind_the_centre():
    # the camera is 1.5 m behind the centre: bearings are measured from (-1.5, 0)
    half = np.radians(55.0)
    inside = (-1.5 + 20 * np.cos(half - 0.03), 20 * np.sin(half - 0.03))
    outside = (-1.5 + 20 * np.cos(half + 0.06), -20 * np.sin(half + 0.06))
    snap = scene(
        [(0, 0), inside, outside, (-15, 0)],
        kinds=[CAR, PED, PED, CAR],
        length=[4.9, 0.5, 0.5, 4.5],
        width=[2.1, 0.5, 0.5, 1.9],
    )
    assert seen(snap)[0].tolist() == [False, True, False, False]  # never itself; nothing behind


def test_range_follows_the_weather_visibility():
    snap = scene([(0, 0), (34, 0)], kinds=[CAR, PED], length=[4.9, 0.5], width=[2.1, 0.5])
    # the pedestrian's near side is 34 - 0.25 + 1.5 = 35.25 m from the camera
    assert seen(snap, rng=120.0)[0, 1]
    assert not seen(snap, rng=35.0)[0, 1]  # FogMorning's 35 m
    assert seen(snap, rng=35.3)[0, 1]


def test_a_car_hides_a_pedestrian_behind_it_but_not_one_beside_it():
    snap = scene(
        [(0, 0), (12, 0), (18, 0), (18, 6)],
        kinds=[CAR, CAR, PED, PED],
        length=[4.9, 4.5, 0.5, 0.5],
        width=[2.1, 1.9, 0.5, 0.5],
    )
    assert seen(snap)[0].tolist() == [False, True, False, True]


def test_low_objects_are_seen_but_hide_nothing():
    # a 0.8 m guardrail across the road 8 m ahead, pedestrians at 10 m and 16 m behind it
    snap = scene(
        [(0, 0), (10, 0), (16, 0)], kinds=[CAR, PED, PED], length=[4.9, 0.5, 0.5], width=[2.1, 0.5, 0.5]
    )
    low = StaticScenery(
        np.array([SceneryKind.GUARDRAIL], np.int8),
        np.array([8.0]),
        np.array([0.0]),
        np.array([np.pi / 2]),
        np.array([6.0]),
        np.array([0.3]),
        np.array([0.8]),
    )
    vis = compute_visibility(snap, np.array([0]), 120.0, low)
    assert vis.scenery[0, 0]  # the guardrail itself is seen
    assert vis.actors[0, 1]  # and the pedestrian behind it too (who hides the second one)
    wall = StaticScenery(low.kind, low.x, low.y, low.yaw, low.length, low.width, np.array([2.5]))
    vis = compute_visibility(snap, np.array([0]), 120.0, wall)
    assert vis.scenery[0, 0] and not vis.actors[0, 1] and not vis.actors[0, 2]


def test_a_building_corner_hides_a_pedestrian_about_to_step_out():
    # a building occupying x 5..25, y 3..23 (left of the road); a pedestrian at (20, 2.5) is in the open,
    # one at (20, 5) stands beside it, hidden from a camera at (-1.5, 0) only when the wall is between
    building = StaticScenery(
        np.array([SceneryKind.BUILDING], np.int8),
        np.array([15.0]),
        np.array([13.0]),
        np.array([0.0]),
        np.array([20.0]),
        np.array([20.0]),
        np.array([12.0]),
    )
    snap = scene(
        [(0, 0), (20, 2.5), (27, 6)], kinds=[CAR, PED, PED], length=[4.9, 0.5, 0.5], width=[2.1, 0.5, 0.5]
    )
    vis = compute_visibility(snap, np.array([0]), 120.0, building)
    # ray to (27, 6): at x = 5 it is at y = 6 * 6.5 / 28.5 = 1.37 < 3 (passes below the building's near
    # corner); at x = 25 it is at 5.58 > 3: it crosses the building's south face -> hidden
    assert vis.actors[0].tolist() == [False, True, False]
    assert vis.scenery[0, 0]


def test_many_cameras_in_one_call_equal_one_at_a_time():
    rng = np.random.default_rng(3)
    n = 40
    xy = rng.uniform(-60, 60, (n, 2))
    yaw = rng.uniform(-np.pi, np.pi, n)
    kinds = rng.choice([CAR, PED, BIKE], n)
    snap = scene(xy, kinds=kinds, yaw=yaw)
    rows = np.arange(8)
    batch = compute_visibility(snap, rows, 60.0).actors
    for i, r in enumerate(rows):
        assert (compute_visibility(snap, np.array([r]), 60.0).actors[0] == batch[i]).all()


def test_seen_by_others_names_the_cav_that_sees_a_hidden_pedestrian():
    # CAV 0 behind a truck-like car cannot see the pedestrian; CAV 1 at the side can
    snap = scene(
        [(0, 0), (15, 12), (10, 0), (16, 0)],
        kinds=[CAR, CAR, CAR, PED],
        yaw=[0, -np.pi / 2, 0, 0],
        length=[4.9, 4.9, 4.5, 0.5],
        width=[2.1, 2.1, 1.9, 0.5],
    )
    vis = compute_visibility(snap, np.array([0, 1]), 120.0)
    assert not vis.actors[0, 3] and vis.actors[1, 3]
    others = vis.seen_by_others(np.array([0, 1]), 2)
    assert others[0, 3].tolist() == [False, True]
    assert not others[1, 3].any()


def test_config_is_checked():
    with pytest.raises(ValueError, match="fov_deg"):
        VisibilityConfig(fov_deg=200.0)
