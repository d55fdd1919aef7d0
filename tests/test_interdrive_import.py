"""Importing the cooperative peers' scenario folders (InterDrive, MDrive-style) as our routes, and running
their free actors. The folders are written here on lanes of our Town05 (found on the map, so the test does
not depend on coordinates copied from anywhere): CARLA's frame is ours mirrored in y."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cmudrive.bench.authoring.interdrive import (
    NO_BACKGROUND,
    NPC_BACKGROUND,
    actor_type_for,
    import_scenario_folders,
    read_scenario_folder,
)
from cmudrive.bench.criteria.collisions import collision_key
from cmudrive.bench.evaluator import route_background
from cmudrive.bench.route_actors import RouteActors
from cmudrive.bench.route_sets import resolve_routes
from cmudrive.bench.routes import (
    BackgroundSpec,
    RouteSpecError,
    read_routes,
    start_conflicts,
    write_routes,
)
from cmudrive.maps import RoadMap, load_map
from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.snapshot import Role


@pytest.fixture(scope="module")
def town05() -> RoadMap:
    return load_map("Town05")


@pytest.fixture(scope="module")
def road(town05: RoadMap) -> tuple[int, int]:
    """A straight normal lane of Town05 at least 80 m long with a same-direction neighbour on its right."""
    m = town05
    for lane in np.argsort(-m.lane_length):
        lane = int(lane)
        right = int(m.lane_right[lane])
        if m.lane_internal[lane] or right < 0 or not (m.driving[lane] and m.driving[right]):
            continue
        if min(m.lane_length[lane], m.lane_length[right]) < 80:
            continue
        xy = m.index.frenet_to_xy(np.full(9, lane), np.linspace(0, 80, 9))
        heading = np.arctan2(*np.diff(xy, axis=0)[:, ::-1].T)
        if np.ptp(np.unwrap(heading)) < 0.02:  # straight: the points below stay on it
            return lane, right
    raise AssertionError("Town05 has no straight 80 m lane with a right neighbour")


def carla(m: RoadMap, lane: int, s: float) -> tuple[float, float]:
    """CARLA x, y of the centre of ``lane`` at ``s`` [m] (our map frame mirrored in y)."""
    x, y = m.index.frenet_to_xy(np.array([lane]), np.array([s]))[0]
    return round(float(x), 3), round(float(-y), 3)


def route_xml(town: str, points: list[tuple[float, float]], yaw: float = 0.0, **attrs: str) -> str:
    """A one-route leaderboard-style file; ``attrs`` go on the <route> (role, model, speed)."""
    extra = "".join(f' {k}="{v}"' for k, v in attrs.items())
    wps = "".join(f'<waypoint x="{x}" y="{y}" z="0.0" yaw="{yaw}" pitch="360.0"/>' for x, y in points)
    return f'<?xml version="1.0"?><routes><route id="7" town="{town}"{extra}>{wps}</route></routes>'


def test_interdrive_folder_becomes_one_route_with_egos_in_file_number_order(
    tmp_path: Path, town05: RoadMap, road: tuple[int, int]
) -> None:
    """Three role-less files named ``_2``, ``_0``, ``_1`` are egos 2, 0, 1: CAV k drives file k's
    waypoints, in CARLA's frame as written; no actors, no background, CARLA's default clear noon."""
    lane, right = road
    folder = tmp_path / "r99_town05_ins_c"
    folder.mkdir()
    starts = {0: (lane, 10.0), 1: (right, 10.0), 2: (lane, 30.0)}
    for k in (2, 0, 1):
        ln, s = starts[k]
        (folder / f"r99_town05_ins_c_{k}.xml").write_text(
            route_xml("Town05", [carla(town05, ln, s), carla(town05, ln, s + 45.0)])
        )
    result = import_scenario_folders(folder)
    assert result.skipped == [] and result.notes == []
    (spec,) = result.routes
    assert spec.id == "r99_town05_ins_c" and spec.town == "Town05" and spec.weather == "ClearNoon"
    assert spec.background == NO_BACKGROUND and spec.actors == ()
    assert spec.lights == "off"  # turn_off_light: the CAVs negotiate the junctions without signals
    assert len(spec.cavs) == 3
    for k, (ln, s) in starts.items():
        assert tuple(spec.cavs[k].waypoints[0, :2]) == carla(town05, ln, s)
        map_xy = spec.map_waypoints(k)[0]  # CARLA (x, y) is map (x, -y), on the lane it was taken from
        assert np.allclose(map_xy, town05.index.frenet_to_xy(np.array([ln]), np.array([s]))[0], atol=1e-3)
    assert import_scenario_folders(folder, npc=True).routes[0].background == NPC_BACKGROUND
    assert import_scenario_folders(tmp_path).routes[0] == spec  # a folder of scenario folders


def test_mdrive_folder_keeps_actors_with_kind_position_and_speed(
    tmp_path: Path, town05: RoadMap, road: tuple[int, int]
) -> None:
    """An MDrive-style folder: the manifest's ego order, and a pedestrian, a bicycle, a cone and a parked
    pickup as actors whose type, collision key, place (CARLA -> map frame) and speed follow the files,
    the manifest's values winning over the file's."""
    lane, right = road
    folder = tmp_path / "Blocked_Lane"
    (folder / "actors" / "static").mkdir(parents=True)
    (folder / "town05_vehicle_1_0.xml").write_text(
        route_xml("Town05", [carla(town05, lane, 10.0), carla(town05, lane, 60.0)], role="ego")
    )
    (folder / "town05_vehicle_2_1.xml").write_text(
        route_xml("Town05", [carla(town05, right, 10.0), carla(town05, right, 60.0)], role="ego")
    )
    ped = [carla(town05, lane, 40.0), carla(town05, right, 40.0)]
    (folder / "actors" / "walker.xml").write_text(route_xml("Town05", ped, role="pedestrian", speed="1.0"))
    (folder / "actors" / "bike.xml").write_text(
        route_xml(
            "Town05",
            [carla(town05, right, 20.0), carla(town05, right, 70.0)],
            role="bicycle",
            model="vehicle.bh.crossbike",
        )
    )
    cone_at = carla(town05, lane, 50.0)
    (folder / "actors" / "static" / "cone.xml").write_text(
        route_xml("Town05", [cone_at], role="static", model="static.prop.constructioncone", yaw=90.0)
    )
    (folder / "actors" / "static" / "truck.xml").write_text(
        route_xml(
            "Town05", [carla(town05, lane, 75.0)], role="static", model="vehicle.tesla.cybertruck", speed="3"
        )
    )
    manifest = {
        "ego": [{"file": "town05_vehicle_2_1.xml"}, {"file": "town05_vehicle_1_0.xml"}],
        "pedestrian": [
            {"file": "actors/walker.xml", "name": "walker_1", "speed": 1.2, "model": "walker.pedestrian.0007"}
        ],
    }
    (folder / "actors_manifest.json").write_text(json.dumps(manifest))

    spec = read_scenario_folder(folder)
    assert [tuple(c.waypoints[0, :2]) for c in spec.cavs] == [
        carla(town05, right, 10.0),
        carla(town05, lane, 10.0),
    ]
    actors = {a.id: a for a in spec.actors}
    assert sorted(actors) == ["bike", "cone", "truck", "walker_1"]
    kinds = {
        i: (a.type, collision_key(ACTOR_TYPES[a.type].kind), a.speed, a.static) for i, a in actors.items()
    }
    assert kinds == {
        "walker_1": ("pedestrian", "collisions_pedestrian", 1.2, False),  # the manifest's speed [m/s]
        "bike": ("bicycle", "collisions_vehicle", 4.0, False),  # a bicycle's default speed
        "cone": ("cone", "collisions_layout", 0.0, True),
        "truck": ("van", "collisions_vehicle", 0.0, True),  # a parked vehicle stands whatever its speed
    }
    assert actors["walker_1"].model == "walker.pedestrian.0007" and actors["walker_1"].moves
    cone = actors["cone"]
    assert np.allclose(cone.map_waypoints()[0], [cone_at[0], -cone_at[1]])
    assert math.isclose(cone.map_yaw(), -math.pi / 2)  # CARLA yaw 90 deg (clockwise) is -pi/2 in ours
    write_routes([spec], tmp_path / "out.xml")
    assert read_routes(tmp_path / "out.xml") == [spec]  # actors and background round-trip exactly


def test_bad_folders_are_refused_naming_file_scenario_and_vehicle(
    tmp_path: Path, town05: RoadMap, road: tuple[int, int]
) -> None:
    lane, _ = road
    good = [carla(town05, lane, 10.0), carla(town05, lane, 50.0)]
    role = tmp_path / "roles"
    role.mkdir()
    (role / "a_0.xml").write_text(route_xml("Town05", good))
    (role / "ufo.xml").write_text(route_xml("Town05", good, role="ufo"))
    with pytest.raises(RouteSpecError, match=r"ufo\.xml.*unknown role 'ufo'"):
        read_scenario_folder(role)
    town = tmp_path / "town"
    town.mkdir()
    (town / "a_0.xml").write_text(route_xml("Town42", good))
    with pytest.raises(RouteSpecError, match=r"route 'town': town Town42 is not available"):
        read_scenario_folder(town)
    far = tmp_path / "r1_far"
    far.mkdir()
    (far / "r1_far_0.xml").write_text(route_xml("Town05", good))
    (far / "r1_far_1.xml").write_text(route_xml("Town05", [(5000.0, 5000.0), (5050.0, 5000.0)]))
    result = import_scenario_folders(tmp_path)
    assert [r for r, _ in result.skipped] == ["r1_far", "roles", "town"]
    reason = dict(result.skipped)["r1_far"]
    assert "route 'r1_far'" in reason and "CAV 1" in reason and "r1_far_1.xml" in reason


def test_blueprints_give_the_collision_kind_carla_gives_them() -> None:
    keys = {
        m: collision_key(ACTOR_TYPES[actor_type_for(m)].kind)
        for m in (
            "walker.pedestrian.0001",
            "vehicle.diamondback.century",
            "vehicle.audi.a2",
            "vehicle.carlamotors.carlacola",
            "static.prop.trafficcone01",
            "static.prop.streetbarrier",
            "static.prop.something_new",
        )
    }
    assert set(keys.values()) == {"collisions_pedestrian", "collisions_vehicle", "collisions_layout"}
    assert [k for k, v in keys.items() if v == "collisions_layout"] == [
        "static.prop.trafficcone01",
        "static.prop.streetbarrier",
        "static.prop.something_new",
    ]
    with pytest.raises(ValueError, match="neither walker"):
        actor_type_for("sensor.camera.rgb")


class _FakeWorld:
    """What RouteActors needs of a World: layer actors with poses."""

    def __init__(self) -> None:
        self.poses: dict[str, tuple[float, float, float, float]] = {}
        self.roles: dict[str, Role] = {}

    def add_layer_actor(
        self, actor_id: str, type_name: str, x: float, y: float, yaw: float, speed: float, role: Role
    ) -> None:
        self.poses[actor_id], self.roles[actor_id] = (x, y, yaw, speed), role

    def set_layer_pose(self, actor_id: str, x: float, y: float, yaw: float, speed: float) -> None:
        self.poses[actor_id] = (x, y, yaw, speed)


def test_moving_actors_walk_their_path_at_their_speed_and_props_stand(
    tmp_path: Path, town05: RoadMap, road: tuple[int, int]
) -> None:
    """4 s at 1.2 m/s moves the pedestrian 4.8 m along its path; 60 s later it stands at its end; the cone
    stands where placed, a prop."""
    lane, _ = road
    folder = tmp_path / "walk"
    (folder / "actors").mkdir(parents=True)
    (folder / "w_0.xml").write_text(
        route_xml("Town05", [carla(town05, lane, 10.0), carla(town05, lane, 50.0)])
    )
    walk = [(0.0, 0.0), (0.0, 10.0)]  # 10 m towards CARLA +y: towards -y in ours
    (folder / "actors" / "p.xml").write_text(route_xml("Town05", walk, role="pedestrian", speed="1.2"))
    (folder / "actors" / "c.xml").write_text(route_xml("Town05", [(3.0, 4.0)], role="static", yaw=0.0))
    spec = read_scenario_folder(folder)
    world = _FakeWorld()
    actors = RouteActors(spec, world)  # type: ignore[arg-type]
    for _ in range(80):  # 80 ticks of 0.05 s
        actors.update(0.05)
    x, y, yaw, speed = world.poses["actor:p"]
    assert math.isclose(x, 0.0, abs_tol=1e-9) and math.isclose(y, -4.8, abs_tol=1e-6)
    assert math.isclose(yaw, -math.pi / 2) and speed == 1.2
    for _ in range(1200):
        actors.update(0.05)
    assert world.poses["actor:p"][1:2] == (-10.0,) and world.poses["actor:p"][3] == 0.0
    assert world.poses["actor:c"] == (3.0, -4.0, 0.0, 0.0) and world.roles["actor:c"] == Role.PROP


def test_route_background_overrides_the_evaluators_counts_only() -> None:
    """A route without <background> runs with the evaluator's; InterDrive's routes with none at all."""
    base = BackgroundConfig()
    spec = read_routes(resolve_routes("smoke"))[0]
    assert route_background(spec, base) is base
    quiet = route_background(replace(spec, background=BackgroundSpec(0, 0)), base)
    assert (quiet.vehicles, quiet.pedestrians, quiet.radius) == (0, 0, base.radius)


def test_side_by_side_starts_on_neighbouring_lanes_do_not_conflict(
    town05: RoadMap, road: tuple[int, int]
) -> None:
    """Two CAVs level on neighbouring lanes do not touch; 3 m apart on one lane they do (footprints
    4.89 x 2.10 m)."""
    from cmudrive.maps import LanePos, RoutePlanner

    lane, right = road
    planner = RoutePlanner(town05)
    a = planner.plan_lanes(LanePos(lane, 10.0), LanePos(lane, 40.0))
    beside = planner.plan_lanes(LanePos(right, 10.0), LanePos(right, 40.0))
    ahead = planner.plan_lanes(LanePos(lane, 13.0), LanePos(lane, 40.0))
    assert start_conflicts([a, beside]) == []
    assert [(i, j, round(d, 1)) for i, j, d in start_conflicts([a, ahead])] == [(0, 1, 3.0)]


def test_routes_import_cli_writes_a_folder_as_routes_and_says_what_it_skipped(
    tmp_path: Path, town05: RoadMap, road: tuple[int, int]
) -> None:
    """`cmudrive routes import FOLDER -o FILE --npc`: one route per scenario folder, the NPC variant's
    background, the folder that cannot be planned named on the way."""
    from typer.testing import CliRunner

    from cmudrive.cli import app

    lane, right = road
    src = tmp_path / "Interdrive"
    for name, far in (("r1_town05_ins_c", False), ("r2_town05_ins_c", True)):
        (src / name).mkdir(parents=True)
        (src / name / f"{name}_0.xml").write_text(
            route_xml("Town05", [carla(town05, lane, 10.0), carla(town05, lane, 60.0)])
        )
        second = (
            [(9000.0, 0.0), (9050.0, 0.0)]
            if far
            else [carla(town05, right, 10.0), carla(town05, right, 60.0)]
        )
        (src / name / f"{name}_1.xml").write_text(route_xml("Town05", second))
    out = tmp_path / "interdrive.xml"
    result = CliRunner().invoke(app, ["routes", "import", str(src), "-o", str(out), "--npc"])
    text = " ".join(result.output.split())
    assert result.exit_code == 0, text
    assert "skipped route r2_town05_ins_c:" in text and "r2_town05_ins_c_1.xml" in text
    assert "wrote 1 routes" in text
    (spec,) = read_routes(out)
    assert spec.id == "r1_town05_ins_c" and len(spec.cavs) == 2 and spec.background == NPC_BACKGROUND
