"""Levels: actors on a bridge and on the road under it are not in each other's way.

Town04's highway (road 39, 11 m up) crosses the ring road's lane 47_1 without a junction; the imported
network keeps the bridge's z, and the snapshot's elevation keeps the two levels apart."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cmudrive.agents.expert.forecast import Forecaster
from cmudrive.maps import LEVEL_CLEARANCE, LanePos, RoutePlanner, actor_elevation, load_map, other_level
from cmudrive.sim import Controls, World, WorldConfig
from cmudrive.sim.collisions import detect_collisions
from cmudrive.sim.snapshot import Role, Snapshot

UNDER = "47_1"  # ring road lane, ground level, runs south (-y) at x ~ -16
OVER = "-39_1"  # highway lane on the bridge, ~11 m up, runs west (-x) at y ~ -6.3


def test_lane_points_keep_the_bridge_height() -> None:
    town = load_map("Town04")
    assert town.has_elevation and not load_map("Town01").has_elevation
    lanes = np.array([town.lane(UNDER), town.lane(OVER), -1])
    z = actor_elevation(town, lanes, np.array([-16.0, -16.0, -16.0]), np.array([-6.3, -6.3, -6.3]))
    assert z[0] == pytest.approx(0.0, abs=0.1)
    assert 10.0 < z[1] < 11.5
    assert math.isnan(z[2])  # off the network: level unknown


def test_level_rule() -> None:
    assert other_level(0.0, 11.0) and other_level(11.0, 0.0)
    assert not other_level(0.0, LEVEL_CLEARANCE - 0.1)
    assert not other_level(np.nan, 11.0) and not other_level(0.0, np.nan)
    snap = Snapshot.from_rows(
        0, 0.0, np.array([], str), x=[0.0, 1.0, 2.0], y=[0.0, 0.0, 0.0], z=[0.0, 11.0, np.nan]
    )
    assert snap.other_level(np.array([0, 1])).tolist() == [[False, True, False], [True, False, False]]


@pytest.mark.parametrize(("z_other", "collides"), [(0.0, True), (2.0, True), (11.0, False), (np.nan, True)])
def test_boxes_overlapping_in_the_plane_collide_only_on_one_level(z_other: float, collides: bool) -> None:
    snap = Snapshot.from_rows(
        0, 0.0, np.array([], str), x=[0.0, 0.5], y=[0.0, 0.0], yaw=[0.0, math.pi / 2], z=[0.0, z_other]
    )
    assert (detect_collisions(snap).num_events == 1) is collides


@pytest.mark.parametrize(("z_other", "conflict"), [(0.0, True), (11.0, False)])
def test_forecast_ignores_a_car_crossing_on_the_bridge_above(z_other: float, conflict: bool) -> None:
    """The ego drives +x at 8 m/s; a car drives +y at 8 m/s towards the same point, 10 m away each."""
    snap = Snapshot.from_rows(
        0,
        0.0,
        np.array([], str),
        x=[-10.0, 0.0],
        y=[0.0, -10.0],
        yaw=[0.0, math.pi / 2],
        speed=[8.0, 8.0],
        z=[0.0, z_other],
        role=np.array([Role.CAV, Role.BACKGROUND], np.int8),
    )
    path = np.stack([np.arange(60.0) - 10.0, np.zeros(60)], axis=1)[None]
    fc = Forecaster().forecast(snap, np.array([0]), path, np.array([8.0]), np.array([8.0]))
    assert bool(np.isfinite(fc.first_conflict[0, 1])) is conflict


def test_car_on_the_bridge_passes_over_a_standing_cav_without_a_collision() -> None:
    """A CAV stands on 47_1 right under the highway; a SUMO car drives across the bridge at ~10 m/s. Their
    boxes overlap in the ground plane for a few ticks, yet no collision is recorded."""
    town = load_map("Town04")
    under = town.lane(UNDER)
    s_under, _ = town.index.project(np.array([[-16.0, -6.3]]), np.array([under]))
    route = RoutePlanner(town).plan_lanes(
        LanePos(under, float(s_under[0])), LanePos(under, float(s_under[0]) + 30.0)
    )
    with World(WorldConfig(town="Town04", seed=1), road_map=town) as world:
        world.add_cav(route)
        world.sumo.add_vehicle(
            "over", "car", ["-39"], Role.BACKGROUND, depart_pos=40.0, depart_lane=1, depart_speed=10.0
        )
        overlapped, events = 0, 0
        for _ in range(120):
            snap = world.tick(Controls(np.zeros(1), np.zeros(1), np.ones(1)))
            events += len(world.collisions)
            if "over" not in snap.ids.tolist():
                continue
            cav, car = snap.index_of("cav0"), snap.index_of("over")
            assert snap.z[cav] == pytest.approx(0.0, abs=0.3)
            assert snap.z[car] > 9.0
            plane = snap.select(np.array([cav, car]))
            flat = Snapshot.from_rows(
                0,
                0.0,
                np.array([], str),
                x=plane.x,
                y=plane.y,
                yaw=plane.yaw,
                length=plane.length,
                width=plane.width,
            )
            overlapped += detect_collisions(flat).num_events
        assert overlapped >= 3
        assert events == 0
