"""The embedded world on the mini network: SUMO traffic reacting to CAVs, lights, pedestrians,
emergency vehicles, control validation and determinism. Behaviour is asserted in physical units."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmudrive.maps import LaneKind, LanePos, RoadMap, RoutePlanner
from cmudrive.sim import ControlError, Controls, Role, Snapshot, World, WorldConfig
from cmudrive.sim.traffic_lights import GREEN_TIME, RED_STATES, YELLOW_TIME

DT = 0.05  # [s]


def make_world(mini_net: Path, mini: RoadMap, seed: int = 1) -> World:
    return World(WorldConfig(town=mini_net, seed=seed), road_map=mini)


def route_from(mini: RoadMap, lane: str, s: float, goal_lane: str, goal_s: float):
    return RoutePlanner(mini).plan_lanes(LanePos(mini.lane(lane), s), LanePos(mini.lane(goal_lane), goal_s))


def drive_counting(
    world: World, ticks: int, steer: float = 0.0, throttle: float = 0.0, brake: float = 0.0
) -> tuple[list[Snapshot], int]:
    """Tick with the same controls for every active CAV; the snapshots and the collision events seen."""
    n = int(world.cav_active.sum())
    snaps, events = [], 0
    for _ in range(ticks):
        snaps.append(world.tick(Controls(np.full(n, steer), np.full(n, throttle), np.full(n, brake))))
        events += len(world.collisions)
    return snaps, events


def drive(
    world: World, ticks: int, steer: float = 0.0, throttle: float = 0.0, brake: float = 0.0
) -> list[Snapshot]:
    return drive_counting(world, ticks, steer, throttle, brake)[0]


def test_sumo_car_stops_behind_a_braking_cav(mini_net: Path, mini: RoadMap) -> None:
    """On the one-lane road C-E, a SUMO car follows a CAV at 10 m/s; the CAV brakes hard to a stop and the
    car stops behind it, bumper to bumper 1-8 m, without touching it."""
    with make_world(mini_net, mini) as world:
        world.add_cav(route_from(mini, "CE_1", 90.0, "CE_1", 190.0), speed=10.0)
        world.sumo.add_vehicle("follower", "car", ["CE"], Role.BACKGROUND, depart_pos=50.0, depart_speed=10.0)
        drive(world, 40, throttle=0.3)  # 2 s cruising
        snaps, events = drive_counting(world, 200, brake=1.0)  # 10 s braking and standing
        last = snaps[-1]
        cav, car = last.index_of("cav0"), last.index_of("follower")
        assert last.speed[cav] == 0.0 and last.speed[car] < 0.05
        gap = (last.x[cav] - 0.5 * last.length[cav]) - (last.x[car] + 0.5 * last.length[car])
        assert 1.0 < gap < 8.0
        assert events == 0


def test_forced_red_light_stops_background_traffic(mini_net: Path, mini: RoadMap) -> None:
    """With junction C held red, a SUMO car from W stops 0-6 m before the stop line (x = 192.8 m)."""
    with make_world(mini_net, mini) as world:
        world.add_cav(route_from(mini, "CN_1", 100.0, "CN_1", 150.0))  # parked far away, not in the way
        world.lights.force_lanes(mini.link_from[mini.link_tls >= 0], "r", others="r")
        world.sumo.add_vehicle("car", "car", ["WC", "CE"], Role.BACKGROUND, depart_pos=100.0, depart_lane=1)
        snaps = drive(world, 600, brake=1.0)
        last = snaps[-1]
        car = last.index_of("car")
        front = last.x[car] + 0.5 * last.length[car]
        assert last.speed[car] < 0.05
        assert 192.8 - 6.0 < front <= 192.8
        # signals that were green show yellow for YELLOW_TIME, then every signal is red
        yellow_ticks = round(YELLOW_TIME / world.dt)
        assert all(set(str(s.tls_state[0])) <= {"r", "y"} for s in snaps[:yellow_ticks])
        assert "y" in str(snaps[0].tls_state[0])
        assert all(set(str(s.tls_state[0])) == {"r"} for s in snaps[yellow_ticks:])
        world.lights.release()
        snaps = drive(world, 1600, brake=1.0)  # the normal cycle resumes and lets it go
        assert "car" not in snaps[-1].ids or snaps[-1].x[snaps[-1].index_of("car")] > 200.0


def test_forced_lights_go_through_yellow_from_green_to_red(mini_net: Path, mini: RoadMap) -> None:
    """Forcing a green signal red, and releasing a forced green into a program phase where it is red, both
    show yellow for YELLOW_TIME first; red to green switches at once."""
    yellow_ticks = round(YELLOW_TIME / 0.05)
    tls = int(mini.link_tls[mini.link_tls >= 0][0])
    first_phase = str(mini.phase_state[mini.tls_phase_ptr[tls]])
    links = np.flatnonzero(mini.link_tls == tls)
    red = [k for k in links.tolist() if first_phase[mini.link_tls_index[k]] in RED_STATES]
    lane = int(mini.link_from[red[0]])  # its signal is red in the program's first phase
    index = int(mini.link_tls_index[red[0]])
    with make_world(mini_net, mini) as world:
        world.add_cav(route_from(mini, "CN_1", 100.0, "CN_1", 150.0))

        def signals(ticks: int) -> list[str]:
            return [str(s.tls_state[tls])[index] for s in drive(world, ticks)]

        world.lights.force_lanes([lane], "G")
        assert signals(1) == ["G"]  # red to green: at once
        world.lights.force_lanes([lane], "r")
        seen = signals(80)
        assert seen[: yellow_ticks - 1] == ["y"] * (yellow_ticks - 1)
        assert seen[yellow_ticks + 1 :] == ["r"] * (80 - yellow_ticks - 1)
        world.lights.force_lanes([lane], "G")
        assert signals(1) == ["G"]
        world.lights.release()  # back to the first phase, where this signal is red
        seen = signals(80)
        assert seen[: yellow_ticks - 1] == ["y"] * (yellow_ticks - 1)
        assert seen[yellow_ticks + 1 :] == ["r"] * (80 - yellow_ticks - 1)


def test_greens_last_10_s_as_carla_cycles_them(mini_net: Path, mini: RoadMap) -> None:
    """CARLA's lights cycle 10 s green (plus yellow) per group; netconvert's programs run 31-42 s greens,
    which leave an approach 45-80 s on red. Every green phase is capped at GREEN_TIME, and every signal
    of every light turns green within 35 s."""
    with make_world(mini_net, mini) as world:
        world.add_cav(route_from(mini, "CN_1", 100.0, "CN_1", 150.0))
        snaps = drive(world, round(35.0 / world.dt))
        for tls in range(len(mini.tls_ids)):
            seen = [str(s.tls_state[tls]) for s in snaps]
            for k in range(len(seen[0])):
                assert any(state[k] in "gGs" for state in seen), (tls, k)
        import libsumo

        for tls_id in world.lights.ids:
            for logic in libsumo.trafficlight.getAllProgramLogics(tls_id):
                greens = [
                    p.duration for p in logic.phases if "y" not in p.state and set(p.state) & set("gGs")
                ]
                assert greens and max(greens) <= GREEN_TIME


def test_scenario_car_runs_the_red_light_that_stops_background_traffic(mini_net: Path, mini: RoadMap) -> None:
    """With C held red, a scenario car told to ignore lights drives through; a background car stops."""
    with make_world(mini_net, mini) as world:
        world.add_cav(route_from(mini, "CN_1", 100.0, "CN_1", 150.0))
        world.lights.force_lanes(mini.link_from[mini.link_tls >= 0], "r", others="r")
        world.sumo.add_vehicle("runner", "car", ["WC", "CE"], Role.SCENARIO, depart_pos=100.0, depart_lane=1)
        world.sumo.add_vehicle("obeys", "car", ["WC", "CE"], Role.BACKGROUND, depart_pos=60.0, depart_lane=2)
        drive(world, 1)
        world.sumo.override("runner", ignore_lights=True)
        last = drive(world, 400)[-1]
        assert last.x[last.index_of("runner")] > 250.0  # through the junction, on C-E
        assert last.x[last.index_of("obeys")] < 192.8 and last.speed[last.index_of("obeys")] < 0.05


def test_standing_scenario_car_is_passed_in_the_other_lane() -> None:
    """On downtown's 3-lane one-way avenue J2_0-J2_1, a scenario car held at 0 m/s in the middle lane is an
    obstacle: the background car behind it changes lanes and passes it without touching it."""
    from cmudrive.maps import load_map

    town = load_map("downtown")
    middle = town.lane("J2_0-J2_1_3")
    with World(WorldConfig(town="downtown", seed=1), road_map=town) as world:
        world.add_cav(route_from(town, "J2_0-J2_1_2", 5.0, "J2_0-J2_1_2", 20.0))
        route = ["J2_0-J2_1", "J2_1-J2_2"]
        index = int(town.lane_index[middle])
        world.sumo.add_vehicle(
            "obstacle", "car", route, Role.SCENARIO, depart_pos=80.0, depart_lane=index, depart_speed=0.0
        )
        world.sumo.add_vehicle("behind", "car", route, Role.BACKGROUND, depart_pos=30.0, depart_lane=index)
        drive(world, 1, brake=1.0)
        world.sumo.override("obstacle", speed=0.0, lane_changes=False)
        passed = False
        snaps, events = drive_counting(world, 400, brake=1.0)
        for snap in snaps:
            b, o = snap.index_of("behind"), snap.index_of("obstacle")
            passed = passed or snap.y[b] > snap.y[o] + 8.0  # the avenue runs north
        assert passed and events == 0
        assert snap.speed[o] == 0.0 and snap.lane[o] == middle


def test_cav_driven_through_a_red_light_is_seen_crossing_on_red(mini_net: Path, mini: RoadMap) -> None:
    """SUMO does not hold our CAVs back: a CAV at full throttle crosses C's stop line while its link is red,
    and the snapshot shows it on the junction with the red state."""
    with make_world(mini_net, mini) as world:
        world.add_cav(route_from(mini, "WC_2", 150.0, "CN_1", 50.0), speed=8.0)
        wc2 = mini.lane("WC_2")
        world.lights.force_lanes([wc2], "r", others="G")
        stop_x = mini.polyline(wc2)[-1, 0]
        crossed = None
        for snap in drive(world, 120, throttle=0.6):
            front = snap.x[0] + 0.5 * snap.length[0]
            if front > stop_x and crossed is None:
                crossed = snap
        assert crossed is not None
        link = mini.successor_links(wc2)[0]
        state = str(crossed.tls_state[mini.link_tls[link]])[mini.link_tls_index[link]]
        assert state in RED_STATES


def test_pedestrians_walk_on_sidewalks_and_cross_at_crossings(mini_net: Path, mini: RoadMap) -> None:
    """A pedestrian walking from the south sidewalk of W-C to its north sidewalk (edge C-W) crosses at
    junction C on a crossing and is never on a driving lane."""
    import libsumo

    with make_world(mini_net, mini) as world:
        world.add_cav(route_from(mini, "NWN_1", 20.0, "NWN_1", 60.0))
        stages = libsumo.simulation.findIntermodalRoute("WC", "CW", modes="")
        edges = [e for st in stages for e in st.edges]
        world.sumo.add_person("walker", edges, depart_pos=170.0, arrival_pos=40.0, role=Role.BACKGROUND)
        kinds = []
        for snap in drive(world, 2400):
            if "walker" in snap.ids:
                lane = snap.lane[snap.index_of("walker")]
                kinds.append(LaneKind(int(mini.lane_kind[lane])) if lane >= 0 else None)
        assert LaneKind.CROSSING in kinds
        assert LaneKind.DRIVING not in kinds and None not in kinds
        assert set(kinds) <= {LaneKind.SIDEWALK, LaneKind.CROSSING, LaneKind.WALKINGAREA}


@pytest.mark.parametrize(("behind", "moves_aside"), [("ambulance", True), ("car", False)])
def test_emergency_vehicle_makes_traffic_move_aside(
    mini_net: Path, mini: RoadMap, behind: str, moves_aside: bool
) -> None:
    """A slow car with an ambulance (bluelight device) closing in from behind moves to the edge of its lane
    by more than 0.5 m; with an ordinary car behind it stays in the middle."""
    import libsumo

    with make_world(mini_net, mini) as world:
        world.add_cav(route_from(mini, "CN_1", 100.0, "CN_1", 150.0))
        world.sumo.add_vehicle(
            "slow", "car", ["WC", "CE"], Role.BACKGROUND, depart_pos=60.0, depart_lane=1, depart_speed=5.0
        )
        world.sumo.add_vehicle(
            "rear", behind, ["WC", "CE"], Role.BACKGROUND, depart_pos=5.0, depart_lane=1, depart_speed=10.0
        )
        drive(world, 1, brake=1.0)
        libsumo.vehicle.setMaxSpeed("slow", 5.0)
        shift = 0.0
        for snap in drive(world, 300, brake=1.0):
            if "slow" in snap.ids:
                shift = max(shift, abs(snap.y[snap.index_of("slow")] - (-4.8)))
        assert (shift > 0.5) == moves_aside


def test_nan_controls_are_rejected_naming_the_cav_and_clipping_is_counted(
    mini_net: Path, mini: RoadMap
) -> None:
    with make_world(mini_net, mini) as world:
        world.add_cav(route_from(mini, "WC_2", 20.0, "WC_2", 150.0))
        world.add_cav(route_from(mini, "WC_1", 20.0, "WC_1", 150.0))
        with pytest.raises(ControlError, match=r"CAV cav1: throttle is nan"):
            world.tick(Controls(np.zeros(2), np.array([0.5, np.nan]), np.zeros(2)))
        snap = world.tick(Controls(np.zeros(2), np.array([1.7, 0.2]), np.zeros(2)))
        assert world.cav_clipped.tolist() == [1, 0]
        assert np.all(np.isfinite(snap.x)) and snap.speed[0] > snap.speed[1]
        with pytest.raises(ControlError, match=r"one value per active CAV"):
            world.tick(Controls.zeros(3))


def test_finished_cav_leaves_the_world(mini_net: Path, mini: RoadMap) -> None:
    with make_world(mini_net, mini) as world:
        world.add_cav(route_from(mini, "WC_2", 20.0, "WC_2", 150.0))
        world.add_cav(route_from(mini, "WC_1", 20.0, "WC_1", 150.0))
        world.remove_cav(0)
        snap = world.tick(Controls.zeros(1))
        assert snap.ids[snap.role == Role.CAV].tolist() == ["cav1"]


def _run(mini_net: Path, mini: RoadMap, seed: int) -> list:
    with make_world(mini_net, mini, seed) as world:
        world.add_cav(route_from(mini, "WC_2", 20.0, "CN_1", 100.0), speed=5.0)
        world.sumo.add_vehicle("a", "car", ["WC", "CE"], Role.BACKGROUND, depart_pos=5.0, depart_lane=1)
        world.sumo.add_vehicle("b", "truck", ["EC", "CW"], Role.BACKGROUND, depart_pos=5.0)
        rng = np.random.default_rng(seed)
        snaps = []
        for _ in range(300):
            controls = Controls(rng.uniform(-0.1, 0.1, 1), rng.uniform(0, 0.6, 1), np.zeros(1))
            snaps.append(world.tick(controls))
        return snaps


def test_same_route_seed_and_controls_give_bit_identical_snapshots(mini_net: Path, mini: RoadMap) -> None:
    first, second = _run(mini_net, mini, 3), _run(mini_net, mini, 3)
    for a, b in zip(first, second, strict=True):
        assert a.ids.tolist() == b.ids.tolist()
        for field in ("x", "y", "yaw", "speed", "accel", "lane", "signals", "tls_state"):
            assert np.array_equal(getattr(a, field), getattr(b, field)), field
    assert len(first[-1].ids) == 3


def test_sumo_car_hit_by_a_cav_stops_for_5_s_with_hazard_lights(mini_net: Path, mini: RoadMap) -> None:
    """A CAV rams a car creeping along C-E at 3 m/s; the car stops with hazard lights on for 5 s (the
    collision hold), then drives on."""
    import libsumo

    from cmudrive.sim.snapshot import SIGNAL_BLINKER_EMERGENCY
    from cmudrive.sim.world import COLLISION_HOLD

    with make_world(mini_net, mini) as world:
        world.add_cav(route_from(mini, "CE_1", 20.0, "CE_1", 190.0), speed=10.0)
        world.sumo.add_vehicle("slow", "car", ["CE"], Role.BACKGROUND, depart_pos=50.0, depart_speed=3.0)
        drive(world, 1)
        libsumo.vehicle.setMaxSpeed("slow", 3.0)
        for _ in range(200):  # full throttle until the contact
            _, events = drive_counting(world, 1, throttle=1.0)
            if events:
                break
        assert events > 0
        within = drive(world, round(0.6 * COLLISION_HOLD / DT), brake=1.0)[-1]  # 3 s later: held
        car = within.index_of("slow")
        assert within.speed[car] == 0.0 and within.signals[car] & SIGNAL_BLINKER_EMERGENCY
        later = drive(world, round(0.8 * COLLISION_HOLD / DT), brake=1.0)[-1]  # 7 s after: driving on
        car = later.index_of("slow")
        assert later.speed[car] > 1.0 and not later.signals[car] & SIGNAL_BLINKER_EMERGENCY


def test_snapshot_columns_follow_actors_that_come_and_go(mini_net: Path, mini: RoadMap) -> None:
    """Ids, kinds and extents are shared read-only between ticks while nobody comes or goes, and follow
    an actor replaced under the same id by one of another type (a cone, then a parked car)."""
    with make_world(mini_net, mini) as world:
        world.add_cav(route_from(mini, "CE_1", 90.0, "CE_1", 190.0), speed=5.0)
        world.add_layer_actor("thing", "cone", 400.0, 400.0, 0.0, role=Role.PROP)  # off the road
        first, second = drive(world, 2)
        assert first.ids is second.ids and not second.length.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            second.kind[0] = 3
        cone = second.length[second.index_of("thing")]
        world.remove_layer_actor("thing")
        world.add_layer_actor("thing", "parked_car", 400.0, 400.0, 0.0, role=Role.PROP)
        (third,) = drive(world, 1)
        assert third.length[third.index_of("thing")] > cone + 2.0  # [m] a car, not a cone


def test_cav_off_the_road_leaves_sumo_and_comes_back_on_it(mini_net: Path, mini: RoadMap) -> None:
    """A CAV that turns off road C-E (more than 15 m into the open) is out of SUMO, lane -1, while it is there
    (SUMO could only put it on the nearest lane, where it is not); set back on its lane it is in SUMO
    again and a SUMO car coming up behind it stops 1-8 m short of it."""
    import libsumo

    with make_world(mini_net, mini) as world:
        world.add_cav(route_from(mini, "CE_1", 60.0, "CE_1", 190.0), speed=8.0)
        start = (float(world.cav_state.x[0]), float(world.cav_state.y[0]), float(world.cav_state.yaw[0]))
        assert "cav0" in libsumo.vehicle.getIDList()
        drive(world, 20, steer=1.0, throttle=0.3)  # a hard turn off the road, then straight on
        off = drive(world, 60, throttle=0.3)[-1]
        cav = off.index_of("cav0")
        assert abs(off.y[cav] - start[1]) > 15.0  # well away from the road
        assert "cav0" not in libsumo.vehicle.getIDList() and off.lane[cav] == -1
        st = world.cav_state  # put it back where it started, standing
        st.x[0], st.y[0], st.yaw[0], st.speed[0] = start[0], start[1], start[2], 0.0
        world.sumo.add_vehicle("car", "car", ["CE"], Role.BACKGROUND, depart_pos=5.0, depart_speed=8.0)
        snaps, events = drive_counting(world, 400, brake=1.0)
        last = snaps[-1]
        assert "cav0" in libsumo.vehicle.getIDList() and last.lane[last.index_of("cav0")] >= 0
        cav, car = last.index_of("cav0"), last.index_of("car")
        gap = (last.x[cav] - 0.5 * last.length[cav]) - (last.x[car] + 0.5 * last.length[car])
        assert last.speed[car] < 0.05 and 1.0 < gap < 8.0 and events == 0


def test_cav_whose_route_lies_inside_one_junction_enters_sumo(mini_net: Path, mini: RoadMap) -> None:
    """A 19 m route along one internal lane of junction C (InterDrive's shortest routes start and end
    inside a junction) gets the edge the junction leads to: the CAV is in SUMO and drives."""
    route = route_from(mini, ":C_1_0", 1.0, ":C_1_0", 20.0)
    assert all(mini.lane_internal[route.path])
    with make_world(mini_net, mini) as world:
        world.add_cav(route)
        snaps = drive(world, 20, throttle=0.5)
        assert world.cav_active.all() and snaps[-1].speed[snaps[-1].role == Role.CAV][0] > 1.0
