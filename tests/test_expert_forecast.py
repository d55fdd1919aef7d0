"""Hazard forecast of the expert: named synthetic scenes in physical units.

The ego is the CAV at row 0, a 4.89 x 2.10 m sedan heading +x from the origin on a straight path unless a
test says otherwise; other cars are 4.5 x 1.85 m. Default margins: ego +1.0 m in front and +0.2 m per side,
others +0.25 m per end and +0.2 m per side.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cmudrive.agents.expert.forecast import Forecast, ForecastConfig, Forecaster, forecast
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot

CAV_LENGTH, CAV_WIDTH = 4.89, 2.10  # [m]
CAR_LENGTH, CAR_WIDTH = 4.5, 1.85  # [m]
DT = 0.05  # [s] tick


def scene(
    actors: list[dict[str, float]],
    time: float = 0.0,
    ids: list[str] | None = None,
    ego: dict[str, float] | None = None,
) -> Snapshot:
    """Row 0: the ego CAV at the origin heading +x at 8 m/s (``ego`` overrides); then ``actors``."""
    rows = [{"x": 0.0, "y": 0.0, "yaw": 0.0, "speed": 8.0, "role": Role.CAV, **(ego or {})}, *actors]
    col = {
        "x": [r.get("x", 0.0) for r in rows],
        "y": [r.get("y", 0.0) for r in rows],
        "yaw": [r.get("yaw", 0.0) for r in rows],
        "speed": [r.get("speed", 0.0) for r in rows],
        "kind": np.array([r.get("kind", ActorKind.CAR) for r in rows], np.int8),
        "role": np.array([r.get("role", Role.BACKGROUND) for r in rows], np.int8),
        "length": [r.get("length", CAV_LENGTH if i == 0 else CAR_LENGTH) for i, r in enumerate(rows)],
        "width": [r.get("width", CAV_WIDTH if i == 0 else CAR_WIDTH) for i, r in enumerate(rows)],
    }
    if ids is not None:
        col["ids"] = np.array(ids)
    return Snapshot.from_rows(
        round(time / DT), time, np.array([], str), **{k: np.asarray(v) for k, v in col.items()}
    )


def straight_path(x0: float = 0.0, y0: float = 0.0, yaw: float = 0.0, length: int = 60) -> np.ndarray:
    """(1, P, 2) points 1 m apart from (x0, y0) along ``yaw``."""
    s = np.arange(length, dtype=np.float64)
    return np.stack([x0 + s * math.cos(yaw), y0 + s * math.sin(yaw)], axis=1)[None]


def run(
    snap: Snapshot, speed: float = 8.0, target: float | None = None, path: np.ndarray | None = None
) -> Forecast:
    return Forecaster().forecast(
        snap,
        np.array([0]),
        straight_path() if path is None else path,
        np.array([speed]),
        np.array([speed if target is None else target]),
    )


def crossing(ego_distance: float, other_distance: float, speed: float = 8.0) -> Snapshot:
    """Ego heading +x, other heading +y; their paths cross at (0, 0)."""
    other = {"x": 0.0, "y": -other_distance, "yaw": math.pi / 2, "speed": speed}
    return scene([other], ego={"x": -ego_distance, "speed": speed})


# ---- crossings -------------------------------------------------------------------------------------


def first_corner_contact(ego_distance: float, other_distance: float, speed: float) -> float:
    """Time [s] at which the enlarged boxes of the crossing scene first overlap (both spans must meet)."""
    ego_front = CAV_LENGTH / 2 + 1.0  # ego front reaches the other's near side
    other_side = CAR_WIDTH / 2 + 0.2
    other_front = CAR_LENGTH / 2 + 0.25
    ego_side = CAV_WIDTH / 2 + 0.2
    return max(
        (ego_distance - ego_front - other_side) / speed, (other_distance - other_front - ego_side) / speed
    )


def test_crossing_at_the_same_time_conflicts_when_the_boxes_first_meet() -> None:
    snap = crossing(10.0, 10.0)
    fc = run(snap, path=straight_path(-10.0))
    expected = first_corner_contact(10.0, 10.0, 8.0)  # 0.75 s; the centres meet at 1.25 s
    assert fc.first_conflict.shape == (1, 2)
    assert math.isinf(fc.first_conflict[0, 0])  # the CAV itself
    assert expected <= fc.first_conflict[0, 1] <= expected + 0.1 + 1e-9
    rows, times = fc.nearest()
    assert rows.tolist() == [1] and times[0] == fc.first_conflict[0, 1]
    assert (
        fc.ego_arrival[0, 1] <= fc.first_conflict[0, 1] and fc.actor_arrival[0, 1] <= fc.first_conflict[0, 1]
    )


def test_crossing_at_speed_of_town_traffic_conflicts_after_about_a_second() -> None:
    fc = run(crossing(15.0, 15.0, 10.0), speed=10.0, path=straight_path(-15.0))
    assert 1.0 <= fc.first_conflict[0, 1] <= 1.3


def test_crossing_three_seconds_later_is_no_conflict_within_two_seconds() -> None:
    fc = run(crossing(10.0, 10.0 + 3.0 * 8.0), path=straight_path(-10.0))
    assert not fc.conflict.any()
    assert fc.nearest() == (pytest.approx([-1]), pytest.approx([math.inf]))


@pytest.mark.parametrize(
    ("ego_distance", "other_distance", "ego_first"), [(9.0, 13.0, True), (13.0, 9.0, False)]
)
def test_who_reaches_the_crossing_first(ego_distance: float, other_distance: float, ego_first: bool) -> None:
    fc = run(crossing(ego_distance, other_distance), path=straight_path(-ego_distance))
    assert fc.conflict[0, 1]
    assert fc.ego_first[0, 1] == ego_first


# ---- lanes -----------------------------------------------------------------------------------------


def test_parallel_car_in_the_next_lane_is_no_conflict() -> None:
    fc = run(scene([{"x": 1.0, "y": 3.5, "speed": 8.0}]))
    assert not fc.conflict.any()
    assert not fc.behind.any()


def test_oncoming_car_in_the_opposite_lane_is_no_conflict() -> None:
    fc = run(scene([{"x": 30.0, "y": 3.5, "yaw": math.pi, "speed": 10.0}]))
    assert not fc.conflict.any()


def test_oncoming_car_in_our_lane_conflicts_and_neither_is_first() -> None:
    fc = run(scene([{"x": 30.0, "y": 0.0, "yaw": math.pi, "speed": 8.0}]))
    gap = 30.0 - CAV_LENGTH / 2 - 1.0 - CAR_LENGTH / 2 - 0.25  # [m] closing at 16 m/s
    assert gap / 16.0 <= fc.first_conflict[0, 1] <= gap / 16.0 + 0.1 + 1e-9
    assert not fc.ego_first[0, 1]  # a tie: the ego yields


def test_stopped_car_ahead_conflicts_and_car_behind_is_behind() -> None:
    snap = scene([{"x": 8.0, "speed": 0.0}, {"x": -6.0, "speed": 0.0}])
    fc = run(snap, speed=5.0)
    gap = 8.0 - CAV_LENGTH / 2 - 1.0 - CAR_LENGTH / 2 - 0.25  # 2.05 m at 5 m/s
    assert gap / 5.0 <= fc.first_conflict[0, 1] <= gap / 5.0 + 0.1 + 1e-9
    assert not fc.ego_first[0, 1]  # the stopped car is already there
    assert fc.actor_arrival[0, 1] == 0.0
    assert fc.behind[0].tolist() == [False, False, True]
    assert not fc.conflict[0, 2]  # the ego drives away from it


def test_ego_braking_to_a_stop_short_of_a_stopped_car_is_no_conflict() -> None:
    snap = scene([{"x": 14.0, "speed": 0.0}])  # 7.3 m of free gap; braking from 5 m/s at 4 m/s^2 takes 3.1 m
    assert run(snap, speed=5.0, target=5.0).conflict[0, 1]
    assert not run(snap, speed=5.0, target=0.0).conflict[0, 1]


def test_car_closing_from_behind_conflicts_with_the_ego_first() -> None:
    fc = run(scene([{"x": -9.0, "speed": 15.0}]), speed=3.0)
    assert fc.conflict[0, 1] and fc.behind[0, 1]
    assert fc.ego_first[0, 1]


def test_ego_follows_a_curved_path() -> None:
    """Ego turning left on a 10 m radius around (0, 10); a stopped car on the arc, off the straight line."""
    angle = np.arange(0.0, 3.0, 0.1)  # 1 m apart on a 10 m radius
    path = np.stack([10.0 * np.sin(angle), 10.0 - 10.0 * np.cos(angle)], axis=1)[None]
    car = {
        "x": 10.0 * math.sin(1.2),
        "y": 10.0 - 10.0 * math.cos(1.2),
        "yaw": 1.2,
        "speed": 0.0,
    }  # 12 m along
    assert run(scene([car]), path=path).conflict[0, 1]
    assert not run(scene([car])).conflict[0, 1]  # straight ahead misses it


# ---- pedestrians -----------------------------------------------------------------------------------


def test_pedestrian_crossing_ten_metres_ahead_conflicts() -> None:
    ped = {"x": 10.0, "y": -3.0, "yaw": math.pi / 2, "speed": 1.4, "kind": ActorKind.PEDESTRIAN}
    ped.update(length=0.5, width=0.5)
    fc = run(scene([ped]))
    assert 0.5 <= fc.first_conflict[0, 1] <= 1.0


def test_standing_pedestrian_stays_and_a_slow_walker_walks_half_a_metre_per_second() -> None:
    ped = {
        "x": 10.0,
        "y": -3.2,
        "yaw": math.pi / 2,
        "kind": ActorKind.PEDESTRIAN,
        "length": 0.5,
        "width": 0.5,
    }
    assert not run(scene([{**ped, "speed": 0.05}])).conflict.any()  # stands: 3.2 m > 1.25 + 0.75
    # creeping at 0.2 m/s beside the standing ego is forecast at 0.5 m/s: 0.8 m to its widened side in 1.6 s
    creeping = scene([{**ped, "x": 1.0, "y": -2.8, "speed": 0.2}])
    assert run(creeping, speed=0.0).conflict[0, 1]
    at_its_speed = ForecastConfig(walker_min_speed=0.2)  # 4 s: beyond the horizon
    assert not forecast(
        creeping, np.zeros(2), np.array([0]), straight_path(), np.zeros(1), np.zeros(1), at_its_speed
    ).conflict.any()


# ---- turning actors and yaw rates ------------------------------------------------------------------


def turning_car(time: float, rate: float, speed: float = 6.0, radius: float = 8.0) -> dict[str, float]:
    """A car turning left on a circle of ``radius`` around (0, -radius), at angle 1.5 rad at t = 2 s."""
    angle = 1.5 - rate * (2.0 - time)  # angle at time ``time``, reaching 1.5 rad at t = 2 s
    return {
        "x": radius * math.cos(angle),
        "y": -radius + radius * math.sin(angle),
        "yaw": angle + math.pi / 2,
        "speed": speed,
    }


def test_turning_car_is_forecast_on_its_arc() -> None:
    """Ego standing at the origin; a car 8 m ahead and 8 m to the right, heading north and turning left
    (6 m/s on an 8 m radius), sweeps into it; with constant heading it would pass 8 m ahead."""
    forecaster = Forecaster()
    before = scene([turning_car(-DT, 0.75)], time=-DT)
    now = scene([turning_car(0.0, 0.75)], time=0.0)
    forecaster.update(before)
    forecaster.update(now)
    assert forecaster.yaw_rate[1] == pytest.approx(0.75, rel=1e-6)
    path, still = straight_path(), np.array([0.0])
    fc = forecaster.forecast(now, np.array([0]), path, still, still)
    assert fc.conflict[0, 1] and fc.first_conflict[0, 1] <= 2.0
    # without the previous snapshot the yaw rate is 0: straight on, no conflict
    assert not Forecaster().forecast(now, np.array([0]), path, still, still).conflict[0, 1]


def test_yaw_rate_is_clipped_and_zero_for_pedestrians() -> None:
    config = ForecastConfig(max_yaw_rate=0.1)
    now = scene([turning_car(0.0, 0.75)])
    # clipped to 0.1 rad/s the car nearly drives straight: no conflict
    fc = forecast(
        now, np.array([0.0, 0.75]), np.array([0]), straight_path(), np.zeros(1), np.zeros(1), config
    )
    assert not fc.conflict.any()
    ped = {"x": 6.0, "y": -6.0, "yaw": math.pi, "speed": 1.5, "kind": ActorKind.PEDESTRIAN}
    snap = scene([ped])  # walks west, 6 m to the right of the ego's lane: would hit it if it turned
    fc = forecast(snap, np.array([0.0, 0.9]), np.array([0]), straight_path(), np.zeros(1), np.zeros(1))
    assert not fc.conflict.any()


def test_yaw_rate_matches_rows_by_id_when_actors_come_and_go() -> None:
    forecaster = Forecaster()
    forecaster.update(
        scene([{"yaw": 0.0}, {"yaw": 1.0}, {"yaw": 3.1}], time=0.0, ids=["cav0", "a", "b", "c"])
    )
    assert forecaster.yaw_rate.tolist() == [0.0, 0.0, 0.0, 0.0]  # first snapshot: nothing to compare with
    # "b" left, "d" came, "c" crossed +-pi (3.1 -> -3.1 is a turn of +0.083 rad), rows reordered
    later = scene([{"yaw": -3.1}, {"yaw": 0.5}, {"yaw": 0.02}], time=0.1, ids=["cav0", "c", "d", "a"])
    forecaster.update(later)
    expected = [0.0, (2 * math.pi - 6.2) / 0.1, 0.0, 0.02 / 0.1]
    np.testing.assert_allclose(forecaster.yaw_rate, expected, atol=1e-9)
    forecaster.update(later)  # the same snapshot again: unchanged
    np.testing.assert_allclose(forecaster.yaw_rate, expected, atol=1e-9)
    again = scene([{"yaw": -3.1}, {"yaw": 0.5}], time=0.1, ids=["cav0", "c", "d"])  # same instant, rebuilt
    forecaster.update(again)
    np.testing.assert_allclose(forecaster.yaw_rate, expected[:3], atol=1e-9)


# ---- bookkeeping -----------------------------------------------------------------------------------


def test_invalid_rows_and_actors_beyond_the_radius_are_not_rolled() -> None:
    snap = scene([{"x": 8.0}, {"x": 60.0, "yaw": math.pi, "speed": 30.0}])
    snap = Snapshot(**{**snap.__dict__, "valid": np.array([True, False, True])})
    fc = run(snap)
    assert not fc.conflict.any()  # row 1 invalid; row 2 is 60 m away (it would meet the ego within 2 s)
    assert run(snap.select(np.array([0, 2])), path=straight_path()).first_conflict.shape == (1, 2)
    wide = Forecaster().forecast(snap, np.array([0]), straight_path(), np.array([8.0]), np.array([8.0]),
                                 ForecastConfig(radius=70.0))  # fmt: skip
    assert wide.conflict[0, 2]


def test_several_cavs_and_other_cavs_are_actors() -> None:
    """Two CAVs nose to tail on one lane, the rear one faster: each sees the other, with opposite roles."""
    snap = scene([{"x": 10.0, "speed": 2.0, "role": Role.CAV, "length": CAV_LENGTH, "width": CAV_WIDTH}])
    paths = np.concatenate([straight_path(), straight_path(10.0)])
    fc = Forecaster().forecast(snap, np.array([0, 1]), paths, np.array([8.0, 2.0]), np.array([8.0, 2.0]))
    assert fc.first_conflict.shape == (2, 2)
    assert fc.conflict[0, 1] and fc.conflict[1, 0]
    assert fc.first_conflict[0, 1] < fc.first_conflict[1, 0]  # the rear one's margin is in front
    assert not fc.ego_first[0, 1] and fc.ego_first[1, 0]
    assert fc.behind[1, 0] and not fc.behind[0, 1]
    rows, _ = fc.nearest(np.array([[True, True], [False, True]]))
    assert rows.tolist() == [1, -1]


def test_path_padding_and_a_cav_behind_its_path_start() -> None:
    """A path that starts 2 m ahead of the CAV and ends after 5 m (padded) is extended both ways."""
    path = straight_path(2.0, length=6)
    path = np.concatenate([path, np.repeat(path[:, -1:], 20, axis=1)], axis=1)
    fc = run(scene([{"x": 20.0, "speed": 0.0}]), path=path)
    straight = run(scene([{"x": 20.0, "speed": 0.0}]))
    assert fc.first_conflict[0, 1] == pytest.approx(straight.first_conflict[0, 1])


def test_shapes_are_checked() -> None:
    snap = scene([{"x": 8.0}])
    with pytest.raises(ValueError, match="paths"):
        Forecaster().forecast(snap, np.array([0]), np.zeros((1, 5, 3)), np.ones(1), np.ones(1))
    with pytest.raises(ValueError, match="cav_rows"):
        Forecaster().forecast(snap, np.array([2]), straight_path(), np.ones(1), np.ones(1))
    with pytest.raises(ValueError):
        ForecastConfig(step=0.0)
