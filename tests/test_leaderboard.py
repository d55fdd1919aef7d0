"""Leaderboard agents on cmudrive: the sensors they ask for (camera size, field of view and pose through
our rasteriser, speedometer, GNSS, IMU) in CARLA's conventions and units, sensors we cannot give refused
before a run, and the example leaderboard agent driving a route on every CAV."""

from __future__ import annotations

import importlib.util
import json
import math
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cmudrive.agents.base import AgentSetupError, Observations, RouteSetup, sparse_plan
from cmudrive.bench import EvalConfig, evaluate_route
from cmudrive.bench.routes import read_routes
from cmudrive.cli import app
from cmudrive.leaderboard import (
    LeaderboardAgent,
    Location,
    SensorError,
    Transform,
    downsample_plan,
    geo_reference,
    global_plan,
    gnss_to_map,
    map_to_gnss,
    parse_sensors,
)
from cmudrive.leaderboard.geo import EARTH_RADIUS, GeoReference
from cmudrive.leaderboard.sensors import ImuTracker, SensorSpec, camera_poses, imu_readings
from cmudrive.maps import RoadMap, RoadOption, RoutePlanner, load_map, load_scenery
from cmudrive.sensors.camera import CameraConfig, FrontCamera
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot
from cmudrive.sim.weather import WEATHERS

REPO = Path(__file__).resolve().parents[1]
FIXTURES = Path(__file__).parent / "fixtures" / "leaderboard"
RECORDING = FIXTURES / "recording_agent.py"
LIDAR = FIXTURES / "lidar_agent.py"
EXAMPLE = REPO / "examples" / "leaderboard_pid_agent.py"
EXAMPLE_CONF = REPO / "examples" / "leaderboard_pid_agent.json"
SMOKE = REPO / "cmudrive" / "assets" / "routes" / "smoke.xml"


@pytest.fixture(scope="module")
def downtown() -> RoadMap:
    return load_map("downtown")


def route_setup(road_map: RoadMap, town: str = "downtown") -> RouteSetup:
    route = RoutePlanner(road_map).plan((141.0, 199.9), (568.2, 220.4))
    cavs = tuple(sparse_plan(f"cav{i}", route, privileged=True) for i in range(2))
    return RouteSetup("lb", town, "ClearNoon", 0.05, cavs, road_map=road_map)


def scene(xs: list[float], ys: list[float], yaws: list[float], speeds: list[float], extra=()) -> Snapshot:
    """CAVs at (xs, ys) heading ``yaws`` at ``speeds``, then background cars at ``extra`` (x, y, yaw)."""
    n, k = len(xs), len(extra)
    return Snapshot.from_rows(
        7,
        0.35,
        np.array([], str),
        ids=np.array([f"cav{i}" for i in range(n)] + [f"car{j}" for j in range(k)]),
        x=np.array(xs + [e[0] for e in extra], float),
        y=np.array(ys + [e[1] for e in extra], float),
        yaw=np.array(yaws + [e[2] for e in extra], float),
        speed=np.array(speeds + [0.0] * k, float),
        role=np.array([Role.CAV] * n + [Role.BACKGROUND] * k, np.int8),
        kind=np.full(n + k, ActorKind.CAR, np.int8),
    )


def observe(snap: Snapshot, n: int) -> Observations:
    return Observations(
        tick=snap.step,
        time=snap.time,
        cav_index=np.arange(n),
        x=snap.x[:n],
        y=snap.y[:n],
        yaw=snap.yaw[:n],
        speed=snap.speed[:n],
        accel=snap.accel[:n],
        snapshot=snap,
    )


def test_each_cav_gets_its_sensors_in_carla_shape_and_units(downtown: RoadMap) -> None:
    agent = LeaderboardAgent(agent=str(RECORDING), conf="my.conf")
    agent.setup(route_setup(downtown))
    route = RoutePlanner(downtown).plan((141.0, 199.9), (568.2, 220.4))
    (x0, y0), (x1, y1) = route.xy[10], route.xy[60]
    snap = scene([x0, x1], [y0, y1], [route.heading[10], route.heading[60]], [4.25, 11.5])
    controls = agent.run_step(observe(snap, 2))
    np.testing.assert_allclose(controls.throttle, 0.3)  # each instance's VehicleControl, batched
    np.testing.assert_allclose(controls.steer, 0.1)
    # the cameras: requested size, BGRA with alpha 255, the rasteriser's image for a 90 deg camera 1 m ahead
    reference = FrontCamera(
        CameraConfig(width=160, height=90, fov_deg=90.0, mount_x=1.0, mount_z=1.8),
        downtown,
        load_scenery(downtown),
    ).render(snap, np.array([0, 1]), WEATHERS["ClearNoon"])
    geo = geo_reference("downtown")
    for cav, instance in enumerate(agent.instances):
        assert instance.conf == "my.conf"
        data, timestamp = instance.inputs[-1]
        assert timestamp == pytest.approx(0.35)
        assert {frame for frame, _ in data.values()} == {7}
        image = data["front"][1]
        assert image.shape == (90, 160, 4) and image.dtype == np.uint8
        assert (image[..., 3] == 255).all()
        np.testing.assert_array_equal(image[..., [2, 1, 0]], reference[cav])
        assert data["speed"][1] == {"speed": pytest.approx(snap.speed[cav])}
        lat, lon, alt = data["gps"][1]
        back = gnss_to_map(np.array([lat, lon, alt]), geo)
        assert np.hypot(back[0] - snap.x[cav], back[1] - snap.y[cav]) < 0.01  # [m]
        imu = data["imu"][1]
        assert imu.shape == (7,) and imu[2] == pytest.approx(9.81)
        assert imu[6] == pytest.approx((math.pi / 2 - snap.yaw[cav]) % (2 * math.pi))


def test_a_rear_camera_sees_the_car_behind_and_the_front_camera_does_not(downtown: RoadMap) -> None:
    agent = LeaderboardAgent(agent=str(RECORDING))
    agent.setup(route_setup(downtown))
    far = 5000.0  # [m] outside the map: only ground, sky and our actors
    alone = scene([far, far + 50], [far, far], [0.0, 0.0], [0.0, 0.0])
    behind = scene([far, far + 50], [far, far], [0.0, 0.0], [0.0, 0.0], extra=[(far - 12.0, far, 0.0)])
    agent.run_step(observe(alone, 2))
    agent.run_step(observe(behind, 2))
    (before, _), (after, _) = agent.instances[0].inputs
    np.testing.assert_array_equal(before["front"][1], after["front"][1])
    changed = np.flatnonzero((before["rear"][1] != after["rear"][1]).any(axis=(0, 2)))
    assert len(changed) > 10
    assert abs(changed.mean() - 80.0) < 8.0  # straight behind: around the middle column of 160


def test_camera_pose_follows_carla_axes() -> None:
    # a camera 1 m forward, 0.5 m right, turned 90 deg right, on a CAV at (10, 20) heading north
    spec = SensorSpec("sensor.camera.rgb", "c", x=1.0, y=0.5, z=1.6, yaw=90.0, width=64, height=32, fov=90)
    snap = scene([10.0], [20.0], [math.pi / 2], [0.0])
    pose = camera_poses(snap, np.array([0]), spec)[0]
    np.testing.assert_allclose(pose, [10.5, 21.0, 1.6, 0.0], atol=1e-12)  # right of north is east


def test_gnss_follows_carla_geo_reference_and_round_trips() -> None:
    assert geo_reference("Town03") == GeoReference(49.0, 8.0)  # the towns' OpenDRIVE geoReference
    assert geo_reference("/some/where/Town05.net.xml") == GeoReference(49.0, 8.0)
    assert geo_reference("downtown") == GeoReference(42.0, 2.0)  # the leaderboard's default
    ref = geo_reference("Town03")
    rng = np.random.default_rng(0)
    xy = rng.uniform(-1000.0, 1000.0, (200, 2))
    z = rng.uniform(0.0, 20.0, 200)
    gnss = map_to_gnss(xy, z, ref)
    # the leaderboard's conversion, written in CARLA's frame (y = -y_map): x adds to mx, y subtracts from my
    scale = math.cos(math.radians(49.0))
    mx = scale * math.radians(8.0) * EARTH_RADIUS + xy[:, 0]
    my = scale * EARTH_RADIUS * math.log(math.tan(math.radians(90.0 + 49.0) / 2)) - (-xy[:, 1])
    lon = np.degrees(mx / (EARTH_RADIUS * scale))
    lat = np.degrees(2.0 * np.arctan(np.exp(my / (EARTH_RADIUS * scale)))) - 90.0
    np.testing.assert_allclose(gnss[:, 0], lat, atol=1e-11)
    np.testing.assert_allclose(gnss[:, 1], lon, atol=1e-11)
    np.testing.assert_allclose(gnss[:, 2], z)
    assert gnss[np.argmax(xy[:, 1]), 0] == gnss[:, 0].max()  # north (+y on our map) is up in latitude
    back = gnss_to_map(gnss, ref)
    assert np.abs(back[:, :2] - xy).max() < 0.01  # [m]


OPENDRIVE_DIR = REPO.parent / "shared" / "data" / "opendrive"  # CARLA's town files (test_import.py too)


@pytest.mark.skipif(
    not OPENDRIVE_DIR.is_dir(), reason="CARLA's OpenDRIVE files are not beside the repository"
)
def test_carla_towns_geo_reference_is_their_opendrive_header() -> None:
    for town in [f"Town0{k}" for k in range(1, 8)]:
        header = (OPENDRIVE_DIR / f"{town}.xodr").read_text()[:5000]
        lat = float(re.search(r"\+lat_0=([-+0-9.e]+)", header).group(1))  # type: ignore[union-attr]
        lon = float(re.search(r"\+lon_0=([-+0-9.e]+)", header).group(1))  # type: ignore[union-attr]
        assert geo_reference(town) == GeoReference(lat, lon), town


def test_global_plan_is_in_carla_world_and_gps(downtown: RoadMap) -> None:
    route = RoutePlanner(downtown).plan((141.0, 199.9), (568.2, 220.4))
    gps, world = global_plan(route, downtown, geo_reference("downtown"))
    assert len(gps) == len(world) == len(route)
    t, option = world[0]
    assert (t.location.x, t.location.y) == pytest.approx((route.xy[0, 0], -route.xy[0, 1]))
    assert t.rotation.yaw == pytest.approx(-math.degrees(route.heading[0]), abs=1e-9)
    assert option == RoadOption(int(route.option[0]))
    back = gnss_to_map(np.array([[p["lat"], p["lon"], p["z"]] for p, _ in gps]), geo_reference("downtown"))
    assert np.abs(back[:, :2] - route.xy).max() < 0.01
    # the base class keeps option changes and a point at least every 200 m, as the leaderboard's
    keep = downsample_plan(world, 200.0)
    assert keep[0] == 0 and keep[-1] == len(world) - 1
    assert np.diff(route.distance[keep]).max() <= 202.0
    # every manoeuvre's first point, except right after a lane change (the leaderboard's rule too)
    changes = np.flatnonzero(np.diff(route.option.astype(int))) + 1
    after_lane_change = np.isin(
        route.option[changes - 1], [RoadOption.CHANGELANELEFT, RoadOption.CHANGELANERIGHT]
    )
    assert set(changes[~after_lane_change].tolist()) <= set(keep)


def test_imu_reads_a_left_turn_in_carla_axes() -> None:
    # 5 m/s, turning left at 1 rad/s: centripetal 5 m/s^2 to the left (-y in CARLA), gyro z -1 (left-handed)
    tracker = ImuTracker(1)
    tracker.update(np.array([0]), 0.0, np.array([0.0]))
    tracker.update(np.array([0]), 0.05, np.array([0.05]))
    snap = scene([0.0], [0.0], [0.05], [5.0])
    spec = SensorSpec("sensor.other.imu", "imu")
    ax, ay, az, gx, gy, gz, compass = imu_readings(
        snap, np.array([0]), tracker.rate, tracker.rate_change, spec
    )[0]
    assert (ax, ay, az) == pytest.approx((0.0, -5.0, 9.81), abs=1e-9)
    assert (gx, gy, gz) == pytest.approx((0.0, 0.0, -1.0))
    assert compass == pytest.approx(math.pi / 2 - 0.05)  # heading a little north of east


def test_sensors_we_cannot_give_are_refused_naming_them() -> None:
    with pytest.raises(SensorError, match=r"sensor 'LIDAR_TOP' \(sensor\.lidar\.ray_cast\).*no LiDAR"):
        LeaderboardAgent.check_options({"agent": str(LIDAR)})
    cam = {"type": "sensor.camera.rgb", "id": "bev", "z": 2.5, "width": 64, "height": 64, "fov": 90}
    with pytest.raises(SensorError, match=r"'bev'.*tilted"):
        parse_sensors([{**cam, "pitch": -90.0}], "a.py")
    with pytest.raises(SensorError, match=r"'seg' \(sensor\.camera\.semantic_segmentation\)"):
        parse_sensors([{**cam, "type": "sensor.camera.semantic_segmentation", "id": "seg"}], "a.py")
    with pytest.raises(SensorError, match=r"'bev'.*needs width, height and fov"):
        parse_sensors([{"type": "sensor.camera.rgb", "id": "bev"}], "a.py")
    with pytest.raises(SensorError, match=r"'bev' is used 2 times"):
        parse_sensors([cam, cam], "a.py")


def test_a_lidar_stops_the_run_before_any_route_starts(tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = CliRunner().invoke(
        app, ["eval", "--routes", "smoke", "--agent", f"leaderboard:{LIDAR}", "--out", str(out)]
    )
    assert result.exit_code == 1
    assert "LIDAR_TOP" in result.output and "sensor.lidar.ray_cast" in result.output
    assert not (out / "routes").exists()


@pytest.mark.skipif(importlib.util.find_spec("carla") is not None, reason="CARLA's own client is installed")
def test_a_file_that_still_imports_carla_says_which_line_to_write() -> None:
    with pytest.raises(AgentSetupError, match=r"write `from cmudrive\.leaderboard import carla`"):
        LeaderboardAgent(agent=str(FIXTURES / "unchanged_imports_agent.py"))


def test_the_base_class_downsamples_the_plan_like_the_leaderboard() -> None:
    plan = [(Transform(Location(float(i), 0.0, 0.0)), RoadOption.LANEFOLLOW) for i in range(450)]
    plan[300] = (plan[300][0], RoadOption.LEFT)
    assert downsample_plan(plan, 200.0) == [0, 202, 300, 301, 449]


def test_the_example_leaderboard_agent_drives_every_cav_forward() -> None:
    spec = read_routes(SMOKE)[0]  # smoke_00: downtown, 4 CAVs among background traffic
    options = {"agent": str(EXAMPLE), "conf": str(EXAMPLE_CONF)}
    LeaderboardAgent.check_options(options)
    result = evaluate_route(spec, lambda: LeaderboardAgent(**options), EvalConfig(tick_cap=200))
    assert result.error is None
    # 10 s at up to 6 m/s on routes of ~150-300 m: every CAV covers a good part of its route
    for cav in result.cavs:
        assert cav.route_completion > 5.0, (cav.cav_id, cav.route_completion)


def test_the_readme_leaderboard_section_works_as_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The README's "Bring a leaderboard agent": its replacement imports are the example's, and its
    command runs from the repository root (a tiny tick cap and one route here, output in a temporary
    folder)."""
    text = (REPO / "README.md").read_text()
    section = text.split("### Bring a leaderboard agent", 1)[1].split("\n## ", 1)[0]
    block = re.findall(r"```python\n(.*?)```", section, flags=re.S)[0]
    imports = [line.split("#")[0].strip() for line in block.splitlines() if "cmudrive.leaderboard" in line]
    assert len(imports) == 3
    example = EXAMPLE.read_text()
    for line in imports:  # each name the README imports is imported so by the example or the fixture
        module, names = line.removeprefix("from ").split(" import ")
        assert all(
            re.search(rf"from {re.escape(module)} import .*\b{n.strip()}\b", example + RECORDING.read_text())
            for n in names.split(",")
        ), line
    command = re.findall(r"\n    (cmudrive eval .*?)\n\n", section.replace("\\\n", " "), flags=re.S)[0]
    args = shlex.split(command)[2:]
    args[args.index("--out") + 1] = str(tmp_path / "out")
    args += ["--tick-cap", "20", "--routes-subset", "0"]
    monkeypatch.chdir(REPO)  # the command's paths are the repository's
    result = CliRunner().invoke(app, ["eval", *args])
    assert result.exit_code == 0, result.output
    routes = json.loads((tmp_path / "out" / "results.json").read_text())["routes"]
    assert len(routes) == 1 and "crashed" not in routes[0]["status"], routes[0]
