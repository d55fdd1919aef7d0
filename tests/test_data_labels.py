"""Waypoint labels from a future trajectory (cmudrive.data.labels), on hand-built trajectories."""

from __future__ import annotations

import numpy as np
import pytest

from cmudrive.data.labels import PATH_POINTS, SPEED_POINTS, waypoint_labels
from cmudrive.maps.coords import to_ego

DT = 0.05  # [s] one tick


def straight(x0: float, y0: float, yaw: float, speed: float, ticks: int) -> np.ndarray:
    """(ticks + 1, 2) positions of a vehicle driving ``speed`` m/s straight along ``yaw`` from (x0, y0)."""
    d = speed * DT * np.arange(ticks + 1)
    return np.stack([x0 + d * np.cos(yaw), y0 + d * np.sin(yaw)], axis=1)


@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.5])
def test_straight_constant_speed_gives_straight_evenly_spaced_waypoints(yaw: float) -> None:
    v = 8.0  # [m/s]
    traj = straight(120.0, -40.0, yaw, v, 100)  # 5 s: more than 2.5 s and 19 m
    path, speed_wp = waypoint_labels(traj, yaw, np.zeros((0, 2)), v)
    assert path.shape == (PATH_POINTS, 2) and speed_wp.shape == (SPEED_POINTS, 2)
    assert path.dtype == np.float32 and speed_wp.dtype == np.float32
    # float32 of coordinates ~100 m from the ego: ~1e-5 m rounding; 1e-4 m is far below any real error
    np.testing.assert_allclose(path[:, 1], 0.0, atol=1e-4)
    np.testing.assert_allclose(path[:, 0], np.arange(PATH_POINTS), atol=1e-4)
    np.testing.assert_allclose(speed_wp[:, 1], 0.0, atol=1e-4)
    np.testing.assert_allclose(np.diff(speed_wp[:, 0], prepend=0.0), 0.25 * v, atol=1e-4)


def test_path_follows_the_driven_curve_and_speed_waypoints_the_timing() -> None:
    """A quarter circle of radius 20 m at 4 m/s: path points lie on the circle 1 m apart in arc length."""
    r, v = 20.0, 4.0
    t = np.arange(0, 200) * DT
    ang = v * t / r
    traj = np.stack([r * np.sin(ang), r * (1.0 - np.cos(ang))], axis=1)  # starts at 0, heading +x, turns left
    path, speed_wp = waypoint_labels(traj, 0.0, np.zeros((0, 2)), v)
    np.testing.assert_allclose(np.hypot(path[:, 0], path[:, 1] - r), r, atol=2e-3)  # on the circle
    chord = np.hypot(*np.diff(path, axis=0).T)
    np.testing.assert_allclose(chord, 2 * r * np.sin(0.5 / r), atol=2e-3)  # 1 m arcs
    k = np.arange(1, SPEED_POINTS + 1) * 5
    np.testing.assert_allclose(speed_wp, traj[k], atol=1e-4)  # exactly the recorded positions


def test_route_end_continues_along_the_plan_at_the_last_speed() -> None:
    """The CAV left the world 10 ticks after the sample, at 6 m/s: the rest of the path is the expert's plan,
    and the speed waypoints after the end advance along it at 6 m/s."""
    v = 6.0
    traj = straight(0.0, 0.0, 0.0, v, 10)  # 3 m driven
    plan = np.stack([np.arange(3.0, 60.0), np.zeros(57)], axis=1)
    path, speed_wp = waypoint_labels(traj, 0.0, plan, v)
    np.testing.assert_allclose(path[:, 0], np.arange(PATH_POINTS), atol=1e-4)
    np.testing.assert_allclose(speed_wp[:, 0], 0.25 * v * np.arange(1, SPEED_POINTS + 1), atol=1e-4)
    np.testing.assert_allclose(speed_wp[:, 1], 0.0, atol=1e-4)


def test_a_standing_cav_at_the_end_holds_its_position_and_its_path_follows_the_plan() -> None:
    """Stopped 5 m on (a red light) until the tick cap: speed waypoints stay at the stop, the path goes on
    along the planned route (turning left after 10 m) so it still shows where the road leads."""
    drive = straight(0.0, 0.0, 0.0, 5.0, 20)  # 5 m in 1 s
    traj = np.concatenate([drive, np.repeat(drive[-1:], 30, axis=0)])  # then stands 1.5 s, route ends
    plan = np.concatenate(
        [
            np.stack([np.arange(5.0, 11.0), np.zeros(6)], axis=1),
            np.stack([np.full(30, 10.0), np.arange(1.0, 31.0)], axis=1),
        ]
    )
    path, speed_wp = waypoint_labels(traj, 0.0, plan, 0.0)
    np.testing.assert_allclose(speed_wp[4:], np.tile([5.0, 0.0], (SPEED_POINTS - 4, 1)), atol=1e-4)
    np.testing.assert_allclose(path[:11, 1], 0.0, atol=1e-4)
    np.testing.assert_allclose(path[-1], [10.0, 9.0], atol=1e-4)  # 19 m: 10 east, then 9 north


def test_path_beyond_plan_and_trajectory_goes_straight_on() -> None:
    traj = straight(0.0, 0.0, np.pi / 2, 2.0, 4)  # 0.4 m north, no plan
    path, _ = waypoint_labels(traj, np.pi / 2, np.zeros((0, 2)), 2.0)
    np.testing.assert_allclose(path[:, 0], np.arange(PATH_POINTS), atol=1e-4)  # ego x = north
    np.testing.assert_allclose(path[:, 1], 0.0, atol=1e-4)


def test_to_ego_axes() -> None:
    # a vehicle at (10, 5) heading north: a point 3 m north of it is ahead, one 2 m west is on its left
    p = to_ego(np.array([[10.0, 8.0], [8.0, 5.0]]), 10.0, 5.0, np.pi / 2)
    np.testing.assert_allclose(p, [[3.0, 0.0], [0.0, 2.0]], atol=1e-12)
