"""The obstacle family on the ego lane (Accident, ConstructionObstacle, ParkedObstacle, HazardAtSideLane)
on our interurban ring road and on CARLA's Town03: CAV 0 drives its route with the PID agent (which
ignores everyone), the obstacles appear where the reference puts them (metres from the trigger point,
fractions of the lane width toward ``direction``), block CAV 0's lane (the PID agent hits them; CAV 1 on
the passing lane does not), and are cleared once CAV 0 is 50 m past the last one."""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from cmudrive.bench import EvalConfig, RouteSpec
from cmudrive.bench.records import RouteResult
from cmudrive.bench.routes import ScenarioSpec
from cmudrive.maps import RoadMap, load_map
from cmudrive.sim.background import BackgroundConfig
from tests.scenario_helpers import StopsSome, cav_track, frenet, lane_cav, run, scenario, track, trigger

T_S = 40.0  # [m] trigger point's arc length on CAV 0's lane
SCENES = {"interurban": ("R1a-R2a_0", "R1a-R2a_1"), "Town03": ("76_3", "76_4")}


def scene(town: str, kind: str, **params: str) -> tuple[RoadMap, RouteSpec]:
    m = load_map(town)
    lane, left = SCENES[town]
    cavs = (lane_cav(m, 0, lane, 20.0, 230.0), lane_cav(m, 1, left, 20.0, 230.0))
    sc = scenario(kind, trigger(m, lane, T_S), **params)
    return m, RouteSpec(f"{kind}_{town}", town, "ClearNoon", 0, cavs, (sc,))


def layout(kind: str, w: float) -> list[tuple[str, float, float]]:
    """(actor suffix, metres past T along the lane, lateral offset [m], + left) for distance = 40 m."""
    if kind == "Accident":
        return [("police", 40.0, -0.3 * w), ("car_a", 50.0, -0.3 * w), ("car_b", 56.0, -0.3 * w)]
    if kind == "ParkedObstacle":
        return [("car", 40.0, -0.35 * w)]
    if kind == "HazardAtSideLane":
        return [("bike1", 40.0, -0.275 * w), ("bike2", 49.0, -0.275 * w)]
    cones = [(f"cone{k}", 40.0 + a, 0.425 * w) for k, a in enumerate((2.0, 4.0, 6.0, 8.0))]
    cones += [(f"cone{4 + k}", 48.0, 0.425 * w - (k + 1.0)) for k in range(3)]
    return [("board", 35.0, 0.0), *cones]


# [m] E past T: fwd(50) past car B, past the parked car, and past C (not the last cone: C + 8 m)
END_PAST_T = {"Accident": 106.0, "ParkedObstacle": 90.0, "ConstructionObstacle": 90.0}


def scenario_collisions(result: RouteResult, cav: int) -> list[str]:
    return [
        inf.actor or ""
        for key, events in result.cavs[cav].infractions.items()
        if key.startswith("collisions")
        for inf in events
        if (inf.actor or "").startswith("S1:")
    ]


@pytest.mark.parametrize("town", ["interurban", "Town03"])
@pytest.mark.parametrize("kind", ["Accident", "ParkedObstacle", "ConstructionObstacle", "HazardAtSideLane"])
def test_obstacles_appear_block_the_lane_and_clear(kind: str, town: str, tmp_path: Path) -> None:
    m, spec = scene(town, kind, distance="40")
    lane = SCENES[town][0]
    w = float(m.lane_width[m.lane(lane)])
    result, log = run(spec, tmp_path)
    assert result.scenario_simulated is True
    cav0 = cav_track(log, 0)
    s_cav, _ = frenet(m, lane, cav0[:, :2])
    for suffix, ahead, offset in layout(kind, w):
        tr = track(log, f"S1:{suffix}")
        present = np.flatnonzero(~np.isnan(tr[:, 0]))
        first, last = int(present[0]), int(present[-1])
        if kind == "ConstructionObstacle":  # hidden until activation: CAV 0 2 m short of T
            assert first > 0 and T_S - 2.5 < s_cav[first] < T_S + 1.0
        else:  # present from instantiation (route start)
            assert first == 0
        s, d = frenet(m, lane, tr[first, :2])
        assert s[0] == pytest.approx(T_S + ahead, abs=0.6), suffix
        assert d[0] == pytest.approx(offset, abs=0.15), suffix
        assert abs(d[0]) < w  # the actor's box reaches into CAV 0's lane
        if kind in END_PAST_T:  # cleared once CAV 0 is ahead of E (on a curve, the lane's s is near E's)
            assert s_cav[last + 1] == pytest.approx(T_S + END_PAST_T[kind], abs=2.0), suffix
    # the PID agent drives into the blockade; CAV 1 on the passing lane goes by untouched
    assert scenario_collisions(result, 0)
    assert scenario_collisions(result, 1) == []
    if kind != "HazardAtSideLane":  # the warning sign stands beside T, off the driving lanes
        sign = track(log, "S1:sign")[0, :2]
        assert not m.index.on_driving_lane(sign[None])[0]
        assert (
            np.linalg.norm(sign - m.index.frenet_to_xy(np.array([m.lane(lane)]), np.array([T_S]))[0]) < 12.0
        )


def test_cyclists_ride_at_bicycle_speed_then_stop(tmp_path: Path) -> None:
    """bicycle_speed is km/h: 10 km/h = 2.78 m/s; after bicycle_drive_distance (5 m) they stand."""
    m, spec = scene(
        "interurban", "HazardAtSideLane", distance="40", bicycle_speed="10", bicycle_drive_distance="5"
    )
    _, log = run(spec, tmp_path)
    bike = track(log, "S1:bike1")
    present = np.flatnonzero(~np.isnan(bike[:, 0]))
    riding = present[bike[present, 3] > 0.0]
    assert bike[riding, 3] == pytest.approx(10.0 / 3.6)
    assert len(riding) * 0.05 == pytest.approx(5.0 / (10.0 / 3.6), abs=0.1)
    moved = np.linalg.norm(bike[present[-1], :2] - bike[0, :2])
    assert moved == pytest.approx(5.0, abs=0.05) and bike[present[-1], 3] == 0.0
    _, d = frenet(m, "R1a-R2a_0", bike[present[-1], :2])
    assert d[0] == pytest.approx(-0.275 * 3.5, abs=0.1)  # still at the right edge of the lane


def test_accident_with_background_traffic_on_a_carla_town(tmp_path: Path) -> None:
    """LeaveSpace and MaxSpeed act on real background traffic without breaking the run."""
    _, spec = scene("Town03", "Accident", distance="40", speed="30")
    config = EvalConfig(background=BackgroundConfig(), tick_cap=400)
    result, log = run(spec, tmp_path, config=config)
    assert result.scenario_simulated is True
    assert not np.isnan(track(log, "S1:police")[0, 0])


TWO_WAYS = {"downtown": "J0_0-J0_1_2", "Town01": "-6_2"}  # one lane each way


@pytest.mark.parametrize("town", ["downtown", "Town01"])
@pytest.mark.parametrize(
    "kind",
    ["AccidentTwoWays", "ParkedObstacleTwoWays", "ConstructionObstacleTwoWays", "HazardAtSideLaneTwoWays"],
)
def test_two_ways_variants_open_the_oncoming_lane(
    kind: str, town: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Same obstacles as the one-way types, on a road with one lane each way; 5 s after a CAV came close,
    the wrong-direction check of CAV 0 is switched off (on again at the end) and, except for the cyclists,
    an OppositeFlow drives the oncoming lane against CAV 0 at the speed limit with gaps of at least
    ``frequency.from`` metres."""
    from cmudrive.bench.criteria import RouteCriteria

    calls: list[tuple[int, bool, float]] = []
    original = RouteCriteria.set_wrong_direction_check

    def spy(self: RouteCriteria, cav: int, enabled: bool) -> None:
        calls.append((cav, enabled, self._time))
        original(self, cav, enabled)

    monkeypatch.setattr(RouteCriteria, "set_wrong_direction_check", spy)
    m = load_map(town)
    lane = TWO_WAYS[town]
    i = m.lane(lane)
    spec = RouteSpec(
        f"{kind}_{town}",
        town,
        "ClearNoon",
        0,
        (lane_cav(m, 0, lane, 5.0, min(200.0, m.lane_length[i] - 3.0)),),
        (ScenarioSpec("S1", kind, trigger(m, lane, 20.0), {"distance": "40", "frequency": FREQ[kind]}),),
    )
    result, log = run(spec, tmp_path)
    assert result.scenario_simulated is True
    first = layout(kind.removesuffix("TwoWays"), float(m.lane_width[i]))[0]
    tr = track(log, f"S1:{first[0]}")
    present = np.flatnonzero(~np.isnan(tr[:, 0]))
    s, d = frenet(m, lane, tr[present[0], :2])
    assert s[0] == pytest.approx(20.0 + first[1], abs=0.6) and d[0] == pytest.approx(first[2], abs=0.15)
    assert [(c, e) for c, e, _ in calls] == [(0, False), (0, True)]
    off = calls[0][2]
    cars = sorted(
        {a for a in log.arrays["actor_id"].tolist() if a.startswith("S1:opp")}, key=lambda a: int(a[7:])
    )
    if kind == "HazardAtSideLaneTwoWays":
        assert cars == []
        return
    assert cars, "no oncoming flow"
    opposite = int(m.lane_opposite[i])
    starts = []
    for car in cars:
        c = track(log, car)
        rows = np.flatnonzero(~np.isnan(c[:, 0]))
        assert rows[0] * 0.05 >= off - 0.1  # the flow starts with the wrong-direction switch
        _, dc = m.index.project(c[rows, :2], np.full(len(rows), opposite))
        assert np.abs(dc).max() < 0.3  # on the oncoming lane
        heading_gap = np.angle(
            np.exp(1j * (c[rows[-1], 2] - m.index.heading_at(np.array([i]), np.array([50.0]))[0]))
        )
        assert abs(heading_gap) > 2.5  # against CAV 0's direction
        assert np.nanmax(c[:, 3]) <= m.lane_speed[i] + 0.1
        starts.append(rows[0])
    if len(cars) > 1:  # the next car leaves once the last one drove a gap >= frequency.from
        first_car = track(log, cars[0])
        driven = np.linalg.norm(first_car[starts[1], :2] - first_car[starts[0], :2])
        assert driven >= 20.0 - 1.0


FREQ = {
    "AccidentTwoWays": {"from": "20", "to": "40"},
    "ParkedObstacleTwoWays": {"from": "20", "to": "40"},
    "ConstructionObstacleTwoWays": {"from": "20", "to": "40"},
    "HazardAtSideLaneTwoWays": "100",
}


@pytest.mark.parametrize(("town", "lane"), [("downtown", "J0_0-J0_1_2"), ("Town03", "-21_4")])
def test_parked_car_opens_its_door_into_the_lane(town: str, lane: str, tmp_path: Path) -> None:
    """VehicleOpensDoorTwoWays: the car parked in the side lane 40 m past T opens its door into CAV 0's
    lane when CAV 0 is 3 s away (or 10 m); 5 s later the oncoming flow starts."""
    m = load_map(town)
    i = m.lane(lane)
    sc = ScenarioSpec("S1", "VehicleOpensDoorTwoWays", trigger(m, lane, 20.0), {"distance": "40"})
    spec = RouteSpec(
        f"door_{town}",
        town,
        "ClearNoon",
        0,
        (lane_cav(m, 0, lane, 5.0, min(150.0, m.lane_length[i] - 3.0)),),
        (sc,),
    )
    result, log = run(spec, tmp_path)
    assert result.scenario_simulated is True
    car, door, cav = track(log, "S1:car"), track(log, "S1:door"), cav_track(log, 0)
    s_car, d_car = frenet(m, lane, car[0, :2])
    assert (
        s_car[0] == pytest.approx(60.0, abs=0.6) and abs(d_car[0]) > 0.5 * m.lane_width[i]
    )  # beside the lane
    opened = int(np.flatnonzero(~np.isnan(door[:, 0]))[0])
    f = m.index.frenet_to_xy(np.array([i]), np.array([60.0]))[0]
    gap = np.linalg.norm(cav[opened - 2 : opened, :2] - f, axis=1)
    assert gap[0] / cav[opened - 2, 3] >= 3.0 - 0.05 or gap[0] >= 10.0
    assert gap[1] / cav[opened - 1, 3] < 3.1 or gap[1] < 10.0
    # the door's outer end reaches into CAV 0's lane
    tip = door[opened, :2] + 0.5 * 1.0 * np.array([np.cos(door[opened, 2]), np.sin(door[opened, 2])])
    _, d_tip = frenet(m, lane, tip)
    assert abs(d_tip[0]) < 0.5 * m.lane_width[i]
    flow = sorted({a for a in log.arrays["actor_id"].tolist() if a.startswith("S1:opp")})
    assert flow
    start = int(np.flatnonzero(~np.isnan(track(log, flow[0])[:, 0]))[0])
    assert (start - opened) * 0.05 == pytest.approx(5.0, abs=0.15)


@pytest.mark.parametrize(("town", "lane"), [("downtown", "J0_0-J0_1_2"), ("Town01", "-6_2")])
def test_invading_cars_cross_the_centre_line(town: str, lane: str, tmp_path: Path) -> None:
    """InvadingTurn (distance 60 m, offset 0.25 m): cones on the oncoming lane 0.4 w toward its outer edge;
    oncoming cars every 40 m at the speed limit, offset + w/2 - 0.7 m toward the ego lane, so their
    boxes cross the centre line by offset + half-width - 0.7 m."""
    m = load_map(town)
    i = m.lane(lane)
    opposite = int(m.lane_opposite[i])
    w = float(m.lane_width[opposite])
    sc = ScenarioSpec("S1", "InvadingTurn", trigger(m, lane, 10.0), {"distance": "60", "offset": "0.25"})
    spec = RouteSpec(f"invading_{town}", town, "ClearNoon", 0, (lane_cav(m, 0, lane, 5.0, 135.0),), (sc,))
    result, log = run(spec, tmp_path)
    assert result.scenario_simulated is True
    ids = {a for a in log.arrays["actor_id"].tolist() if a.startswith("S1:")}
    cones = sorted(a for a in ids if a.startswith("S1:cone"))
    assert len(cones) == 6  # every 5 m while covering < 30 m
    for c in cones:
        first = track(log, c)[~np.isnan(track(log, c)[:, 0])][0]
        _, d = m.index.project(first[None, :2], np.array([opposite]))
        assert d[0] == pytest.approx(-0.4 * w, abs=0.1)
    cars = sorted((a for a in ids if a.startswith("S1:inv")), key=lambda a: int(a[6:]))
    assert len(cars) >= 2
    for c in cars:
        tr = track(log, c)
        rows = np.flatnonzero(~np.isnan(tr[:, 0]))
        _, d = m.index.project(tr[rows, :2], np.full(len(rows), opposite))
        assert np.median(d) == pytest.approx(0.25 + 0.5 * w - 0.7, abs=0.05)
        assert np.median(d) + 0.5 * 1.85 > 0.5 * w  # the box crosses the centre line
        assert tr[rows[1:-1], 3] == pytest.approx(m.lane_speed[i])


class Cav1Stops(StopsSome):
    STOP_AT: ClassVar[dict[int, float]] = {1: 0.0}  # [s]: CAV 1 never moves


def test_invading_turn_ends_with_cav_0_whatever_the_others_do(tmp_path: Path) -> None:
    """InvadingTurn (downtown, distance 40 m): CAV 1 stands behind CAV 0 on the same lane, its route
    through the trigger too, and never reaches the end (past S within 50 m). The scenario's ego is CAV 0:
    the moment CAV 0 is past S, the cones and invading cars are gone and no scenario timeout is charged."""
    m = load_map("downtown")
    lane = "J0_0-J0_1_2"
    sc = ScenarioSpec("S1", "InvadingTurn", trigger(m, lane, 25.0), {"distance": "40", "offset": "0.3"})
    cavs = (lane_cav(m, 0, lane, 20.0, 135.0), lane_cav(m, 1, lane, 5.0, 135.0))
    spec = RouteSpec("invading_cav1_stands", "downtown", "ClearNoon", 0, cavs, (sc,))
    result, log = run(spec, tmp_path, Cav1Stops, EvalConfig(background=BackgroundConfig(0, 0), tick_cap=800))
    ids = sorted({a for a in log.arrays["actor_id"].tolist() if a.startswith("S1:")})
    assert any(a.startswith("S1:inv") for a in ids) and any(a.startswith("S1:cone") for a in ids)
    last = max(int(np.flatnonzero(~np.isnan(track(log, a)[:, 0]))[-1]) for a in ids)
    # S is abreast next(distance + 30) = s 95 m of CAV 0's lane: the actors go as CAV 0 gets past it
    s_last, _ = frenet(m, lane, cav_track(log, 0)[last, :2])
    assert 94.0 < s_last[0] < 100.0, s_last
    assert last * 0.05 < 20.0 and log.num_ticks > last + 200  # long before the route's end (40 s)
    assert cav_track(log, 1)[-1, 3] < 0.1  # CAV 1 stood all along
    assert all(len(c.infractions["scenario_timeouts"]) == 0 for c in result.cavs)


def test_the_door_opening_halts_the_traffic_behind_until_the_end(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """VehicleOpensDoorTwoWays (downtown): upstream's StopBack freezes the background traffic behind the
    ego when the door opens and StartBack releases it at the end: CAV 0's lane is halted from the tick the
    door appears to the scenario's end, behind CAV 0 only (what is ahead of it drives on)."""
    from cmudrive.sim.background import BackgroundActivity

    calls: list[tuple[str, list[int], float]] = []
    before: list[float] = []
    for name in ("stop_lane", "release_lane"):
        original = getattr(BackgroundActivity, name)

        def spy(self: BackgroundActivity, lanes, *rest, _name=name, _original=original):  # type: ignore[no-untyped-def]
            calls.append((_name, [int(x) for x in lanes], self._need_world().time))
            before.extend(rest)
            return _original(self, lanes, *rest)

        monkeypatch.setattr(BackgroundActivity, name, spy)
    m = load_map("downtown")
    lane = "J0_0-J0_1_2"
    sc = ScenarioSpec("S1", "VehicleOpensDoorTwoWays", trigger(m, lane, 20.0), {"distance": "40"})
    spec = RouteSpec("door_back", "downtown", "ClearNoon", 0, (lane_cav(m, 0, lane, 5.0, 135.0),), (sc,))
    _, log = run(spec, tmp_path)
    door = track(log, "S1:door")
    present = np.flatnonzero(~np.isnan(door[:, 0]))
    assert [(c[0], c[1]) for c in calls] == [("stop_lane", [m.lane(lane)]), ("release_lane", [m.lane(lane)])]
    assert calls[0][2] == pytest.approx((present[0] + 1) * 0.05, abs=0.06)  # as the door opens
    assert calls[1][2] == pytest.approx((present[-1] + 1) * 0.05, abs=0.11)  # released at the end
    assert len(before) == 1 and 20.0 < before[0] < 60.0 - 2.45  # CAV 0 past T (20 m), before the car (60 m)
