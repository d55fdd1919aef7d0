"""ParkingExit on downtown and CARLA's Town03: CAV 0 starts in the parking lane beside T between two
parked cars (front_vehicle_distance ahead, behind_vehicle_distance behind), a car waits beside it in the
driving lane and drives off at activation; the scenario ends once CAV 0 drove front + 15 m."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmudrive.bench import RouteSpec
from cmudrive.maps import load_map
from tests.scenario_helpers import cav_track, frenet, lane_cav, run, scenario, track, trigger


@pytest.mark.parametrize(
    ("town", "lane", "side"), [("downtown", "J0_0-J0_1_2", "J0_0-J0_1_1"), ("Town03", "-21_4", "-21_3")]
)
def test_cav_starts_in_the_slot_and_pulls_out(town: str, lane: str, side: str, tmp_path: Path) -> None:
    m = load_map(town)
    i, j = m.lane(lane), m.lane(side)
    spec = RouteSpec(
        f"parking_exit_{town}", town, "ClearNoon", 0, (lane_cav(m, 0, lane, 20.0, 135.0),),
        (scenario("ParkingExit", trigger(m, lane, 20.0)),),
    )  # fmt: skip
    result, log = run(spec, tmp_path)
    assert result.scenario_simulated is True
    slot = -(0.5 * m.lane_width[i] + 0.5 * m.lane_width[j] + (m.lane_width[j] - 0.5 * 2.10) / 4.0)
    cav = cav_track(log, 0)
    s0, d0 = frenet(m, lane, cav[0, :2])
    assert s0[0] == pytest.approx(20.0, abs=0.5) and d0[0] == pytest.approx(slot, abs=0.1)  # in the slot
    for name, ahead in (("S1:front", 20.0), ("S1:behind", -10.0)):
        s, d = frenet(m, lane, track(log, name)[0, :2])
        # (measured along the parking lane: on a bend its arc differs from the driving lane's)
        assert s[0] == pytest.approx(20.0 + ahead, abs=2.0) and d[0] == pytest.approx(slot, abs=0.1)
    beside = track(log, "S1:beside")
    rows = np.flatnonzero(~np.isnan(beside[:, 0]))
    s, d = frenet(m, lane, beside[rows[0], :2])
    assert abs(d[0]) < 0.2 and abs(s[0] - 20.0) < 3.0  # in the driving lane beside CAV 0
    assert np.nanmax(beside[:, 3]) > 1.0  # it drives off
    last = int(np.flatnonzero(~np.isnan(track(log, "S1:front")[:, 0]))[-1])
    route = spec.dense_routes(m)[0]
    k = int(np.argmin(np.linalg.norm(route.xy - cav[last + 1, :2], axis=1)))
    assert route.distance[k] == pytest.approx(35.0, abs=1.5)  # ended when CAV 0 drove 20 + 15 m
    _, d_end = frenet(m, lane, cav[last + 1, :2])
    assert d_end[0] > slot + 1.5  # out of the slot
