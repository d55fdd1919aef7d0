"""Route logs: a recorded run on the mini network rebuilds the same snapshots, controls and events; the
replay is a video with one frame per rendered tick and infraction markers; bad files raise naming them;
a long, busy route stays small on disk."""

from __future__ import annotations

import os
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from cmudrive.bench.recording import RouteRecorder, infraction_event
from cmudrive.bench.records import Infraction
from cmudrive.bench.route_log import RouteLog, RouteLogError, load_route_log
from cmudrive.maps import LanePos, RoadMap, RoutePlanner
from cmudrive.sim import Controls, Role, Snapshot, World, WorldConfig
from cmudrive.viz.bev import BevView
from cmudrive.viz.replay import (
    COLLISION_COLOUR,
    LIGHT_COLOUR,
    OTHER_COLOUR,
    SHORT_LABELS,
    SLOW_COLOUR,
    draw_events,
    draw_legend,
    legend_box,
    render_replay_frame,
    replay,
    replay_renderer,
)

TICKS = 100
REMOVE_CAV1_AT = 60  # tick at which CAV 1 finishes and leaves the world
COLLISION_TICK = 20
RED_LIGHT_TICK = 70
MB = 1024 * 1024


@dataclass
class Recorded:
    path: Path
    snaps: list[Snapshot]
    controls: list[Controls]
    cav_xy: list[np.ndarray]  # per tick (2, 2) positions of cav0 and cav1 (NaN once gone)


def route_from(mini: RoadMap, lane: str, s: float, goal_lane: str, goal_s: float):
    return RoutePlanner(mini).plan_lanes(LanePos(mini.lane(lane), s), LanePos(mini.lane(goal_lane), goal_s))


@pytest.fixture(scope="module")
def recorded(mini_net: Path, mini: RoadMap, tmp_path_factory: pytest.TempPathFactory) -> Recorded:
    """Two CAVs and two SUMO cars for 100 ticks; CAV 1 leaves at tick 60; a collision event at tick 40 and a
    red-light event at tick 70."""
    routes = [route_from(mini, "WC_2", 20.0, "CN_1", 100.0), route_from(mini, "WC_1", 30.0, "WC_1", 180.0)]
    recorder = RouteRecorder("mini_0", str(mini_net), [r.xy for r in routes])
    rng = np.random.default_rng(0)
    snaps, controls, cav_xy = [], [], []
    with World(WorldConfig(town=mini_net, seed=1), road_map=mini) as world:
        for r in routes:
            world.add_cav(r, speed=5.0)
        world.sumo.add_vehicle("a", "car", ["WC", "CE"], Role.BACKGROUND, depart_pos=5.0, depart_lane=1)
        world.sumo.add_vehicle("b", "truck", ["EC", "CW"], Role.BACKGROUND, depart_pos=5.0)
        snap = world.snapshot()
        for k in range(TICKS):
            if k == REMOVE_CAV1_AT:
                world.remove_cav(1)
            n = int(world.cav_active.sum())
            ctl = Controls(rng.uniform(-0.1, 0.1, n), rng.uniform(0.2, 0.6, n), np.zeros(n))
            snap = world.tick(ctl)
            rows = np.flatnonzero(snap.role == Role.CAV)
            recorder.record(snap, ctl, rows)
            snaps.append(snap)
            controls.append(ctl)
            xy = np.full((2, 2), np.nan)
            for row in rows.tolist():
                xy[int(str(snap.ids[row])[3:])] = snap.x[row], snap.y[row]
            cav_xy.append(xy)
    c = cav_xy[COLLISION_TICK][0]
    recorder.add_events(
        COLLISION_TICK, [{"cav": 0, "key": "collisions_vehicle", "x": c[0], "y": c[1], "message": "hit a"}]
    )
    inf = Infraction("red_light", RED_LIGHT_TICK, 3.5, 195.0, -1.6, "ran a red light", factor=0.7)
    recorder.add_events(RED_LIGHT_TICK, [infraction_event(0, inf)])
    path = recorder.save(tmp_path_factory.mktemp("logs") / "mini_0.npz")
    return Recorded(path, snaps, controls, cav_xy)


@pytest.fixture(scope="module")
def log(recorded: Recorded) -> RouteLog:
    return load_route_log(recorded.path)


def test_rebuilt_snapshots_equal_the_recorded_ones(recorded: Recorded, log: RouteLog) -> None:
    assert log.num_ticks == TICKS and log.num_cavs == 2 and log.route_id == "mini_0"
    assert log.town.endswith("mini.net.xml") and log.dt == 0.05
    f32 = np.float32
    for k in (0, 1, COLLISION_TICK, REMOVE_CAV1_AT, TICKS - 1):
        want, got = recorded.snaps[k], log.snapshot(k)
        assert got.ids.tolist() == want.ids.tolist()
        assert got.step == want.step and got.time == want.time
        assert np.array_equal(got.x, want.x.astype(f32)) and np.array_equal(got.y, want.y.astype(f32))
        np.testing.assert_allclose(got.x, want.x, rtol=0, atol=1e-4)  # [m] float32 at |x| < 300 m
        assert np.array_equal(got.yaw, want.yaw.astype(f32)) and np.array_equal(
            got.speed, want.speed.astype(f32)
        )
        assert np.array_equal(got.kind, want.kind) and np.array_equal(got.role, want.role)
        assert np.array_equal(got.length, want.length.astype(f32)) and np.array_equal(
            got.signals, want.signals
        )
        assert got.tls_state.tolist() == want.tls_state.tolist()
        assert np.all(got.lane == -1) and np.all(got.accel == 0.0) and np.all(got.valid)
    assert {"a", "b"} <= set(log.snapshot(TICKS - 1).ids.tolist())
    assert log.snapshot(-1).step == recorded.snaps[-1].step


def test_controls_round_trip_with_nan_for_a_cav_that_left(recorded: Recorded, log: RouteLog) -> None:
    for k in (0, REMOVE_CAV1_AT - 1):
        got = log.controls(k)
        for name in ("steer", "throttle", "brake"):
            np.testing.assert_array_equal(
                getattr(got, name), getattr(recorded.controls[k], name).astype(np.float32)
            )
    after = log.controls(REMOVE_CAV1_AT)
    assert np.isfinite(after.throttle[0]) and np.isnan(after.throttle[1]) and np.isnan(after.steer[1])
    track = log.cav_xy(1)
    assert np.all(np.isnan(track[REMOVE_CAV1_AT:])) and np.all(np.isfinite(track[:REMOVE_CAV1_AT]))
    expected = np.array([xy[1] for xy in recorded.cav_xy])
    np.testing.assert_allclose(track[:REMOVE_CAV1_AT], expected[:REMOVE_CAV1_AT], atol=1e-4)


def test_events_and_routes_round_trip(recorded: Recorded, log: RouteLog) -> None:
    first, second = log.events
    c = recorded.cav_xy[COLLISION_TICK][0]
    assert first == {
        "tick": COLLISION_TICK,
        "cav": 0,
        "key": "collisions_vehicle",
        "x": c[0],
        "y": c[1],
        "message": "hit a",
    }
    assert second["key"] == "red_light" and second["tick"] == RED_LIGHT_TICK and second["time"] == 3.5
    assert (second["x"], second["y"], second["actor"]) == (195.0, -1.6, None)
    active = {k: [e["key"] for e in log.active_events(k)] for k in (19, 20, 69, 79, 80)}  # 3 s = 60 ticks
    assert active[19] == [] and active[20] == active[69] == ["collisions_vehicle"]
    assert active[79] == ["collisions_vehicle", "red_light"] and active[80] == ["red_light"]
    assert len(log.cav_routes) == 2 and log.cav_routes[0].shape[1] == 2
    assert log.cav_routes[0][0, 0] == pytest.approx(20.0, abs=1.0)


def test_replay_writes_one_gif_frame_per_rendered_tick(
    recorded: Recorded, mini: RoadMap, tmp_path: Path
) -> None:
    import imageio.v3 as iio
    from PIL import Image

    out = replay(
        recorded.path,
        tmp_path / "mini_0.gif",
        town_map=mini,
        follow=0,
        window=60.0,
        every=4,
        pixels_per_meter=3.0,
    )
    frames = iio.imread(out, index=None)
    assert frames.shape == (TICKS // 4, 180, 180, 3)
    with Image.open(out) as gif:  # Pillow merges identical consecutive frames: durations must add up
        durations = []
        for i in range(gif.n_frames):
            gif.seek(i)
            durations.append(gif.info["duration"])
    assert sum(durations) == pytest.approx(TICKS // 4 * 50, abs=TICKS // 4)  # [ms] at 20 fps


def test_replay_frame_marks_infractions_in_their_colours(log: RouteLog, mini: RoadMap) -> None:
    """The collision ring is red while the event is fresh (3 s), absent before it and after; the red-light
    ring is orange; the legend (top right, on every frame) names both marks. The frame at the collision is
    written to /tmp for a look."""
    renderer, centres = replay_renderer(log, mini, pixels_per_meter=4.0)
    assert centres is None
    at = render_replay_frame(log, renderer, COLLISION_TICK, title="mini_0")
    box = legend_box(at.shape[1], [e["key"] for e in log.events], renderer.font_px)
    assert box is not None

    def count(frame: np.ndarray, colour: tuple[int, int, int], legend: bool = False) -> int:
        """Pixels of ``colour`` outside the legend (``legend``: inside it)."""
        inside = np.zeros(frame.shape[:2], bool)
        inside[box[1] : box[3] + 1, box[0] : box[2] + 1] = True
        hit = np.all(frame == np.array(colour, np.uint8), axis=-1)
        return int((hit & (inside if legend else ~inside)).sum())

    before = render_replay_frame(log, renderer, COLLISION_TICK - 1)
    late = render_replay_frame(log, renderer, COLLISION_TICK + 60)
    assert count(at, COLLISION_COLOUR) > 100 and count(before, COLLISION_COLOUR) == 0
    assert count(late, COLLISION_COLOUR) == 0 and count(late, LIGHT_COLOUR) > 100
    for frame in (at, before, late):  # the legend: a row for collisions and one for the red light
        assert (
            count(frame, COLLISION_COLOUR, legend=True) > 20 and count(frame, LIGHT_COLOUR, legend=True) > 20
        )
        assert count(frame, SLOW_COLOUR, legend=True) == 0  # the log has no min-speed record
    from PIL import Image

    Image.fromarray(render_replay_frame(log, renderer, RED_LIGHT_TICK, title="mini_0")).save(
        Path("/tmp") / "cmudrive_replay_marker.png"
    )


def test_a_min_speed_record_is_a_too_slow_triangle_not_a_ring() -> None:
    """A min-speed record costs nothing: it is drawn as a light-blue triangle labelled "too slow", with no
    pixel of a ring colour, and the legend names it "too slow"; a collision at the same spot is a ring."""
    view = BevView(x_min=0.0, y_max=100.0, width=200, height=200, pixels_per_meter=2.0)
    blank = np.zeros((200, 200, 3), np.uint8)
    slow = {"tick": 0, "cav": 0, "key": "min_speed_infractions", "x": 50.0, "y": 50.0, "message": "80 %"}
    hit = dict(slow, key="collisions_vehicle")

    def pixels(frame: np.ndarray, colour: tuple[int, int, int]) -> np.ndarray:
        return np.all(frame == np.array(colour, np.uint8), axis=-1)

    slow_frame = draw_events(blank, view, [slow])
    hit_frame = draw_events(blank, view, [hit])
    assert SHORT_LABELS["min_speed_infractions"] == "too slow"
    assert pixels(slow_frame, SLOW_COLOUR).sum() > 30
    assert not any(pixels(slow_frame, c).any() for c in (COLLISION_COLOUR, LIGHT_COLOUR, OTHER_COLOUR))
    assert pixels(hit_frame, COLLISION_COLOUR).sum() > 30 and not pixels(hit_frame, SLOW_COLOUR).any()
    # the shapes differ: the ring's pixel at the centre's left (on the circle) is empty in the triangle
    r = 8  # [px] MARKER_MIN_RADIUS at 2 px/m (3 m ring = 6 px)
    ring_row = pixels(hit_frame, COLLISION_COLOUR)[100, 100 - r - 1 : 100 - r + 2]
    assert ring_row.any() and not pixels(slow_frame, SLOW_COLOUR)[100, 100 - r - 1 : 100 - r + 2].any()

    wide = np.zeros((200, 400, 3), np.uint8)
    legend = draw_legend(wide, ["min_speed_infractions", "collisions_vehicle"])
    box = legend_box(400, ["min_speed_infractions", "collisions_vehicle"])
    assert box is not None and box[2] <= 400 and box[0] > 200  # in the top-right corner
    assert pixels(legend, SLOW_COLOUR).any() and pixels(legend, COLLISION_COLOUR).any()
    assert not pixels(legend, LIGHT_COLOUR).any()
    assert legend_box(400, []) is None and draw_legend(wide, []) is wide


@pytest.mark.parametrize("damage", ["missing", "garbage", "truncated", "version", "field"])
def test_bad_log_raises_naming_the_file(recorded: Recorded, tmp_path: Path, damage: str) -> None:
    path = tmp_path / f"{damage}.npz"
    data = recorded.path.read_bytes()
    if damage == "garbage":
        path.write_bytes(b"not a log at all" * 10)
    elif damage == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif damage in ("version", "field"):
        with np.load(recorded.path) as npz:
            arrays = {k: npz[k] for k in npz.files}
        if damage == "version":
            arrays["header"] = np.array(str(arrays["header"]).replace('"version": 1', '"version": 99'))
        else:
            del arrays["tick_ptr"]
        np.savez_compressed(path, **arrays)
    match = {"version": "unsupported format version 99", "field": "tick_ptr", "missing": "does not exist"}
    with pytest.raises(RouteLogError, match=match.get(damage)) as err:
        load_route_log(path)
    assert str(path) in str(err.value)


def test_flipped_bytes_inside_the_zip_are_reported(recorded: Recorded, tmp_path: Path) -> None:
    path = tmp_path / "flipped.npz"
    data = bytearray(recorded.path.read_bytes())
    with zipfile.ZipFile(recorded.path) as z:
        info = z.getinfo("x.npy")
    at = info.header_offset + 30 + len(info.filename) + info.compress_size // 2
    data[at : at + 8] = bytes(8)
    path.write_bytes(bytes(data))
    with pytest.raises(RouteLogError, match=str(path)):
        load_route_log(path)


def test_save_is_atomic_and_replaces(tmp_path: Path) -> None:
    """Padding rows are not recorded; an id that comes back as another kind gets its own table row."""
    recorder = RouteRecorder("r", "mini", [np.zeros((2, 2))])
    for kind in (0, 5):
        snap = Snapshot.from_rows(
            1,
            0.05,
            np.array(["rG", ""]),
            ids=np.array(["cav0", "p", "pad"]),
            role=np.array([Role.CAV, Role.BACKGROUND, Role.BACKGROUND], np.int8),
            kind=np.array([0, kind, 0], np.int8),
            x=np.array([1.0, 2.0, 0.0]),
            y=np.array([2.0, 3.0, 0.0]),
            valid=np.array([True, True, False]),
        )
        recorder.record(snap, None, np.array([0]))
    target = tmp_path / "r.npz"
    target.write_bytes(b"old")
    assert recorder.save(target) == target
    assert os.listdir(tmp_path) == ["r.npz"]  # no temporary file left behind
    log = load_route_log(target)
    assert log.num_ticks == 2 and np.isnan(log.controls(0).steer[0])
    assert log.tls_state(1).tolist() == ["rG", ""]
    assert log.snapshot(0).ids.tolist() == log.snapshot(1).ids.tolist() == ["cav0", "p"]
    assert log.snapshot(1).kind.tolist() == [0, 5] and log.arrays["actor_id"].tolist() == ["cav0", "p", "p"]


def test_record_rejects_mismatched_controls_and_unknown_cavs() -> None:
    recorder = RouteRecorder("r", "mini", [np.zeros((2, 2))])
    snap = Snapshot.from_rows(
        1, 0.05, np.array([""]), ids=np.array(["cav0", "x"]), x=np.array([1.0, 2.0]), y=np.array([2.0, 3.0])
    )
    with pytest.raises(ValueError, match="route r, tick 0: steer has 2 values for 1 CAV rows"):
        recorder.record(snap, Controls.zeros(2), np.array([0]))
    with pytest.raises(ValueError, match="CAV ids look like 'cav0'"):
        recorder.record(snap, Controls.zeros(1), np.array([1]))
    with pytest.raises(ValueError, match="lacks"):
        recorder.add_events(0, [{"cav": 0, "key": "red_light"}])
    assert recorder.num_ticks == 0


def synthetic_snapshots(ticks: int, actors: int, seed: int = 0):
    """``actors`` vehicles driving smooth curves over a 1 km map; 1 % of them swapped for new ones every
    second (actors come and go), 16 of them CAVs."""
    rng = np.random.default_rng(seed)
    x0, y0 = rng.uniform(0.0, 1000.0, (2, actors))
    heading, speed = rng.uniform(-np.pi, np.pi, actors), rng.uniform(0.0, 15.0, actors)
    ids = np.array([f"cav{i}" if i < 16 else f"veh{i}" for i in range(actors)])
    role = np.where(np.arange(actors) < 16, Role.CAV, Role.BACKGROUND).astype(np.int8)
    tls = np.array(["GGrrGGrr", "rrGGrrGGyy"])
    next_id = actors
    for k in range(ticks):
        t = 0.05 * k
        if k % 20 == 0 and k:
            swap = rng.choice(np.arange(16, actors), max(1, actors // 100), replace=False)
            ids[swap] = [f"veh{next_id + j}" for j in range(len(swap))]
            next_id += len(swap)
        yaw = heading + 0.05 * np.sin(0.1 * t + heading)
        yield Snapshot.from_rows(
            k + 1,
            t + 0.05,
            tls,
            ids=ids.copy(),
            role=role,
            x=x0 + speed * t * np.cos(heading),
            y=y0 + speed * t * np.sin(heading),
            yaw=yaw,
            speed=speed + 0.5 * np.sin(t),
            signals=np.where(np.sin(t + heading) > 0.8, 8, 0).astype(np.int32),
        )


def test_a_4000_tick_200_actor_log_is_under_50_mb(tmp_path: Path) -> None:
    recorder = RouteRecorder("big", "downtown", [np.zeros((500, 2))] * 16)
    rows = np.arange(16)
    ctl = Controls(np.full(16, 0.1), np.full(16, 0.5), np.zeros(16))
    start = time.perf_counter()
    for snap in synthetic_snapshots(4000, 200):
        recorder.record(snap, ctl, rows)
    record_s = time.perf_counter() - start
    path = recorder.save(tmp_path / "big.npz")
    size = path.stat().st_size
    print(f"4000 ticks x 200 actors: {size / MB:.1f} MB on disk, recording {record_s:.2f} s")
    assert size < 50 * MB
    log = load_route_log(path)
    assert log.num_ticks == 4000 and log.snapshot(3999).num_actors == 200
    assert len(log.arrays["actor_id"]) == 200 + 199 * 2  # two new actors every 20 ticks


def test_a_town_without_traffic_lights_replays(tmp_path: Path) -> None:
    """CARLA's Town06 has no light at all: its logs read back with an empty light state (the replay of a
    Town06 route failed with "zip() argument 2 is shorter than argument 1")."""
    recorder = RouteRecorder("r", "Town06", [np.zeros((2, 2))])
    cav = {"ids": np.array(["cav0"]), "role": np.array([Role.CAV], np.int8)}
    snap = Snapshot.from_rows(1, 0.05, np.zeros(0, dtype=str), x=np.array([1.0]), y=np.array([2.0]), **cav)
    recorder.record(snap, None, np.array([0]))
    log = load_route_log(recorder.save(tmp_path / "r.npz"))
    assert log.tls_state(0).tolist() == [] and log.snapshot(0).ids.tolist() == ["cav0"]


def _damaged(recorded: Recorded, path: Path, **changes: object) -> Path:
    """The recorded log with some arrays replaced (a header dict is merged into the header)."""
    import json

    with np.load(recorded.path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    for name, value in changes.items():
        if name == "header":
            arrays["header"] = np.array(json.dumps({**json.loads(str(arrays["header"])), **value}))  # type: ignore[dict-item]
        elif name == "events":
            arrays["events"] = np.array([json.dumps(e) for e in value], dtype=str)  # type: ignore[attr-defined]
        else:
            arrays[name] = value  # type: ignore[assignment]
    np.savez_compressed(path, **arrays)  # type: ignore[arg-type]
    return path


GOOD_EVENT = {"tick": 3, "cav": 0, "key": "red_light", "x": 1.0, "y": 2.0, "message": "m"}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"header": {"dt": 0}}, r"header dt must be a number of seconds in \(0, 10\], got 0"),
        ({"header": {"dt": "fast"}}, "header dt must be a number of seconds"),
        ({"events": [{k: v for k, v in GOOD_EVENT.items() if k != "tick"}]}, r"event 0 lacks \['tick'\]"),
        (
            {"events": [GOOD_EVENT, {**GOOD_EVENT, "tick": "5"}]},
            "event 1: tick must be an integer in 0..99, got '5'",
        ),
        ({"events": [{**GOOD_EVENT, "cav": 99}]}, "event 0: cav must be an integer in 0..1, got 99"),
        ({"events": [{**GOOD_EVENT, "x": float("nan")}]}, "event 0: x must be a finite number"),
        ({"x": "nan"}, r"x is not finite in 1 rows \(first: row 7\)"),
        ({"actor_kind": "kind"}, r"actor_kind holds unknown values \[42\]"),
    ],
)
def test_a_log_the_replay_cannot_draw_is_refused_on_load(
    recorded: Recorded, tmp_path: Path, change: dict[str, object], message: str
) -> None:
    """dt = 0, an event without a tick or with a string tick ended in tracebacks mid-replay;
    NaN positions and events of CAV 99 were drawn as if they were data."""
    with np.load(recorded.path) as npz:
        if change.get("x") == "nan":
            x = npz["x"].copy()
            x[7] = np.nan
            change = {"x": x}
        elif change.get("actor_kind") == "kind":
            kind = npz["actor_kind"].copy()
            kind[0] = 42
            change = {"actor_kind": kind}
    path = _damaged(recorded, tmp_path / "bad.npz", **change)
    with pytest.raises(RouteLogError, match=message) as err:
        load_route_log(path)
    assert str(path) in str(err.value)
    with pytest.raises(RouteLogError, match=message):
        replay(path, tmp_path / "bad.gif")


def test_declared_sizes_are_checked_before_reading(
    recorded: Recorded, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A 5.9 MB log asked numpy for 5.59 GiB. A member whose .npy header declares more data than
    it holds, and a log whose members declare more than MAX_LOG_BYTES, are refused before np.load."""
    from cmudrive.bench import route_log

    bomb = tmp_path / "bomb.npz"
    with zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as archive:
        header = {"descr": "<f8", "fortran_order": False, "shape": (750_000_000,)}  # 6 GB of float64
        with archive.open("x.npy", "w") as member:
            np.lib.format.write_array_header_1_0(member, header)
            member.write(bytes(64))

    def no_load(*args: object, **kwargs: object) -> None:
        raise AssertionError("np.load ran on a log whose sizes were not checked")

    monkeypatch.setattr(route_log.np, "load", no_load)
    with pytest.raises(RouteLogError, match=r"bomb\.npz: member 'x\.npy' declares 6000000000 bytes"):
        load_route_log(bomb)
    monkeypatch.setattr(route_log, "MAX_LOG_BYTES", 1000)
    with pytest.raises(RouteLogError, match=r"mini_0\.npz declares 0\.\d+ GiB of data, more than the"):
        load_route_log(recorded.path)
