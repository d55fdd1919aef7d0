"""Collecting shards in closed loop on the mini network: labels of a straight drive, the shards load with
``datasets``, resume, a bad route, the benchmark-route guard, and recovery views."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any, ClassVar

import datasets
import numpy as np
import pytest

from cmudrive.agents import Agent, Observation, Observations, RouteSetup
from cmudrive.agents.expert import ExpertAgent
from cmudrive.bench.callbacks import RouteCallback, Step
from cmudrive.bench.evaluator import EvalConfig, RouteHooks, evaluate_route
from cmudrive.bench.manifest import SetupMismatchError
from cmudrive.bench.records import STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED
from cmudrive.bench.routes import CavSpec, RouteSpec, read_routes
from cmudrive.bench.runner import ProgressCallback, RouteTask, run_task
from cmudrive.data import (
    COLUMNS,
    BenchmarkRouteError,
    RecoveryViews,
    ShardJob,
    ShardWriter,
    check_not_benchmark,
    collect,
    features,
    load_shards,
    shard_path,
    unpack_occupancy,
)
from cmudrive.data.collector import SAMPLE_EVERY, RouteInfo, RowCollector
from cmudrive.data.labels import plan_labels
from cmudrive.data.recovery import moved, to_view, view_poses
from cmudrive.maps import RoadMap
from cmudrive.maps.coords import map_to_carla, to_ego
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.dynamics import Controls
from cmudrive.sim.snapshot import Snapshot

EMPTY = EvalConfig(tick_cap=300, background=BackgroundConfig(vehicles=0, pedestrians=0))
ROUTES = Path(__file__).resolve().parents[1] / "cmudrive" / "assets" / "routes"


class InlineExecutor:
    """Routes one after another in this process (the runner's tasks, without worker processes)."""

    def run(self, tasks: list[RouteTask], on_progress: ProgressCallback | None = None) -> Iterator:
        for task in tasks:
            yield run_task(task)


def lane_route(m: RoadMap, net: Path, route_id: str, lanes: list[tuple[str, float, float]]) -> RouteSpec:
    """One CAV per (lane, start s, end s), driving along that lane."""
    cavs = []
    for k, (lane, s0, s1) in enumerate(lanes):
        i = m.lane(lane)
        xy = m.index.frenet_to_xy(np.full(4, i), np.linspace(s0, s1, 4))
        cavs.append(CavSpec(k, np.column_stack([map_to_carla(xy), np.zeros(4)])))
    return RouteSpec(route_id, str(net), "ClearNoon", 0, tuple(cavs))


@pytest.fixture(scope="module")
def straight(mini: RoadMap, mini_net: Path) -> RouteSpec:
    """Two CAVs on the straight two-way road C-E (x = 212 .. 392, y = 0), one each way, no traffic."""
    east = mini.lane("CE_1")
    length = float(mini.lane_length[east])
    west = "EC_1" if "EC_1" in list(mini.lane_ids) else "EC_0"
    return lane_route(mini, mini_net, "straight", [("CE_1", 5.0, length - 5.0), (west, 5.0, length - 5.0)])


@pytest.fixture(scope="module")
def dataset_dir(straight: RouteSpec, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("data")
    summary = collect([straight], out, InlineExecutor(), EMPTY)
    assert summary.written == ["straight"], summary.failed
    return out


def test_shards_load_with_datasets_and_keep_the_schema(dataset_dir: Path) -> None:
    ds = datasets.load_dataset("parquet", data_dir=str(dataset_dir), split="train")
    assert ds.column_names == list(COLUMNS)
    assert ds.features == features()  # image, array and list types come back as written
    assert len(ds) > 50
    row = ds[0]
    assert row["camera"].size == (256, 128) and row["camera"].mode == "RGB"
    assert row["merged_bev"].size == (128, 192) and row["merged_bev"].mode == "RGB"
    assert np.asarray(row["occupancy"]).shape == (192, 128)
    assert set(ds["cav"]) == {0, 1}
    assert all(t % SAMPLE_EVERY == 0 for t in ds["tick"])
    np_rows = ds.with_format("numpy")[:4]
    assert np_rows["path"].shape == (4, 20, 2) and np_rows["path"].dtype == np.float32
    # (the numpy formatter widens integers to int64; the column itself is uint8, see ds.features)
    assert np_rows["merged_occupancy"].shape == (4, 192, 128) and np_rows["merged_occupancy"].max() < 16
    assert os.path.isdir(dataset_dir / ".routes")  # the route records sit beside the shards, not in the data
    same = datasets.load_dataset(str(dataset_dir), split="train")  # the folder alone: parquet inferred
    assert same.features == ds.features and len(same) == len(ds)
    assert load_shards(dataset_dir, columns=["cav", "tick"]).column_names == ["cav", "tick"]


def test_straight_constant_speed_drive_has_straight_evenly_spaced_waypoints(dataset_dir: Path) -> None:
    """On the straight road, samples where the CAV's speed stays within 0.1 m/s over the next 2.5 s: speed
    waypoints 0.25 s x v apart within 0.25 s x 0.1 m/s (the speed change allowed) + 0.02 m (the speed is
    the sample tick's, positions integrate the ticks between); every label point within 0.1 m of the lane
    centre line through the ego (the lateral controller's wobble plus its lane offset)."""
    ds = datasets.load_dataset("parquet", data_dir=str(dataset_dir), split="train").with_format("numpy")
    cols = ds.select_columns(["cav", "tick", "speed", "path", "speed_waypoints"])[:]
    cav, tick, speed = cols["cav"], cols["tick"], cols["speed"]
    checked = 0
    for i in range(len(ds)):
        later = (cav == cav[i]) & (tick > tick[i]) & (tick <= tick[i] + 50)
        if later.sum() < 10 or speed[i] < 2.0 or np.abs(speed[later] - speed[i]).max() > 0.1:
            continue
        path, wp = cols["path"][i], cols["speed_waypoints"][i]
        np.testing.assert_allclose(np.diff(wp[:, 0], prepend=0.0), 0.25 * speed[i], atol=0.25 * 0.1 + 0.02)
        np.testing.assert_allclose(np.hypot(*np.diff(path, axis=0).T), 1.0, atol=1e-3)
        assert np.abs(path[:, 1]).max() < 0.1 and np.abs(wp[:, 1]).max() < 0.1
        checked += 1
    assert checked >= 10  # the drive has a constant-speed stretch to check


def test_resume_collects_only_what_is_missing(mini: RoadMap, mini_net: Path, tmp_path: Path) -> None:
    short = EvalConfig(tick_cap=40, background=BackgroundConfig(vehicles=0, pedestrians=0))
    specs = [lane_route(mini, mini_net, f"r{k}", [("CE_1", 5.0 + 20 * k, 120.0 + 20 * k)]) for k in range(2)]
    collect(specs, tmp_path, InlineExecutor(), short)
    first, second = shard_path(tmp_path, "r0"), shard_path(tmp_path, "r1")
    stamp = first.stat().st_mtime_ns
    second.unlink()
    with pytest.raises(FileExistsError, match="--resume"):
        collect(specs, tmp_path, InlineExecutor(), short)
    summary = collect(specs, tmp_path, InlineExecutor(), short, resume=True)
    assert summary.skipped == ["r0"] and summary.written == ["r1"]
    assert first.stat().st_mtime_ns == stamp and second.exists()
    assert not list(tmp_path.glob(".*.tmp"))
    runs = json.loads((tmp_path / ".run.json").read_text())["runs"]  # hidden: datasets reads the rest
    assert [r["resume"] for r in runs] == [False, True]
    second.unlink()  # a resume with another tick cap would mix shards of two setups
    with pytest.raises(SetupMismatchError, match=r"config\.tick_cap: 40 \(then\) -> 41 \(now\)"):
        collect(specs, tmp_path, InlineExecutor(), replace(short, tick_cap=41), resume=True)
    assert not second.exists()


def test_a_bad_route_is_named_and_the_others_are_written(
    mini: RoadMap, mini_net: Path, tmp_path: Path
) -> None:
    short = EvalConfig(tick_cap=20, background=BackgroundConfig(vehicles=0, pedestrians=0))
    good = lane_route(mini, mini_net, "good", [("CE_1", 5.0, 120.0)])
    bad = RouteSpec("bad_town_route", "no_such_town", "ClearNoon", 0, good.cavs)
    summary = collect([bad, good], tmp_path, InlineExecutor(), short)
    assert summary.written == ["good"]
    assert "bad_town_route" in summary.failed and "bad_town_route" in summary.failed["bad_town_route"]
    assert shard_path(tmp_path, "good").exists() and not shard_path(tmp_path, "bad_town_route").exists()
    assert (tmp_path / ".routes" / "bad_town_route.json").exists()
    ds = datasets.load_dataset("parquet", data_dir=str(tmp_path), split="train")
    assert set(ds["route_id"]) == {"good"}


def test_occupancy_columns_unpack_to_the_sensor_layout(dataset_dir: Path) -> None:
    ds = datasets.load_dataset("parquet", data_dir=str(dataset_dir), split="train").with_format("numpy")
    cols = ds.select_columns(["cav", "occupancy", "merged_occupancy", "partner"])[:]
    own, merged = cols["occupancy"], cols["merged_occupancy"]
    grids = unpack_occupancy(own)
    assert grids.shape == (len(ds), 4, 192, 128)
    assert np.all(merged | own == merged)  # the merged map holds everything the ego's own map holds
    partner = cols["partner"]
    assert np.all(partner != cols["cav"])
    # the two CAVs drive towards each other: while within 70 m they see each other, so each has a partner
    assert (partner >= 0).any()


def test_benchmark_routes_are_refused_and_training_routes_pass() -> None:
    bench = read_routes(ROUTES / "cmudrive44.xml")
    with pytest.raises(BenchmarkRouteError, match=bench[3].id):
        check_not_benchmark(bench[3:5])
    check_not_benchmark(read_routes(ROUTES / "training.xml"))
    renamed = [RouteSpec("my_copy", s.town, s.weather, s.seed, s.cavs, s.scenarios) for s in bench[:1]]
    with pytest.raises(BenchmarkRouteError, match="benchmark place"):  # same place under another name
        check_not_benchmark(renamed)
    with pytest.raises(BenchmarkRouteError):
        collect(bench[:1], Path("/nonexistent"), InlineExecutor())


def test_worker_processes_and_ray_write_the_same_shard(tmp_path: Path) -> None:
    """The real executors: the job pickles to a spawned worker and to a Ray task, and a route's samples do
    not depend on which one ran it (routes are deterministic by seed)."""
    ray = pytest.importorskip("ray", reason="Ray is an optional extra: pip install 'cmudrive[ray]'")
    from cmudrive.bench.runner import LocalExecutor, RayExecutor

    from .test_evaluator import ring_route

    short = EvalConfig(tick_cap=60, background=BackgroundConfig(vehicles=0, pedestrians=0))
    route = [ring_route("ring", seed=2)]
    collect(route, tmp_path / "local", LocalExecutor(1), short)
    try:
        collect(route, tmp_path / "ray", RayExecutor(), short)
    finally:
        ray.shutdown()
    a = datasets.load_dataset("parquet", data_dir=str(tmp_path / "local"), split="train")
    b = datasets.load_dataset("parquet", data_dir=str(tmp_path / "ray"), split="train")
    assert len(a) == len(b) == 2 * (60 // SAMPLE_EVERY)
    names = ["cav", "tick", "speed", "path", "speed_waypoints", "commentary", "partner"]
    assert a.select_columns(names).to_dict() == b.select_columns(names).to_dict()


def test_stats_and_show_commands(dataset_dir: Path, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from cmudrive.cli import app
    from cmudrive.data.stats import dataset_stats

    stats = dataset_stats(dataset_dir)
    ds = datasets.load_dataset("parquet", data_dir=str(dataset_dir), split="train")
    assert stats["samples"] == len(ds) and stats["routes"] == 1
    assert sum(stats["counts"]["num_cavs"].values()) == len(ds) and stats["counts"]["num_cavs"] == {
        2: len(ds)
    }
    assert stats["counts"]["reason"] == dict(zip(*np.unique(ds["reason"], return_counts=True), strict=True))
    assert 0 < stats["bytes_per_sample"] < 20_000
    assert stats["ranges"]["path end x [m]"]["max"] == pytest.approx(19.0, abs=1e-3)  # a straight road
    result = CliRunner().invoke(app, ["data", "stats", str(dataset_dir)])
    assert result.exit_code == 0 and f"{len(ds)} samples from 1 routes (1 shards; 0 of them" in result.output
    out = tmp_path / "grid.png"
    result = CliRunner().invoke(app, ["data", "show", str(dataset_dir), "-o", str(out), "--count", "3"])
    assert result.exit_code == 0, result.output
    assert out.stat().st_size > 10_000
    result = CliRunner().invoke(app, ["data", "show", str(dataset_dir), "-o", str(out), "--types", "Nope"])
    assert result.exit_code == 1 and "Nope" in result.output


class RaisesAtTick30(ExpertAgent):
    def run_step(self, obs: Observations) -> Controls:
        if obs.tick == 30:
            raise RuntimeError("expert failure at tick 30")
        return super().run_step(obs)


def test_a_route_that_crashes_midway_leaves_no_shard(mini: RoadMap, mini_net: Path, tmp_path: Path) -> None:
    route = lane_route(mini, mini_net, "crashes", [("CE_1", 5.0, 120.0)])
    schema = features().arrow_schema
    result = ShardJob(str(tmp_path), schema)(route, RaisesAtTick30, EMPTY, RouteHooks())
    assert result.status == STATUS_AGENT_CRASHED and "expert failure at tick 30" in (result.error or "")
    assert not shard_path(tmp_path, "crashes").exists() and not list(tmp_path.glob(".*.tmp"))
    with pytest.raises(FileNotFoundError, match=r"no \.parquet shard"):
        load_shards(tmp_path)


def test_rows_feed_the_model_processor(dataset_dir: Path) -> None:
    """The shards' columns are what V2V-VLA's processor reads (camera, merged BEV, speed, target points,
    other CAVs, waypoint and language labels)."""
    pytest.importorskip("torch")
    from cmudrive.model.config import get_config
    from cmudrive.model.processor import VLAProcessor

    ds = datasets.load_dataset("parquet", data_dir=str(dataset_dir), split="train")
    rows = [ds[i] for i in range(0, len(ds), 25)]
    batch = VLAProcessor.from_config(get_config("tiny"))(rows)
    assert batch.path is not None and tuple(batch.path.shape) == (len(rows), 20, 2)
    assert batch.speed_waypoints is not None and tuple(batch.speed_waypoints.shape) == (len(rows), 10, 2)
    assert tuple(batch.target_points.shape) == (len(rows), 2, 2)


# ---------------------------------------------------------------- recovery views (cmudrive.data.recovery)
@pytest.fixture(scope="module")
def views_dir(straight: RouteSpec, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The straight two-CAV drive, half of its rows with a view up to 1.5 m aside and no turn (so that the
    lane's offset in the view reads directly)."""
    out = tmp_path_factory.mktemp("views")
    summary = collect([straight], out, InlineExecutor(), EMPTY, recovery=RecoveryViews(0.5, 1.5, 0.0))
    assert summary.written == ["straight"], summary.failed
    return out


@pytest.fixture(scope="module")
def with_views(views_dir: Path) -> datasets.Dataset:
    return datasets.load_dataset("parquet", data_dir=str(views_dir), split="train")


def _own_and_views(ds: datasets.Dataset) -> tuple[np.ndarray, np.ndarray]:
    view = np.asarray(ds["view"], np.float64)
    is_view = np.abs(view).sum(axis=1) > 0
    return np.flatnonzero(~is_view), np.flatnonzero(is_view)


def test_the_cavs_own_rows_are_those_of_a_collection_without_views(
    with_views: datasets.Dataset, dataset_dir: Path
) -> None:
    plain = datasets.load_dataset("parquet", data_dir=str(dataset_dir), split="train")
    own, views = _own_and_views(with_views)
    assert len(own) == len(plain)
    assert 0.35 * len(own) < len(views) < 0.65 * len(own)  # half of the rows, drawn
    cols = ["cav", "tick", "speed", "path", "speed_waypoints", "target_points", "merged_occupancy"]
    a = with_views.select(own).select_columns(cols).with_format("numpy")[:]
    b = plain.select_columns(cols).with_format("numpy")[:]
    for c in cols:
        np.testing.assert_array_equal(a[c], b[c], err_msg=c)
    assert with_views.select(own)["camera"][0].tobytes() == plain["camera"][0].tobytes()


def test_a_view_beside_the_cav_puts_its_lane_centre_that_far_the_other_way(
    with_views: datasets.Dataset, mini: RoadMap
) -> None:
    """CAV 0 drives east along lane CE_1 (straight, heading +x): from a view dy to its left, every path
    point lies on the lane's centre line, dy (+- 0.05 m) to the right of where the CAV itself sees it."""
    own, views = _own_and_views(with_views)
    ds = with_views.with_format("numpy")
    cols = ds.select_columns(["cav", "tick", "view", "path", "target_points"])[:]
    key = {
        (int(c), int(t)): i for i, (c, t) in enumerate(zip(cols["cav"][own], cols["tick"][own], strict=True))
    }
    checked = 0
    for i in views:
        c, t = int(cols["cav"][i]), int(cols["tick"][i])
        j = own[key[(c, t)]]
        dy = float(cols["view"][i][1])
        assert cols["view"][i][0] == 0.0 and cols["view"][i][2] == 0.0
        np.testing.assert_allclose(cols["path"][i][:, 1], cols["path"][j][:, 1] - dy, atol=1e-5)
        np.testing.assert_allclose(cols["path"][i][:, 0], cols["path"][j][:, 0], atol=1e-5)
        np.testing.assert_allclose(
            cols["target_points"][i][:, 1], cols["target_points"][j][:, 1] - dy, atol=1e-4
        )
        if c == 0 and abs(dy) > 0.5:
            assert np.abs(cols["path"][j][:, 1]).max() < 0.05  # the expert holds the lane centre
            np.testing.assert_allclose(cols["path"][i][:, 1], -dy, atol=0.05)
            checked += 1
    assert checked >= 5


def test_stats_count_the_views(with_views: datasets.Dataset, views_dir: Path, dataset_dir: Path) -> None:
    from cmudrive.data.stats import dataset_stats

    _, views = _own_and_views(with_views)
    assert dataset_stats(views_dir)["recovery_views"] == len(views) > 0
    assert dataset_stats(dataset_dir)["recovery_views"] == 0


def test_views_are_sensed_from_their_own_pose(with_views: datasets.Dataset) -> None:
    """The farthest view's camera differs from the CAV's own image of the same tick (the road and its
    markings moved sideways)."""
    own, views = _own_and_views(with_views)
    ds = with_views
    cav, tick = np.asarray(ds["cav"]), np.asarray(ds["tick"])
    i = int(views[np.argmax(np.abs(np.asarray(ds["view"])[views, 1]))])  # the farthest view
    j = int(own[(cav[own] == cav[i]) & (tick[own] == tick[i])][0])
    a, b = np.asarray(ds[i]["camera"], np.float64), np.asarray(ds[j]["camera"], np.float64)
    assert np.abs(a - b).mean() > 2.0  # grey levels of 255: the road and its markings moved


def test_view_poses_and_the_moved_snapshot() -> None:
    """A view 1 m left of a CAV heading north (+y) stands 1 m west of it, turned as asked; only the CAV's
    row of the snapshot moves; a point 1 m right of the CAV's front sits 2 m right in the view."""
    pose = view_poses(np.array([10.0]), np.array([5.0]), np.array([np.pi / 2]), np.array([[0.0, 1.0, 0.1]]))
    np.testing.assert_allclose(pose, [[9.0, 5.0, np.pi / 2 + 0.1]], atol=1e-12)
    snap = Snapshot.from_rows(0, 0.0, np.array([], str), x=np.array([10.0, 30.0]), y=np.array([5.0, 5.0]))
    there = moved(snap, np.array([0]), pose)
    assert (there.x[0], there.y[0]) == (9.0, 5.0) and there.x[1] == 30.0 and snap.x[0] == 10.0
    np.testing.assert_allclose(to_view(np.array([[2.0, -1.0]]), np.array([0.0, 1.0, 0.0])), [[2.0, -2.0]])


def test_a_share_outside_zero_to_one_is_refused() -> None:
    with pytest.raises(ValueError, match="share must be in"):
        RecoveryViews(prob=1.5)


# ---------------------------------------------------------------- closed-loop data: another agent drives
class Drifter(Agent):
    """Holds ~4 m/s and steers slightly right (CARLA's sign) for 5 s, then straight: it leaves its lane
    to the right (~1 m in 10 s), where the expert would keep to the lane centre."""

    observations: ClassVar[frozenset[Observation]] = frozenset({Observation.EGO_STATE})

    def setup(self, route: RouteSetup) -> None:
        pass

    def run_step(self, obs: Observations) -> Controls:
        n = len(obs.cav_index)
        throttle = np.where(obs.speed < 4.0, 0.5, 0.0)
        steer = np.full(n, 0.01 if obs.tick < 100 else 0.0)
        return Controls(throttle=throttle, steer=steer, brake=np.zeros(n))


class Poses(RouteCallback):
    """Every CAV's pose at every tick, as the agent saw it."""

    def __init__(self) -> None:
        self.pose: dict[tuple[int, int], np.ndarray] = {}

    def on_step(self, step: Step) -> None:
        s = step.snapshot
        for r, k in zip(step.rows, step.cav_index, strict=True):
            self.pose[(int(k), step.tick)] = np.array([s.x[r], s.y[r], s.yaw[r], s.speed[r]])


@pytest.fixture(scope="module")
def drifted(mini: RoadMap, mini_net: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, Poses]:
    """The drifter drives one CAV east on C-E for 10 s; the expert labels beside it."""
    route = lane_route(mini, mini_net, "drift", [("CE_1", 5.0, 150.0)])
    out = tmp_path_factory.mktemp("drift")
    writer = ShardWriter(out, route.id, features().arrow_schema)
    info = RouteInfo(route.id, "", route.weather, route.town, 1)
    collector = RowCollector(info, writer, seed=0, labeller=ExpertAgent(), driver="drifter")
    poses = Poses()
    config = replace(EMPTY, tick_cap=200)
    result = evaluate_route(route, Drifter, config, callbacks=[collector, poses])
    assert result.status not in (STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED), result.error
    return load_shards(out), poses


def test_closed_loop_rows_are_labelled_by_the_expert_not_the_driver(drifted: tuple[Any, Poses]) -> None:
    """Wherever the drifter is, the path label starts on the lane centre (+-0.15 m) and leads along it
    (+-0.3 m at 19 m); where it is more than 0.5 m right of the centre, the expert's controls steer left,
    back to it, while the driver steered right or straight."""
    ds, poses = drifted
    assert len(ds) == 200 // SAMPLE_EVERY and set(ds["driver"]) == {"drifter"}
    lane_y = poses.pose[(0, 0)][1]  # the CAV starts on the lane centre of the straight road
    off = 0
    for row in ds:
        x, y, yaw, _ = poses.pose[(0, row["tick"])]
        d = y - lane_y  # [m] left of the lane centre (the road runs along +x)
        path = np.asarray(row["path"], np.float64)
        centre = to_ego(np.array([[x, lane_y], [x + 19.0, lane_y]]), x, y, yaw)  # the lane, seen from the CAV
        assert np.linalg.norm(path[0] - centre[0]) < 0.15, (row["tick"], d, path[0], centre[0])
        assert np.linalg.norm(path[-1] - centre[1]) < 0.3, (row["tick"], d, path[-1], centre[1])
        if d < -0.5:
            off += 1
            assert row["steer"] < -0.3, (row["tick"], d, row["steer"])  # left, back to the lane
    assert off >= 10  # the drifter spent seconds beside its lane: those rows were checked


def test_plan_labels_start_on_the_plan_and_roll_at_the_commanded_acceleration() -> None:
    plan = np.stack([np.arange(40.0), np.zeros(40)], axis=1)  # straight along +x, 1 m apart
    path, speed = plan_labels(plan, 3.3, 1.0, 0.0, 5.0, 0.0, 5.0)  # 1 m left of it, cruising
    np.testing.assert_allclose(path[:, 1], -1.0, atol=1e-6)
    np.testing.assert_allclose(path[:, 0], np.arange(20.0), atol=1e-5)
    np.testing.assert_allclose(speed[:, 0], 5.0 * 0.25 * np.arange(1, 11), atol=1e-4)
    _, braking = plan_labels(plan, 0.0, 0.0, 0.0, 10.0, -5.0, 0.0)  # stands after 2 s and 10 m
    assert braking[-1, 0] == pytest.approx(10.0, abs=0.05) and braking[-1, 0] == braking[-2, 0]
    _, starting = plan_labels(plan, 0.0, 0.0, 0.0, 0.0, 2.0, 3.0)  # 2 m/s^2 up to 3 m/s, then 3 m/s
    assert starting[-1, 0] == pytest.approx(2.25 + 3.0 * 1.0, abs=0.15)
    _, past_end = plan_labels(plan[:5], 0.0, 0.0, 0.0, 10.0, 0.0, 10.0)  # a short plan goes on straight
    assert past_end[-1, 0] == pytest.approx(25.0, abs=1e-4) and abs(past_end[-1, 1]) < 1e-6
    end = np.tile([[5.0, 5.0]], (40, 1))  # at the end of its route the plan is one point, repeated
    path, _ = plan_labels(end, 5.0, 5.0, np.pi / 2, 2.0, 0.0, 2.0)  # the CAV heads along +y
    np.testing.assert_allclose(path[:, 0], np.arange(20.0), atol=1e-5)  # straight ahead of it
    np.testing.assert_allclose(path[:, 1], 0.0, atol=1e-5)


def test_collect_with_another_driver_names_it_in_the_rows(
    mini: RoadMap, mini_net: Path, tmp_path: Path
) -> None:
    route = lane_route(mini, mini_net, "pid", [("CE_1", 5.0, 80.0)])
    config = replace(EMPTY, tick_cap=60)
    summary = collect([route], tmp_path, InlineExecutor(), config, driver="pid")
    assert summary.written == ["pid"], summary.failed
    ds = load_shards(tmp_path)
    assert set(ds["driver"]) == {"pid"} and len(ds) == 60 // SAMPLE_EVERY
    run = json.loads((tmp_path / ".run.json").read_text())
    assert run["setup"]["agent"] == "cmudrive.agents.pid:PidAgent"
