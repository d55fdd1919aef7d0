"""Vectorised lane queries on the mini network, checked against hand-computed geometry."""

from __future__ import annotations

import numpy as np
import pytest

from cmudrive.maps import LaneKind, RoadMap


def test_nearest_lane_gives_frenet_coordinates(mini: RoadMap) -> None:
    # WC_1 runs east along y = -4.8 from x = 0; a point 1 m to its left and 50 m along it
    proj = mini.index.nearest_lane(np.array([[50.0, -3.8]]))
    assert mini.lane_ids[proj.lane[0]] == "WC_1"
    assert proj.s[0] == pytest.approx(50.0)
    assert proj.d[0] == pytest.approx(1.0)  # + is left of the direction of travel
    assert proj.heading[0] == pytest.approx(0.0)


def test_heading_filter_picks_the_direction_of_travel(mini: RoadMap) -> None:
    # on the two-way road C-E, a point on the centre line is equally near both directions
    point = np.array([[300.0, 0.0], [300.0, 0.0]])
    proj = mini.index.nearest_lane(point, heading=np.array([0.0, np.pi]))
    assert [str(mini.lane_ids[i]) for i in proj.lane] == ["CE_1", "EC_1"]
    # heading west on an eastbound lane: the nearest westbound lane, 6.4 m away, is found
    west = mini.index.nearest_lane(np.array([[100.0, -4.8]]), heading=np.pi, max_heading_diff=0.3)
    assert mini.lane_ids[west.lane[0]] == "CW_2"
    assert west.d[0] == pytest.approx(6.4)  # south of a westbound lane is its left
    # ... unless it is farther than allowed
    none = mini.index.nearest_lane(np.array([[100.0, -4.8]]), heading=np.pi, max_distance=5.0)
    assert none.lane[0] == -1


def test_kind_filter_and_max_distance(mini: RoadMap) -> None:
    walk = mini.index.nearest_lane(np.array([[50.0, -7.4]]), kinds=(LaneKind.SIDEWALK,))
    assert mini.lane_ids[walk.lane[0]] == "WC_0"
    far = mini.index.nearest_lane(np.array([[1000.0, -500.0]]), max_distance=10.0)
    assert far.lane[0] == -1 and np.isnan(far.s[0])


def test_frenet_round_trip_on_many_points(mini: RoadMap) -> None:
    rng = np.random.default_rng(0)
    lanes = np.flatnonzero(mini.driving & ~mini.lane_internal)
    lane = rng.choice(lanes, 2000)
    s = rng.uniform(0.0, 1.0, 2000) * mini.lane_length[lane]
    d = rng.uniform(-1.0, 1.0, 2000)
    xy = mini.index.frenet_to_xy(lane, s, d)
    s2, d2 = mini.index.project(xy, lane)
    assert np.allclose(s2, s, atol=1e-6) and np.allclose(d2, d, atol=1e-6)
    # the nearest lane of a point 1 m off a lane centre is that lane, except near junction ends
    inner = (s > 15.0) & (s < mini.lane_length[lane] - 15.0)
    proj = mini.index.nearest_lane(xy[inner], heading=mini.index.heading_at(lane[inner], s[inner]))
    assert np.all(proj.lane == lane[inner])
    assert np.allclose(proj.d, d[inner], atol=1e-6)


def test_heading_and_width_at(mini: RoadMap) -> None:
    lane = np.array([mini.lane("CN_1"), mini.lane("WC_1")])
    assert mini.index.heading_at(lane, np.array([10.0, 10.0])) == pytest.approx([np.pi / 2, 0.0])
    assert mini.index.width_at(lane) == pytest.approx([3.2, 3.2])


def test_on_driving_lane(mini: RoadMap) -> None:
    points = np.array(
        [
            [50.0, -4.8],  # centre of WC_1
            [50.0, -6.3],  # 1.5 m right of it, still within its 1.6 m half-width
            [50.0, -7.4],  # on the sidewalk
            [50.0, 40.0],  # in a field
            [200.0, 0.0],  # in the middle of junction C, on its internal lanes
        ]
    )
    assert mini.index.on_driving_lane(points).tolist() == [True, True, False, False, True]
