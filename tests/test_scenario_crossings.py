"""The crossing family (DynamicObjectCrossing, ParkingCrossingPedestrian, PedestrianCrossing,
VehicleTurningRoutePedestrian, VehicleTurningRoute) on downtown and on CARLA's Town03 and Town01: CAV 0
drives with the PID agent; the crosser waits beside the road (behind its occluder) until CAV 0's time to
arrival at the crossing point drops below the reference's t, then crosses CAV 0's lane at its speed
[m/s], and leaves the world with its occluder."""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from cmudrive.bench import EvalConfig, RouteSpec
from cmudrive.maps import RoadMap, load_map
from tests.scenario_helpers import (
    EMPTY,
    StopsSome,
    cav_track,
    lane_cav,
    path_cav,
    run,
    scenario,
    track,
    trigger,
)

A, STRAIGHT, RIGHT = "J0_0-J0_1_2", "J0_1-J0_2_2", "J0_1-J1_1_1"  # downtown: approach, straight / right exit
W1, W3 = ["walker"], ["walker0", "walker1", "walker2"]
ADVERT = {"distance": "40", "blocker_model": "static.prop.advertisement", "crossing_angle": "10"}
D40 = {"distance": "40"}
# town, type, approach lane, exit lane, trigger s [m] on the approach lane, parameters,
# crossers, TTA seconds, crosser speed [m/s] (None: drawn per walker)
SCENES = [
    ("downtown", "DynamicObjectCrossing", A, STRAIGHT, 30.0, D40, W1, 2.1, 2.0),
    ("Town03", "DynamicObjectCrossing", "-2_3", "-3_3", 30.0, ADVERT, W1, 2.2, 2.0),
    ("downtown", "ParkingCrossingPedestrian", A, STRAIGHT, 30.0, D40, W1, 2.15, 2.0),
    ("Town03", "ParkingCrossingPedestrian", "-2_3", "-3_3", 30.0, D40, W1, 2.15, 2.0),
    ("downtown", "PedestrianCrossing", A, STRAIGHT, 80.0, {}, W3, 3.5, None),
    ("Town03", "PedestrianCrossing", "-2_3", "-3_3", 80.0, {}, W3, 3.5, None),
    ("downtown", "VehicleTurningRoutePedestrian", A, RIGHT, 80.0, {}, W1, 2.2, 1.8),
    ("Town01", "VehicleTurningRoutePedestrian", "-24_2", "-6_2", 80.0, {}, W1, 2.2, 1.8),
    ("downtown", "VehicleTurningRoute", A, RIGHT, 80.0, {}, ["bicycle"], 1.8, 1.8),
    ("Town03", "VehicleTurningRoute", "-2_3", "-21_4", 80.0, {}, ["bicycle"], 1.8, 1.8),
]


def route_through(m: RoadMap, kind: str, a: str, b: str, t_s: float, **params: str) -> RouteSpec:
    """CAV 0 from s = 10 m on lane ``a`` through the junction at its end to s = 100 m on lane ``b``
    (or 5 m short of its end)."""
    ia, ib = m.lane(a), m.lane(b)
    xy = np.array(
        [
            m.index.frenet_to_xy(np.array([ia]), np.array([10.0]))[0],
            m.index.frenet_to_xy(np.array([ia]), np.array([m.lane_length[ia] - 3.0]))[0],
            m.index.frenet_to_xy(np.array([ib]), np.array([min(100.0, m.lane_length[ib] - 5.0)]))[0],
        ]
    )
    sc = scenario(kind, trigger(m, a, t_s), **params)
    return RouteSpec(f"{kind}_{m.name}", m.name, "ClearNoon", 0, (path_cav(m, 0, xy),), (sc,))


@pytest.mark.parametrize(
    ("town", "kind", "a", "b", "t_s", "params", "crossers", "tta", "speed"),
    SCENES,
    ids=[f"{s[1]}-{s[0]}" for s in SCENES],
)
def test_crossers_cross_the_cav_lane_when_it_arrives(
    town: str,
    kind: str,
    a: str,
    b: str,
    t_s: float,
    params: dict[str, str],
    crossers: list[str],
    tta: float,
    speed: float | None,
    tmp_path: Path,
) -> None:
    m = load_map(town)
    spec = route_through(m, kind, a, b, t_s, **params)
    route = spec.dense_routes(m)[0]
    result, log = run(spec, tmp_path)
    assert result.scenario_simulated is True
    cav0 = cav_track(log, 0)
    moved_at = []
    for name in crossers:
        tr = track(log, f"S1:{name}")
        present = np.flatnonzero(~np.isnan(tr[:, 0]))
        assert len(present) > 0, name
        moving = present[tr[present, 3] > 0.0]
        moved_at.append(int(moving[0]))
        if speed is not None:
            assert tr[moving, 3] == pytest.approx(speed)
        else:  # PedestrianCrossing draws each walker's speed from U[1.3, 2.0] m/s
            assert 1.3 <= tr[moving[0], 3] <= 2.0
        # it crosses CAV 0's lane where its path meets CAV 0's route: from beyond one edge to the other
        mid = tr[moving[len(moving) // 2], :2]
        k = int(np.argmin(np.linalg.norm(route.xy - mid, axis=1)))
        lane, w = int(route.lane[k]), float(m.lane_width[route.lane[k]])
        _, d = m.index.project(tr[present, :2], np.full(len(present), lane))
        assert d.min() < -0.5 * w and d.max() > 0.5 * w, (name, d.min(), d.max())
        # it leaves the world when its crossing ends (or it is still crossing when CAV 0's route ends)
        assert present[-1] < log.num_ticks - 1 or tr[-1, 3] > 0.0
    # the trigger: CAV 0's time to arrival at the crossing point just dropped below t (or it is < 6 m)
    first = min(moved_at)
    if kind != "PedestrianCrossing":  # (its walkers idle U[0, 1.5] s after the trigger)
        x = _crossing_point(log, crossers[0], first, m, route)
        gap = np.linalg.norm(cav0[first - 2 : first, :2] - x, axis=1)
        v = np.maximum(cav0[first - 2 : first, 3], 1e-6)
        assert gap[0] / v[0] >= tta - 0.05 or gap[0] >= 6.0
        assert gap[1] / v[1] < tta + 0.1 or gap[1] < 6.0


def _crossing_point(log, name: str, tick: int, m: RoadMap, route) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Where the crosser's line meets CAV 0's route (the nearest route point to its path)."""
    tr = track(log, f"S1:{name}")
    present = np.flatnonzero(~np.isnan(tr[:, 0]))
    pts = tr[present, :2]
    dist = np.linalg.norm(route.xy[:, None, :] - pts[None], axis=2)
    k = int(np.unravel_index(np.argmin(dist), dist.shape)[0])
    return route.xy[k]


def test_occluder_hides_the_walker_until_activation(tmp_path: Path) -> None:
    """DynamicObjectCrossing: the occluder stands on the sidewalk from the start, off the driving lanes;
    the walker appears only at activation, beside it (blocker half-length + 0.5 m further on)."""
    m = load_map("downtown")
    spec = route_through(m, "DynamicObjectCrossing", "J0_0-J0_1_2", "J0_1-J0_2_2", 30.0, distance="40")
    _, log = run(spec, tmp_path)
    blocker, walker = track(log, "S1:blocker"), track(log, "S1:walker")
    assert not np.isnan(blocker[0, 0]) and not m.index.on_driving_lane(blocker[:1, :2])[0]
    appear = int(np.flatnonzero(~np.isnan(walker[:, 0]))[0])
    s_cav, _ = m.index.project(cav_track(log, 0)[appear, :2][None], np.array([m.lane("J0_0-J0_1_2")]))
    assert 27.5 < s_cav[0] < 30.5  # activation: CAV 0 2 m short of T
    lane = np.array([m.lane("J0_0-J0_1_2")])
    s_b, _ = m.index.project(blocker[:1, :2], lane)
    s_w, _ = m.index.project(walker[appear : appear + 1, :2], lane)
    assert s_b[0] == pytest.approx(70.0, abs=0.1) and s_w[0] - s_b[0] == pytest.approx(1.0, abs=0.1)


class Cav0StopsAfterActivation(StopsSome):
    # [s]: CAV 0 has passed the trigger (s = 28 m) and stands ~30 m short of X
    STOP_AT: ClassVar[dict[int, float]] = {0: 4.0}


def test_only_cav_0_releases_the_crosser(tmp_path: Path) -> None:
    """DynamicObjectCrossing (downtown, distance 40 m): CAV 0 activates the scenario and stands ~30 m short
    of the crossing point X; CAV 1 drives the oncoming lane right past X (3.3 m from it, inside the 6 m
    distance trigger). The walker, the scenario's adversary for CAV 0 alone, does not start."""
    m = load_map("downtown")
    a = "J0_0-J0_1_2"
    oncoming = str(m.lane_ids[m.lane_opposite[m.lane(a)]])
    cav0 = route_through(m, "DynamicObjectCrossing", a, "J0_1-J0_2_2", 30.0, distance="40").cavs[0]
    sc = scenario("DynamicObjectCrossing", trigger(m, a, 30.0), distance="40")
    cav1 = lane_cav(m, 1, oncoming, 20.0, 130.0)  # X is at s = 70 m of lane a, ~68 m of the oncoming one
    spec = RouteSpec("cav1_passes_x", "downtown", "ClearNoon", 0, (cav0, cav1), (sc,))
    result, log = run(spec, tmp_path, Cav0StopsAfterActivation, EvalConfig(background=EMPTY, tick_cap=500))
    walker, blocker = track(log, "S1:walker"), track(log, "S1:blocker")
    present = np.flatnonzero(~np.isnan(walker[:, 0]))
    assert len(present) > 0  # the scenario activated on CAV 0
    assert np.all(walker[present, 3] == 0.0)  # and the walker never moved
    x_s = 70.0
    s0, _ = m.index.project(cav_track(log, 0)[-1:, :2], np.array([m.lane(a)]))
    assert 28.0 < s0[0] < x_s - 6.0 and cav_track(log, 0)[-1, 3] < 0.1  # CAV 0 stands short of X
    # CAV 1 came within 6 m of X (the old any-CAV trigger fired on it) and drove on past it
    x_xy = m.index.frenet_to_xy(np.array([m.lane(a)]), np.array([x_s]))[0]
    gap1 = np.linalg.norm(cav_track(log, 1)[:, :2] - x_xy, axis=1)
    assert np.nanmin(gap1) < 6.0 and result.cavs[1].route_completion > 90.0
    assert not np.isnan(blocker[-1, 0])  # the occluder is still there: the crossing never happened
