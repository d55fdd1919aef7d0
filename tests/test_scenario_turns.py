"""Turning at a junction across or into a flow (the six Junction*Turn* types) on downtown, suburb and
CARLA's Town03, Town04 and Town06: the flow comes from the approach the type names (opposite for the left
turns, the CAV's left for the right turns) at flow_speed; the signalized types hold CAV 0's approach red
for 5 s while the flow's is green, then give both green; the scenario ends 10 m past the junction."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cmudrive.bench import RouteSpec
from cmudrive.bench.scenarios.base import Scenario
from cmudrive.maps import RoadMap, load_map
from cmudrive.sim.traffic_lights import YELLOW_TIME
from tests.scenario_helpers import path_cav, run, scenario, track, trigger

SCENES = [
    ("SignalizedJunctionLeftTurn", "downtown", "J0_2-J0_1_2", "J0_1-J1_1_2"),
    ("SignalizedJunctionLeftTurn", "Town03", "-2_4", "20_4"),
    ("SignalizedJunctionLeftTurnEnterFlow", "downtown", "J0_2-J0_1_2", "J0_1-J1_1_2"),
    ("SignalizedJunctionLeftTurnEnterFlow", "Town03", "-33_4", "-90_5"),
    ("SignalizedJunctionRightTurn", "downtown", "J0_2-J1_2_2", "J1_2-J1_1_1"),
    ("SignalizedJunctionRightTurn", "Town03", "90_5", "33_4"),
    ("NonSignalizedJunctionLeftTurn", "suburb", "J0_4-J0_2_2", "J0_2-J1_2_2"),
    ("NonSignalizedJunctionLeftTurn", "Town06", "40_3", "-45_3"),
    ("NonSignalizedJunctionLeftTurnEnterFlow", "suburb", "J0_0-J1_0_2", "J1_0-J1_1_1"),
    ("NonSignalizedJunctionLeftTurnEnterFlow", "Town06", "40_3", "-45_3"),
    ("NonSignalizedJunctionRightTurn", "suburb", "J1_2-J0_2_2", "J0_2-J0_4_2"),
    ("NonSignalizedJunctionRightTurn", "Town04", "-23_1", "-41_1"),
]
SPEED = 10.0  # [m/s]


def end_heading(m: RoadMap, lane: int) -> float:
    p = m.polyline(lane)
    return math.atan2(p[-1, 1] - p[-2, 1], p[-1, 0] - p[-2, 0])


@pytest.mark.parametrize(("kind", "town", "a", "b"), SCENES, ids=[f"{s[0]}-{s[1]}" for s in SCENES])
def test_turn_flow_comes_from_the_named_approach(
    kind: str, town: str, a: str, b: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seen: list[tuple[float, float]] = []
    original = Scenario.finish

    def finish(self: Scenario) -> None:
        if self.phase.name == "ACTIVE":
            seen.append((self.activated_at, self.time))
        original(self)

    monkeypatch.setattr(Scenario, "finish", finish)
    m = load_map(town)
    ia, ib = m.lane(a), m.lane(b)
    xy = np.array(
        [
            m.index.frenet_to_xy(np.array([ia]), np.array([max(2.0, m.lane_length[ia] - 60.0)]))[0],
            m.index.frenet_to_xy(np.array([ia]), np.array([m.lane_length[ia] - 2.0]))[0],
            m.index.frenet_to_xy(np.array([ib]), np.array([min(60.0, m.lane_length[ib] - 5.0)]))[0],
        ]
    )
    t_s = max(5.0, m.lane_length[ia] - 45.0)
    gap = {"from": "15", "to": "25"}
    sc = scenario(kind, trigger(m, a, t_s), flow_speed=str(SPEED), source_dist_interval=gap)
    spec = RouteSpec(f"{kind}_{town}", town, "ClearNoon", 0, (path_cav(m, 0, xy),), (sc,))
    result, log = run(spec, tmp_path)
    assert result.scenario_simulated is True
    cars = sorted(
        {x for x in log.arrays["actor_id"].tolist() if x.startswith("S1:flow0:")}, key=lambda x: int(x[9:])
    )
    assert cars
    tr = track(log, cars[-1])  # spawned at the source (pre-filled cars come first)
    rows = np.flatnonzero(~np.isnan(tr[:, 0]))
    first = rows[0]
    proj = m.index.nearest_lane(tr[first, :2][None], heading=tr[first, 2])
    rel = (end_heading(m, int(proj.lane[0])) - end_heading(m, ia) + math.pi) % (2 * math.pi) - math.pi
    want = math.pi if "LeftTurn" in kind else -math.pi / 2
    assert abs((rel - want + math.pi) % (2 * math.pi) - math.pi) < math.radians(35.0), (rel, want)
    # each car drives at the imposed speed; SUMO may only lower it (no driving through a CAV in its way).
    # A car that departs before the signal departs no faster than it could stop at the line: those seen
    # for 5 s or more have reached the flow speed
    top = np.array([np.nanmax(track(log, c)[:, 3]) for c in cars])
    seen_s = np.array([np.count_nonzero(~np.isnan(track(log, c)[:, 3])) * 0.05 for c in cars])
    assert np.all(top <= SPEED + 0.05)
    assert np.count_nonzero(seen_s >= 5.0) >= 2 and top[seen_s >= 5.0] == pytest.approx(SPEED, abs=0.05)
    act, end = seen[0]
    if kind.startswith("Signalized"):
        link = int(np.flatnonzero((m.link_from == ia) & (m.link_tls >= 0))[0])
        light, k = int(m.link_tls[link]), int(m.link_tls_index[link])
        ego = [str(log.tls_state(i)[light])[k] for i in range(log.num_ticks)]
        tick = round(act / 0.05) - 1
        red = min(tick + 100, round(end / 0.05) - 1)
        yellow = tick + round(YELLOW_TIME / 0.05)  # (yellow first where the light was green)
        assert set(ego[yellow + 1 : red]) == {"r"} and set(ego[tick + 1 : red]) <= {"r", "y"}  # 5 s red ...
        assert set(ego[tick + 101 : round(end / 0.05) - 1]) <= {"G"}  # ... then green
    # the end: CAV 0 10 m past the junction
    route = spec.dense_routes(m)[0]
    inside = np.flatnonzero(route.in_junction)
    exit_k = int(inside[0]) + int(np.flatnonzero(~route.in_junction[inside[0] :])[0])
    cav = track(log, "cav0")[round(end / 0.05) - 1, :2]
    k = int(np.argmin(np.linalg.norm(route.xy - cav, axis=1)))
    assert route.distance[k] - route.distance[exit_k] == pytest.approx(10.0, abs=1.5)
