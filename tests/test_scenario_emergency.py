"""YieldToEmergencyVehicle on interurban and Town04: the ambulance (a SUMO vehicle with a blue light)
appears at activation ``distance`` m behind the trigger in CAV 0's lane and closes in at CAV 0's speed +
25 m/s; a CAV that keeps its lane blocks it (it follows, never rams) and is charged the x0.7
yield_emergency_vehicle infraction at the end; a CAV that moves over is passed and is not; a CAV whose
route does not pass the trigger is not judged."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmudrive.bench import RouteSpec
from cmudrive.maps import load_map
from cmudrive.sim.actor_types import ACTOR_TYPES
from tests.scenario_helpers import cav_track, frenet, lane_cav, path_cav, run, scenario, track, trigger

LANES = {"interurban": ("R1a-R2a_0", "R1a-R2a_1"), "Town04": ("-45_2", "-45_3")}
KEY = "yield_emergency_vehicle_infractions"


@pytest.mark.parametrize("town", ["interurban", "Town04"])
def test_a_cav_that_keeps_its_lane_fails_to_yield(town: str, tmp_path: Path) -> None:
    m = load_map(town)
    lane, other = LANES[town]
    cavs = (lane_cav(m, 0, lane, 20.0, 300.0), lane_cav(m, 1, other, 60.0, 300.0))
    sc = scenario("YieldToEmergencyVehicle", trigger(m, lane, 40.0), distance="30")
    result, log = run(RouteSpec(f"ev_{town}", town, "ClearNoon", 0, cavs, (sc,)), tmp_path)
    assert result.scenario_simulated is True
    ev, cav = track(log, "S1:ev"), cav_track(log, 0)
    present = np.flatnonzero(~np.isnan(ev[:, 0]))
    s_ev, d_ev = frenet(m, lane, ev[present[0], :2])
    s_cav, _ = frenet(m, lane, cav[present[0], :2])
    assert s_ev[0] == pytest.approx(10.0, abs=1.5) and abs(d_ev[0]) < 0.2  # 30 m behind T, in the ego lane
    assert 37.0 < s_cav[0] < 41.5  # placed at activation (inserted by the next SUMO step)
    # it closes in and then follows CAV 0 in its lane without touching it
    s_e, _ = frenet(m, lane, ev[present, :2])
    s_c, _ = frenet(m, lane, cav[present, :2])
    gap = s_c - s_e - 0.5 * (4.89 + 6.2)  # bumper to bumper [m]
    assert gap.min() > 1.0 and gap[-20:].max() < 20.0
    assert not [i for i in result.cavs[0].infractions["collisions_vehicle"] if i.actor == "S1:ev"]
    fails = result.cavs[0].infractions[KEY]
    assert len(fails) == 1 and fails[0].factor == 0.7 and fails[0].actor == "S1:ev"
    assert result.cavs[1].infractions[KEY] == []  # CAV 1's route does not pass the trigger


def test_a_cav_that_moves_over_is_passed_and_not_charged(tmp_path: Path) -> None:
    m = load_map("interurban")
    stops = (("R1a-R2a_0", 20.0), ("R1a-R2a_0", 45.0), ("R1a-R2a_1", 75.0), ("R1a-R2a_1", 300.0))
    xy = np.array([m.index.frenet_to_xy(np.array([m.lane(ln)]), np.array([s]))[0] for ln, s in stops])
    sc = scenario("YieldToEmergencyVehicle", trigger(m, "R1a-R2a_0", 40.0), distance="30")
    result, log = run(
        RouteSpec("ev_yield", "interurban", "ClearNoon", 0, (path_cav(m, 0, xy),), (sc,)), tmp_path
    )
    assert result.cavs[0].infractions[KEY] == []
    ev, cav = track(log, "S1:ev"), cav_track(log, 0)
    last = int(np.flatnonzero(~np.isnan(ev[:, 0]))[-1])
    s_ev, _ = frenet(m, "R1a-R2a_0", ev[last, :2])
    s_cav, _ = frenet(m, "R1a-R2a_0", cav[last, :2])
    assert s_ev[0] > s_cav[0] + 10.0  # it went past
    assert np.nanmax(ev[:, 3]) > cav[last, 3] + 8.0  # faster than CAV 0 by far
    # upstream's WaitUntilInFront: "ahead" once its centre is past the point one CAV and one ambulance
    # half-length in front of CAV 0 (within 10 m of it); the scenario ends (it is removed) 50 m later
    half = 0.5 * (ACTOR_TYPES["cav"].length + ACTOR_TYPES["ambulance"].length)
    fwd = np.column_stack([np.cos(cav[:, 2]), np.sin(cav[:, 2])])
    ref = cav[:, :2] + half * fwd
    ahead = (np.einsum("ij,ij->i", ev[:, :2] - ref, fwd) > 0) & (np.linalg.norm(ev[:, :2] - ref, axis=1) < 10)
    k = int(np.flatnonzero(ahead)[0])
    driven = np.sum(np.linalg.norm(np.diff(ev[k : last + 1, :2], axis=0), axis=1))
    assert driven == pytest.approx(50.0, abs=3.0)
