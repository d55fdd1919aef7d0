"""The cut-in family (StaticCutIn, ParkingCutIn) on our towns and on CARLA's Town04 and Town03: CAV 0
drives with the PID agent; the cut-in car waits beside the ego lane until CAV 0's time to arrival abreast
it drops below the reference's t, then moves into CAV 0's lane ahead of CAV 0 and drives on it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmudrive.bench import RouteSpec
from cmudrive.maps import load_map
from tests.scenario_helpers import cav_track, frenet, lane_cav, run, scenario, track, trigger

T_S = 40.0  # [m] the trigger's arc length on CAV 0's lane


def test_static_cut_in_leaves_the_queue_into_the_cav_lane_ahead(tmp_path: Path) -> None:
    """Queue of six cars in the right lane (placed at activation, d+0..55 m); the car at d+22 m cuts in
    when CAV 0 is 2.7 s away, ends its lateral move on CAV 0's lane ahead of it, then drives 70 m at
    60 km/h; all six are removed at the end."""
    for town, lane in (("interurban", "R1a-R2a_1"), ("Town04", "-45_2")):
        m = load_map(town)
        spec = RouteSpec(
            f"static_{town}",
            town,
            "ClearNoon",
            0,
            (lane_cav(m, 0, lane, 20.0, 300.0),),
            (scenario("StaticCutIn", trigger(m, lane, T_S), distance="40"),),
        )
        result, log = run(spec, tmp_path / town)
        assert result.scenario_simulated is True
        w = 0.5 * (m.lane_width[m.lane(lane)] + m.lane_width[m.lane_right[m.lane(lane)]])
        cav = cav_track(log, 0)
        s_cav, _ = frenet(m, lane, cav[:, :2])
        for k, gap in enumerate((0.0, 11.0, 22.0, 33.0, 44.0, 55.0)):
            tr = track(log, f"S1:car{k}")
            present = np.flatnonzero(~np.isnan(tr[:, 0]))
            assert T_S - 2.5 < s_cav[present[0]] < T_S + 1.0  # placed at activation
            s, d = frenet(m, lane, tr[present[0], :2])
            assert s[0] == pytest.approx(T_S + 40.0 + gap, abs=0.5) and d[0] == pytest.approx(-w, abs=0.1)
            assert present[-1] < log.num_ticks - 1  # removed at the end
        _check_cut_in(m, lane, log, "S1:car2", T_S + 62.0, tta=2.7, distance=15.0, cruise=60.0 / 3.6)


def test_parking_cut_in_pulls_out_into_the_cav_lane_ahead(tmp_path: Path) -> None:
    """Blocker and cut-in car in the parking lane (28 and 35 m past T, pushed (w_side - half-width)/4
    outward) from the start; the cut-in car pulls out at 20 km/h when CAV 0 is 2.35 s away."""
    for town, lane in (("downtown", "J0_0-J0_1_2"), ("Town03", "-21_4")):
        m = load_map(town)
        spec = RouteSpec(
            f"parking_{town}",
            town,
            "ClearNoon",
            0,
            (lane_cav(m, 0, lane, 10.0, 130.0),),
            (scenario("ParkingCutIn", trigger(m, lane, T_S), direction="right"),),
        )
        result, log = run(spec, tmp_path / town)
        assert result.scenario_simulated is True
        i = m.lane(lane)
        side = [
            x for x in np.flatnonzero(m.lane_edge == m.lane_edge[i]) if m.lane_index[x] == m.lane_index[i] - 1
        ]
        w, w_side = m.lane_width[i], m.lane_width[side[0]]
        offset = 0.5 * w + 0.5 * w_side + (w_side - 0.5 * 1.85) / 4.0
        for name, ahead in (("S1:blocker", 28.0), ("S1:cutter", 35.0)):
            tr = track(log, name)
            assert not np.isnan(tr[0, 0])  # present from the start
            s, d = frenet(m, lane, tr[0, :2])
            assert s[0] == pytest.approx(T_S + ahead, abs=0.5) and d[0] == pytest.approx(-offset, abs=0.1)
        _check_cut_in(m, lane, log, "S1:cutter", T_S + 35.0, tta=2.35, distance=10.0, cruise=20.0 / 3.6)


def _check_cut_in(m, lane, log, name, s_point, tta, distance, cruise) -> None:  # type: ignore[no-untyped-def]
    """The car starts when CAV 0's time to arrival at the ego-lane point abreast it drops below ``tta``
    (or its distance below ``distance``), reaches CAV 0's lane centre ahead of CAV 0, cruises there."""
    tr, cav = track(log, name), cav_track(log, 0)
    present = np.flatnonzero(~np.isnan(tr[:, 0]))
    start = int(present[tr[present, 3] > 0.0][0])
    point = m.index.frenet_to_xy(np.array([m.lane(lane)]), np.array([s_point]))[0]
    gap = np.linalg.norm(cav[start - 2 : start, :2] - point, axis=1)
    v = np.maximum(cav[start - 2 : start, 3], 1e-6)
    assert gap[0] / v[0] >= tta - 0.05 or gap[0] >= distance  # the tick before it fired: not yet
    assert gap[1] / v[1] < tta + 0.1 or gap[1] < distance
    s, d = frenet(m, lane, tr[present, :2])
    s_cav, _ = frenet(m, lane, cav[present, :2])
    merged = int(np.flatnonzero(np.abs(d) < 0.05)[0])  # first tick on CAV 0's lane centre
    assert s[merged] - s_cav[merged] > 4.89  # ahead of CAV 0 (more than a car length between centres)
    assert tr[present[merged:-1], 3] == pytest.approx(cruise)
    assert present[-1] < log.num_ticks - 1  # removed when its drive ends


@pytest.mark.parametrize(
    ("town", "approach", "exit_lane", "ramp", "s_start", "s_car", "t_s", "s_end"),
    [
        (
            "highway",
            "EB_gore1-EB_merge1_0",
            "EB_merge1-EB_gore2_1",
            "S_entry1-EB_merge1_0",
            450.0,
            341.0,
            620.0,
            250.0,
        ),
        ("Town06", "-42_3", "-43_3", "75_2", 20, 22, 81, 150),
    ],
)
def test_highway_cut_in_times_its_merge_and_cuts_into_the_cav_lane(
    town: str,
    approach: str,
    exit_lane: str,
    ramp: str,
    s_start: float,
    s_car: float,
    t_s: float,
    s_end: float,
    tmp_path: Path,
) -> None:
    """The ramp car (placed at activation) adapts its speed to be 10 m past its junction exit when CAV 0
    is at its own exit; 5 m short of that it changes into CAV 0's lane at 80 % of CAV 0's speed (0.3 s +
    2 s + 3 s of travel), entering the lane ahead of CAV 0, and is removed at the end of its manoeuvre."""
    from cmudrive.maps.coords import map_to_carla
    from tests.scenario_helpers import path_cav

    m = load_map(town)
    a, b, r = m.lane(approach), m.lane(exit_lane), m.lane(ramp)
    xy = np.array(
        [
            m.index.frenet_to_xy(np.array([a]), np.array([s_start]))[0],
            m.index.frenet_to_xy(np.array([a]), np.array([m.lane_length[a] - 3.0]))[0],
            m.index.frenet_to_xy(np.array([b]), np.array([s_end]))[0],
        ]
    )
    car = map_to_carla(m.index.frenet_to_xy(np.array([r]), np.array([s_car])))[0]
    where = {"x": str(car[0]), "y": str(car[1]), "z": "0"}
    sc = scenario("HighwayCutIn", trigger(m, approach, t_s), other_actor_location=where)
    spec = RouteSpec(f"highway_cut_in_{town}", town, "ClearNoon", 0, (path_cav(m, 0, xy),), (sc,))
    route = spec.dense_routes(m)[0]
    result, log = run(spec, tmp_path)
    assert result.scenario_simulated is True
    tr, cav = track(log, "S1:car"), cav_track(log, 0)
    present = np.flatnonzero(~np.isnan(tr[:, 0]))
    s_cav_a, _ = frenet(m, approach, cav[present[0], :2])
    assert t_s - 2.5 < s_cav_a[0] < t_s + 1.0  # placed at activation
    # the lane change: from the tick its speed stays constant to the end
    v = tr[present, 3]
    switch = present[int(np.flatnonzero(np.abs(v - v[-1]) > 1e-3)[-1]) + 1]
    k = int(np.argmin(np.linalg.norm(route.xy - cav[switch, :2], axis=1)))
    exit_k = int(np.flatnonzero(route.in_junction)[-1]) + 1
    assert route.distance[k] - route.distance[exit_k] == pytest.approx(0.0, abs=6.0)  # CAV 0 at its exit
    s_sw, _ = frenet(m, exit_lane, tr[switch, :2])
    assert 4.0 < s_sw[0] < 10.5  # the car 5-10 m past its own exit
    assert tr[switch, 3] == pytest.approx(0.8 * cav[switch - 1, 3], abs=0.3)
    s, d = frenet(m, exit_lane, tr[present, :2])
    s_c, _ = frenet(m, exit_lane, cav[present, :2])
    w = float(m.lane_width[b])
    enter = int(np.flatnonzero(np.abs(d) < 0.5 * w)[0])
    assert s[enter] > s_c[enter]  # its centre enters CAV 0's lane ahead of CAV 0's centre
    assert np.abs(d[-1]) < 0.05 and present[-1] < log.num_ticks - 1  # on the lane centre, then removed
