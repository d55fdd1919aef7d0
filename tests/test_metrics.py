"""Metrics on hand-computed cases: the paper's route equations, Bench2Drive success, efficiency, comfort,
multi-ability and the route-set summary."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from cmudrive.bench.metrics import (
    ABILITIES,
    comfort_score,
    efficiency,
    infractions_per_km,
    is_success,
    multi_ability,
    passes_traffic_signs,
    route_result,
    route_scores,
    summarize,
    v2v_totals,
)
from cmudrive.bench.records import (
    INFRACTION_KEYS,
    STATUS_BLOCKED,
    STATUS_COMPLETED,
    STATUS_PERFECT,
    STATUS_TIMEOUT,
    CavResult,
    Infraction,
    RouteResult,
    record_problems,
)
from cmudrive.bench.scenario_types import SCENARIO_TYPES

DT = 0.05  # [s] frame time at 20 Hz


def event(key: str, factor: float = 1.0) -> Infraction:
    return Infraction(key=key, tick=10, time=0.5, x=0.0, y=0.0, message=key, factor=factor)


def cav(
    rc: float = 100.0,
    is_: float = 1.0,
    status: str | None = None,
    events: tuple[str, ...] = (),
    cav_id: str = "0",
    length: float = 1000.0,
    **kw: Any,
) -> CavResult:
    infractions: dict[str, list[Infraction]] = {k: [] for k in INFRACTION_KEYS}
    for k in events:
        infractions[k].append(event(k))
    if status is None:
        status = STATUS_PERFECT if rc == 100.0 and not events else STATUS_COMPLETED
    return CavResult(cav_id, status, rc, is_, length, infractions, **kw)


def route(
    cavs: list[CavResult], scenario: str = "Accident", weather: str = "ClearNoon", rid: str = "r0"
) -> RouteResult:
    return route_result(rid, "downtown", weather, scenario, cavs)


# --- route level -------------------------------------------------------------------------------------


def test_one_pedestrian_collision_halves_the_route():
    cavs = [cav(100.0, 1.0), cav(100.0, 0.5, events=("collisions_pedestrian",), cav_id="1")]
    assert route_scores(cavs) == (100.0, 0.5, 50.0, False)


def test_success_needs_every_cav_perfect():
    assert route_scores([cav(100.0, 1.0), cav(100.0, 1.0)]) == (100.0, 1.0, 100.0, True)
    rc, _, ds, ss = route_scores([cav(100.0, 1.0), cav(99.0, 1.0, status=STATUS_BLOCKED)])
    assert (rc, ds, ss) == (99.5, 99.5, False)


def test_route_scores_mean_completion_product_of_infraction_scores():
    rc, is_, ds, ss = route_scores([cav(100.0, 1.0), cav(80.0, 0.6), cav(60.0, 0.5)])
    assert rc == pytest.approx(80.0) and is_ == pytest.approx(0.3) and ds == pytest.approx(24.0)
    assert not ss
    with pytest.raises(ValueError, match="at least one CAV"):
        route_scores([])


def test_route_status_and_record():
    assert route([cav(), cav()]).status == STATUS_PERFECT
    assert route([cav(), cav(100.0, 0.6, events=("collisions_vehicle",))]).status == STATUS_COMPLETED
    failed = route([cav(), cav(40.0, status=STATUS_TIMEOUT), cav(10.0, status=STATUS_BLOCKED)])
    assert failed.status == STATUS_TIMEOUT
    assert failed.num_cavs == 3 and failed.route_completion == pytest.approx(50.0)
    crashed = route_result("r", "t", "w", "Accident", [cav()], status="Failed - Agent crashed")
    assert crashed.status == "Failed - Agent crashed"
    nothing = route_result("r", "t", "w", "Accident", [], num_cavs=4)  # crashed before any CAV was scored
    assert (nothing.num_cavs, nothing.driving_score, nothing.success) == (4, 0.0, False)
    assert nothing.status == "Failed - Simulation crashed"


def test_bench2drive_success_ignores_min_speed_only():
    assert is_success(cav(events=("min_speed_infractions",)))
    assert not is_success(cav(100.0, 0.65, events=("collisions_layout",)))
    assert not is_success(cav(99.0, 1.0, status=STATUS_BLOCKED))
    # an unpenalised but recorded infraction other than min speed still fails (e.g. 0 % outside lanes)
    assert not is_success(cav(events=("outside_route_lanes",)))
    assert is_success(route([cav(), cav(events=("min_speed_infractions",))]))
    assert not is_success(route([cav(), cav(100.0, 0.7, events=("red_light",))]))


# --- efficiency and comfort --------------------------------------------------------------------------


def test_efficiency_drops_values_above_1000_percent():
    assert efficiency([50.0, 100.0, 1500.0]) == pytest.approx(75.0)
    assert efficiency([80.0, 1000.0]) == pytest.approx(540.0)  # 1000 itself is kept
    assert efficiency([2000.0]) is None
    assert efficiency([]) is None


def straight(speed: np.ndarray) -> tuple[np.ndarray, ...]:
    """t, x, y, yaw, speed of a car on the x axis whose speed per frame is given (Euler integrated)."""
    n = len(speed)
    x = np.concatenate([[0.0], np.cumsum(speed[:-1]) * DT])
    return np.arange(n) * DT, x, np.zeros(n), np.zeros(n), speed


def from_rates(speed: np.ndarray, yaw_rate: np.ndarray) -> tuple[np.ndarray, ...]:
    """t, x, y, yaw, speed of a car driving with the given speed [m/s] and yaw rate [rad/s] per frame."""
    yaw = np.concatenate([[0.0], np.cumsum(yaw_rate[:-1]) * DT])
    x = np.concatenate([[0.0], np.cumsum(speed[:-1] * np.cos(yaw[:-1])) * DT])
    y = np.concatenate([[0.0], np.cumsum(speed[:-1] * np.sin(yaw[:-1])) * DT])
    return np.arange(len(speed)) * DT, x, y, yaw, speed


def test_comfort_constant_speed_straight_line_is_comfortable():
    assert comfort_score(*straight(np.full(100, 10.0))) == 1.0


def test_comfort_braking_spike_fails_exactly_its_window():
    accel = np.zeros(100)  # 5 windows of 20 frames
    accel[47:53] = -6.0  # [m/s^2] 0.3 s of hard braking in the middle of window 2 (frames 40-59)
    speed = 10.0 + np.concatenate([[0.0], np.cumsum(accel[:-1]) * DT])
    assert comfort_score(*straight(speed)) == pytest.approx(4 / 5)


def test_comfort_windows_and_short_trajectories():
    assert comfort_score(*straight(np.full(19, 5.0))) is None
    assert comfort_score(*straight(np.full(20, 5.0))) == 1.0
    accel = np.zeros(50)  # 2 full windows + 10 dropped frames that brake hard
    accel[46:50] = -6.0  # smoothing spreads an event ~6 frames (0.3 s): it starts clear of window 1
    speed = 10.0 + np.concatenate([[0.0], np.cumsum(accel[:-1]) * DT])
    assert comfort_score(*straight(speed)) == 1.0


@pytest.mark.parametrize(("accel", "expected"), [(2.0, 1.0), (3.0, 0.0), (-4.0, 1.0), (-4.2, 0.0)])
def test_comfort_longitudinal_acceleration_bounds(accel: float, expected: float):
    t = np.arange(60) * DT
    speed = 20.0 + accel * t  # [m/s] stays positive over 3 s
    x = 20.0 * t + 0.5 * accel * t**2
    assert comfort_score(t, x, 0 * t, 0 * t, speed) == expected


@pytest.mark.parametrize(
    ("speed", "yaw_rate", "expected"),
    [
        (10.0, 0.4, 1.0),  # lateral 4 m/s^2
        (15.0, 0.4, 0.0),  # lateral 6 m/s^2 > 4.89
        (2.0, 0.9, 1.0),  # yaw rate 0.9 rad/s (51.6 deg/s, which the public script would reject)
        (2.0, 1.0, 0.0),  # yaw rate 1.0 rad/s > 0.95
    ],
)
def test_comfort_on_a_circle(speed: float, yaw_rate: float, expected: float):
    t = np.arange(60) * DT
    r, yaw = speed / yaw_rate, yaw_rate * t  # [m], [rad]
    assert comfort_score(t, r * np.sin(yaw), r * (1 - np.cos(yaw)), yaw, np.full(60, speed)) == expected


def test_comfort_yaw_wrapping_is_ignored():
    t, x, y, yaw, v = from_rates(np.full(200, 3.0), np.full(200, 0.3))  # 3 rad over 10 s crosses +-pi
    wrapped = np.angle(np.exp(1j * (yaw + 2.0)))  # start at 2 rad: the heading wraps once
    c, s = np.cos(2.0), np.sin(2.0)
    assert comfort_score(t, c * x - s * y, s * x + c * y, wrapped, v) == 1.0


@pytest.mark.parametrize(("jerk", "expected"), [(3.0, 1.0), (5.0, 0.5)])
def test_comfort_longitudinal_jerk_uses_the_real_frame_time(jerk: float, expected: float):
    """A ramp of the acceleration at ``jerk`` m/s^3 to 2.2 m/s^2 starting at 0.2 s (window 0 of 2); with
    the public script's 0.1 s frame time 5 m/s^3 would read 2.5 m/s^3 and pass."""
    accel = np.minimum(jerk * np.maximum(np.arange(40) * DT - 0.2, 0.0), 2.2)
    speed = 5.0 + np.concatenate([[0.0], np.cumsum(accel[:-1]) * DT])
    assert comfort_score(*straight(speed)) == expected


@pytest.mark.parametrize(("yaw_accel", "expected"), [(1.0, 1.0), (2.4, 0.5)])
def test_comfort_yaw_acceleration_is_the_derivative_of_yaw_rate(yaw_accel: float, expected: float):
    """The yaw rate ramps to 0.6 rad/s in window 0 (of 2) at 1 m/s: rate and lateral acceleration stay
    within bounds, only the yaw acceleration can fail (the public script tests the rate twice)."""
    rate = np.minimum(yaw_accel * np.maximum(np.arange(40) * DT - 0.2, 0.0), 0.6)
    assert comfort_score(*from_rates(np.full(40, 1.0), rate)) == expected


def test_comfort_rejects_bad_input():
    t, x, y, yaw, v = straight(np.full(40, 5.0))
    with pytest.raises(ValueError, match="evenly spaced"):
        comfort_score(t * np.linspace(1.0, 1.5, 40), x, y, yaw, v)
    with pytest.raises(ValueError, match="one length"):
        comfort_score(t, x[:-1], y, yaw, v)
    x[3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        comfort_score(t, x, y, yaw, v)


# --- multi-ability -----------------------------------------------------------------------------------


def test_ability_groups_use_the_canonical_names():
    for types in ABILITIES.values():
        assert types <= set(SCENARIO_TYPES)
    assert "VehicleOpensDoorTwoWays" in ABILITIES["Overtaking"]
    assert "MergerIntoSlowTraffic" in ABILITIES["Merging"]
    assert "ParkingCrossingPedestrian" in ABILITIES["Emergency_Brake"]
    assert "VanillaNonSignalizedTurnEncounterStopsign" in ABILITIES["Traffic_Signs"]
    assert len(ABILITIES["Traffic_Signs"]) == 19


def test_multi_ability_on_a_small_set():
    lead_past_junction = cav(60.0, 1.0, status=STATUS_BLOCKED, first_junction_completion=40.0)
    routes = [
        route([cav(), cav()], "Accident", rid="a"),  # Overtaking: pass
        route([cav(), cav(100.0, 0.6, events=("collisions_vehicle",))], "Accident", rid="b"),  # fail
        route([cav()], "InvadingTurn", rid="c"),  # Give_Way: pass
        route([cav(), cav()], "PedestrianCrossing", rid="d"),  # Emergency_Brake + Traffic_Signs: pass
        # Merging fails (RC 80); Traffic_Signs passes: CAV 0 got past its first junction, no light run
        route([lead_past_junction, cav()], "SignalizedJunctionLeftTurn", rid="e"),
        route([cav(100.0, 0.7, events=("red_light",))], "T_Junction", rid="f"),  # Traffic_Signs: fail
        route([cav(50.0, 1.0, status=STATUS_BLOCKED)], "T_Junction", rid="g"),  # no junction info: fail
    ]
    assert passes_traffic_signs(routes[4]) and not passes_traffic_signs(routes[6])
    rates = multi_ability(routes)
    assert rates == {
        "Overtaking": 50.0,
        "Merging": 0.0,
        "Emergency_Brake": 100.0,
        "Give_Way": 100.0,
        "Traffic_Signs": 50.0,
        "mean": 60.0,
    }
    partial = multi_ability(routes[:2])  # only Overtaking has routes
    assert partial["Merging"] is None and partial["mean"] == 50.0


# --- summary -----------------------------------------------------------------------------------------


def three_routes() -> list[RouteResult]:
    return [
        route([cav(), cav()], "Accident", "ClearNoon", "r1"),  # DS 100, SS
        route([cav(), cav(100.0, 0.5, events=("collisions_pedestrian",))], "Accident", "HardRainNoon", "r2"),
        route([cav(40.0, status=STATUS_BLOCKED), cav(), cav(), cav(10.0, status=STATUS_BLOCKED)],
              "InvadingTurn", "ClearNoon", "r3"),  # RC 62.5, DS 62.5
    ]  # fmt: skip


def test_summary_driving_score_and_success_rate():
    s = summarize(three_routes())
    assert s["driving_score"] == pytest.approx((100.0 + 50.0 + 62.5) / 3)
    assert s["success_rate"] == pytest.approx(100.0 / 3)
    assert s["route_completion"] == pytest.approx((100.0 + 100.0 + 62.5) / 3)
    assert s["infraction_score"] == pytest.approx(2.5 / 3)
    assert (s["num_routes"], s["num_expected"], s["num_missing"], s["num_crashed"]) == (3, None, 0, 0)


def test_summary_missing_routes_count_zero():
    s = summarize(three_routes(), expected_routes=5)
    assert s["driving_score"] == pytest.approx(212.5 / 5)
    assert s["success_rate"] == pytest.approx(20.0)
    assert (s["num_routes"], s["num_expected"], s["num_missing"]) == (3, 5, 2)
    with pytest.raises(ValueError, match="expected_routes"):
        summarize(three_routes(), expected_routes=2)
    with pytest.raises(ValueError, match="duplicate"):
        summarize([*three_routes(), three_routes()[0]])


def test_summary_breakdowns():
    s = summarize(three_routes())
    assert set(s) >= {
        "driving_score", "success_rate", "num_routes", "num_expected", "num_crashed", "efficiency",
        "comfortness", "multi_ability", "by_scenario_type", "by_ability", "by_weather", "by_num_cavs",
        "infractions_per_km", "v2v",
    }  # fmt: skip
    assert list(s["by_scenario_type"]) == ["Accident", "InvadingTurn"]
    assert s["by_scenario_type"]["Accident"] == {"driving_score": 75.0, "success_rate": 50.0, "num_routes": 2}
    assert list(s["by_weather"]) == ["ClearNoon", "HardRainNoon"]
    assert s["by_weather"]["ClearNoon"]["driving_score"] == pytest.approx(81.25)
    assert list(s["by_num_cavs"]) == ["2", "4"]
    assert s["by_num_cavs"]["2"]["num_routes"] == 2
    assert list(s["by_ability"]) == ["Overtaking", "Give_Way"]
    assert s["multi_ability"]["Overtaking"] == 50.0 and s["multi_ability"]["Give_Way"] == 0.0


def test_v2v_totals_sum_the_routes_counters_and_the_share_of_named_partners():
    a, b, none = three_routes()
    a.v2v = {
        "messages": 100,
        "bytes": 100 * 12316,
        "cav_ticks": 120,
        "named": 30,
        "named_taken": 24,
        "bytes_per_message": 12316.0,
    }
    b.v2v = {"messages": 40, "bytes": 40 * 12316, "cav_ticks": 80, "named": 10, "named_taken": 10,
             "bytes_per_message": 12316.0}  # fmt: skip
    total = v2v_totals([a, b, none])  # the route without counters (no V2V) adds nothing
    assert total is not None
    assert (total["messages"], total["cav_ticks"], total["named"], total["named_taken"]) == (140, 200, 40, 34)
    assert total["bytes_per_message"] == 12316.0
    assert total["named_share"] == pytest.approx(0.2)  # 40 of 200 partner choices named by the agent
    assert summarize([a, b, none])["v2v"] == total
    b.v2v = {"messages": 0, "bytes": 0}  # an older record without the partner counters
    assert v2v_totals([b])["named_share"] is None  # type: ignore[index]
    assert v2v_totals([none]) is None and summarize([none])["v2v"] is None


def test_summary_efficiency_and_comfort_average_cavs_then_routes():
    r1 = route([cav(min_speed_checkpoints=[50.0, 1500.0], comfort=1.0), cav(min_speed_checkpoints=[100.0])])
    r2 = route([cav(min_speed_checkpoints=[80.0], comfort=0.5)], rid="r2")
    r3 = route([cav()], rid="r3")  # neither value: skipped
    s = summarize([r1, r2, r3])
    assert s["efficiency"] == pytest.approx(((50.0 + 100.0) / 2 + 80.0) / 2)
    assert s["comfortness"] == pytest.approx(75.0)


def test_infractions_per_km_over_distance_driven():
    r = route([cav(100.0, 0.36, events=("collisions_vehicle", "collisions_vehicle")),
               cav(50.0, 0.6, events=("collisions_vehicle",), length=1000.0)])  # fmt: skip
    per_km = infractions_per_km([r])
    assert per_km is not None
    assert per_km["collisions_vehicle"] == pytest.approx(3 / 1.5)
    assert per_km["red_light"] == 0.0
    assert infractions_per_km([route([cav(0.0, status=STATUS_BLOCKED)])]) is None


def test_first_junction_completion_round_trips_and_defaults():
    r = route([cav(first_junction_completion=42.0)])
    again = RouteResult.from_json(r.to_json())
    assert again.cavs[0].first_junction_completion == 42.0
    old = r.to_json()
    del old["cavs"][0]["first_junction_completion"]  # records written before the field existed
    assert RouteResult.from_json(old).cavs[0].first_junction_completion is None
    assert math.isclose(again.driving_score, 100.0)


def test_infractions_carry_carla_frame_places_and_older_records_get_them():
    """Route files speak CARLA's frame (y mirrored against our map frame); an infraction at map
    y = +1.6 is at CARLA y = -1.6, and a record written before the CARLA pair existed reads back with it."""
    inf = Infraction("red_light", 10, 0.5, 195.0, 1.6, "ran a red light", factor=0.7)
    assert (inf.carla_x, inf.carla_y) == (195.0, -1.6)
    r = route([cav(100.0, 0.7, events=("red_light",))])
    r.cavs[0].infractions["red_light"][0] = inf
    data = r.to_json()
    assert data["cavs"][0]["infractions"]["red_light"][0]["carla_y"] == -1.6
    old = r.to_json()
    for key in ("carla_x", "carla_y"):
        del old["cavs"][0]["infractions"]["red_light"][0][key]
    again = RouteResult.from_json(old).cavs[0].infractions["red_light"][0]
    assert (again.carla_x, again.carla_y) == (195.0, -1.6)
    nan = Infraction("route_dev", 1, 0.05, float("nan"), float("nan"), "lost")  # position unknown
    assert math.isnan(nan.carla_x or 0.0) and math.isnan(nan.carla_y or 0.0)
    assert record_problems(route([cav(0.0, 1.0, status=STATUS_BLOCKED)])) == []


@pytest.mark.parametrize(
    ("carla", "problem"),
    [
        ((195.0, 1.6), r"carla_x, carla_y \(195\.0, 1\.6\) are not the map frame's x, -y \(195\.0, -1\.6\)"),
        ((195.0, "south"), "carla_y must be a number, got 'south'"),
    ],
)
def test_a_record_whose_frames_disagree_is_refused(carla: tuple[object, object], problem: str) -> None:
    data = route([cav(100.0, 0.7, events=("red_light",))]).to_json()
    inf = data["cavs"][0]["infractions"]["red_light"][0]
    inf.update(x=195.0, y=1.6, carla_x=carla[0], carla_y=carla[1])
    with pytest.raises(ValueError, match=problem):
        RouteResult.from_json(data)


def test_outside_lanes_per_km_is_the_distance_driven_outside():
    """Upstream reports kilometres driven outside the route lanes per km, not events per km: a CAV that
    drove 40 % of its 1 km route outside (factor 0.6) over 2 km driven gives 0.2 km per km."""
    outside = cav(100.0, 0.6, events=("outside_route_lanes",))
    outside.infractions["outside_route_lanes"][0] = event("outside_route_lanes", factor=0.6)
    per_km = infractions_per_km([route([outside, cav(100.0)])])
    assert per_km is not None and per_km["outside_route_lanes"] == pytest.approx(0.4 / 2.0)
