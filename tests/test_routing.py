"""Route planning on the mini network: lane-level paths, road options, 1 m spacing, densification."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from cmudrive.maps import LanePos, RoadMap, RoadOption, RouteError, RoutePlanner, densify
from cmudrive.maps.index import wrap_angle


def _lane_sequence(m: RoadMap, lanes: np.ndarray) -> list[str]:
    return [str(m.lane_ids[k]) for k, _ in itertools.groupby(lanes.tolist())]


def test_left_turn_route_changes_lane_then_turns_left(mini: RoadMap) -> None:
    """From the right lane of W-C to the road north of C: change left, then turn left at C."""
    route = RoutePlanner(mini).plan((20.0, -4.8), (201.6, 150.0), start_heading=0.0, goal_heading=np.pi / 2)
    lanes = _lane_sequence(mini, route.lane)
    assert lanes[0] == "WC_2" and lanes[-1] == "CN_1"
    assert all(name.startswith(":C_") for name in lanes[1:-1])
    options = route.option
    change = np.flatnonzero(options == RoadOption.CHANGELANELEFT)
    assert len(change) > 0 and route.distance[change[-1]] <= 25.0  # the change is done within 20-25 m
    turn = np.flatnonzero(options == RoadOption.LEFT)
    assert np.all(route.in_junction[turn]) and np.all(route.in_junction == (options == RoadOption.LEFT))
    # geometry: starts and ends where asked, 1 m spacing, and a smooth heading (< 25 deg per metre)
    assert route.xy[0] == pytest.approx([20.0, -4.8], abs=1e-6)
    assert route.xy[-1] == pytest.approx([201.6, 150.0], abs=1e-6)
    steps = np.diff(route.distance)
    assert np.allclose(steps[:-1], 1.0) and 0.0 < steps[-1] <= 1.0
    assert np.allclose(
        np.linalg.norm(np.diff(route.xy, axis=0), axis=1), steps, atol=0.05
    )  # chords of polyline corners
    assert np.max(np.abs(wrap_angle(np.diff(route.heading)))) < np.radians(25.0)
    assert route.heading[0] == pytest.approx(0.0, abs=0.05)
    assert route.heading[-1] == pytest.approx(np.pi / 2, abs=1e-6)
    assert route.length == pytest.approx(180.0 + 150.0, rel=0.1)
    assert np.allclose(route.speed_limit[route.option == RoadOption.LANEFOLLOW][-1], 11.11)


def test_straight_through_a_junction_is_straight(mini: RoadMap) -> None:
    route = RoutePlanner(mini).plan((20.0, -4.8), (300.0, -1.6), start_heading=0.0)
    assert _lane_sequence(mini, route.lane)[-1] == "CE_1"
    in_junction = route.option[route.in_junction]
    assert len(in_junction) > 5 and np.all(in_junction == RoadOption.STRAIGHT)


def test_goal_behind_start_on_a_two_way_road_loops_around(mini: RoadMap) -> None:
    """Going back 50 m on a two-way road means driving on, turning at a junction and coming back."""
    planner = RoutePlanner(mini)
    start = LanePos(mini.lane("CE_1"), 100.0)
    goal = LanePos(mini.lane("CE_1"), 50.0)
    route = planner.plan_lanes(start, goal)
    lanes = _lane_sequence(mini, route.lane)
    assert lanes[0] == "CE_1" and lanes[-1] == "CE_1" and "EC_1" in lanes
    assert route.length > 150.0


def test_unreachable_goal_names_both_lanes(mini: RoadMap) -> None:
    planner = RoutePlanner(mini)
    with pytest.raises(RouteError, match=r"no route in map 'mini' from lane WC_1 .* to lane I_0"):
        planner.plan((20.0, -4.8), (650.0, 298.4))
    with pytest.raises(RouteError, match=r"point \(1000.0, 1000.0\) is more than 10 m from any driving lane"):
        planner.plan((20.0, -4.8), (1000.0, 1000.0))


def test_densify_joins_sparse_keypoints(mini: RoadMap) -> None:
    """Keypoints ~150 m apart, as in leaderboard route files, become one dense route through all of them."""
    keypoints = np.array([[10.0, -1.6], [160.0, -1.6], [201.6, 100.0], [230.0, 198.4]])
    route = densify(mini, keypoints)
    for kp in keypoints:
        assert np.min(np.linalg.norm(route.xy - kp, axis=1)) < 0.6
    assert _lane_sequence(mini, route.lane)[-1] == "NNE_1"
    assert np.all(np.diff(route.distance)[:-1] == pytest.approx(1.0))
    opts = {RoadOption(int(o)) for o in route.option}
    assert {RoadOption.LEFT, RoadOption.RIGHT, RoadOption.LANEFOLLOW} <= opts


def test_densify_rejects_bad_keypoints(mini: RoadMap) -> None:
    with pytest.raises(RouteError, match="at least 2 keypoints"):
        densify(mini, np.array([[10.0, -1.6]]))
    with pytest.raises(RouteError, match="keypoint 1: point"):
        densify(mini, np.array([[10.0, -1.6], [5000.0, 0.0]]))
