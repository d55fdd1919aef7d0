"""The row contract: the closed-loop V2V-VLA agent builds, from the same state, the very rows that data
collection stores (target points, other CAVs, speed, BEV image, camera, prompt), on a committed smoke route
driven by the expert with collection on, traffic and pedestrians included."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, cast

import numpy as np
import pytest

from cmudrive.agents.base import Observations, RouteSetup, load_agent_class
from cmudrive.agents.expert import ExpertAgent
from cmudrive.bench.callbacks import RouteCallback, RouteStart, Step
from cmudrive.bench.evaluator import EvalConfig, evaluate_route
from cmudrive.bench.observe import ObservationBuilder
from cmudrive.bench.records import STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED
from cmudrive.bench.routes import read_routes
from cmudrive.data.collector import SAMPLE_EVERY, RouteInfo, RowCollector
from cmudrive.data.schema import features, pack_occupancy
from cmudrive.data.shards import ShardWriter, load_shards
from cmudrive.maps import load_scenery
from cmudrive.sim.weather import get_weather

ROUTES = Path(__file__).resolve().parents[1] / "cmudrive" / "assets" / "routes"
ROUTE = "smoke_01"  # downtown, 2 CAVs, rain: turns (target points move on), traffic, pedestrians
TICKS = 300


class Twin(RouteCallback):
    """Beside the collector, the closed-loop agent (no model) gets every tick the observations the
    evaluator would give it, from the same snapshot, and builds its rows, kept for the sample ticks."""

    def __init__(self, seed: int) -> None:
        self.seed = seed
        self.agent_rows: dict[tuple[int, int], tuple[dict[str, Any], np.ndarray]] = {}

    def on_route_start(self, start: RouteStart) -> None:
        route = start.setup
        self.v2v: Any = cast(Any, load_agent_class("v2v-vla")())
        self.v2v.model = object()  # rows only: no checkpoint is loaded
        plans = tuple(replace(c, dense_route=None) for c in route.cavs)  # what a non-privileged agent gets
        self.v2v.setup(RouteSetup(route.route_id, route.town, route.weather, route.dt, plans))
        assert route.road_map is not None
        self.agent_observer = ObservationBuilder(
            type(self.v2v).observations,
            len(route.cavs),
            get_weather(route.weather),
            load_scenery(route.road_map),
            rng=np.random.default_rng([self.seed, 1]),  # as the evaluator seeds its sensors
            road_map=route.road_map,
        )

    def on_step(self, step: Step) -> None:
        seen = self.agent_observer.build(
            step.snapshot, step.tick, step.rows, step.cav_index, privileged=False
        )
        built = self.v2v.rows(seen)
        assert seen.merged_occupancy is not None
        if step.tick % SAMPLE_EVERY == 0:
            for a, k in enumerate(step.cav_index):
                self.agent_rows[(int(k), step.tick)] = (built[a], pack_occupancy(seen.merged_occupancy[a]))


@pytest.fixture(scope="module")
def collected(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, dict[tuple[int, int], Any]]:
    spec = next(s for s in read_routes(ROUTES / "smoke.xml") if s.id == ROUTE)
    out = tmp_path_factory.mktemp("rows")
    writer = ShardWriter(out, spec.id, features().arrow_schema)
    info = RouteInfo(spec.id, "", spec.weather, spec.town, len(spec.cavs))
    twin = Twin(spec.seed)
    callbacks = [RowCollector(info, writer, seed=spec.seed), twin]
    result = evaluate_route(spec, ExpertAgent, EvalConfig(tick_cap=TICKS), callbacks=callbacks)
    assert result.status not in (STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED), result.error
    return load_shards(out), twin.agent_rows


def test_the_agent_builds_the_rows_collection_stores(collected: tuple[Any, dict]) -> None:
    ds, agent_rows = collected
    assert len(ds) == len(agent_rows) == 2 * (TICKS // 5)
    moved = 0
    for i in range(len(ds)):
        stored = ds[i]
        row, merged = agent_rows[(stored["cav"], stored["tick"])]
        where = f"CAV {stored['cav']} tick {stored['tick']}"
        # the sensors: the agent's merged occupancy is the stored one
        assert np.array_equal(merged, np.asarray(stored["merged_occupancy"], np.uint8)), where
        target = np.asarray(stored["target_points"], np.float32)
        assert np.array_equal(np.asarray(row["target_points"], np.float32), target), (
            where,
            row["target_points"],
            target,
        )
        moved += int(target[0, 0] < 15.0)  # a target point close ahead: the next one comes soon
        assert row["other_cavs"] == stored["other_cavs"], where
        assert row["speed"] == stored["speed"], where
        assert np.array_equal(
            np.asarray(row["merged_bev"]), np.asarray(stored["merged_bev"].convert("RGB"))
        ), where
        camera = np.asarray(stored["camera"].convert("RGB"))
        assert np.array_equal(np.asarray(row["camera"]), camera), (
            where,
            np.abs(np.asarray(row["camera"], np.int16) - camera).mean(),
        )
    assert moved > 0  # the route reaches target points, so their hand-over is compared too


def test_training_derives_the_standing_time_the_closed_loop_counts(collected: tuple[Any, dict]) -> None:
    """Training derives ``standing`` from the stored 4 Hz rows, the closed loop counts it every tick: the
    same where the CAV moves (-1), at most one sample interval (0.25 s) apart where it stands."""
    from cmudrive.model.row import MOVING, standing_seconds

    ds, agent_rows = collected
    derived = standing_seconds(
        np.asarray(ds["route_id"]), np.asarray(ds["cav"]), np.asarray(ds["time"]), np.asarray(ds["speed"])
    )
    keys = zip(ds["cav"], ds["tick"], strict=True)
    counted = np.array([agent_rows[(c, t)][0]["standing"] for c, t in keys])
    moving = derived == MOVING
    assert np.array_equal(counted == MOVING, moving)
    assert (~moving).sum() >= 2  # both CAVs stand at the start: the standing rows are compared too
    lag = counted[~moving] - derived[~moving]
    assert lag.min() >= -1e-6 and lag.max() < 0.25 + 1e-6, lag


def test_the_prompt_and_pixels_the_model_reads_are_the_same(collected: tuple[Any, dict]) -> None:
    pytest.importorskip("transformers", reason="the processor's tokenizer needs the 'model' extra")
    from cmudrive.model import get_config
    from cmudrive.model.processor import VLAProcessor
    from cmudrive.model.row import standing_seconds

    ds, agent_rows = collected
    standing = standing_seconds(
        np.asarray(ds["route_id"]), np.asarray(ds["cav"]), np.asarray(ds["time"]), np.asarray(ds["speed"])
    )
    processor = VLAProcessor.from_config(get_config("tiny"))
    for i in range(0, len(ds), 7):
        stored = ds[i] | {"standing": float(standing[i])}
        row, _ = agent_rows[(stored["cav"], stored["tick"])]
        assert processor.prompt(row) == processor.prompt(stored)
        assert np.array_equal(processor.pixel_values(row), processor.pixel_values(stored))


def test_the_stored_columns_decode_to_the_model_rows() -> None:
    """Without a route: what the collector stores, decoded as training decodes it, is what the closed loop
    feeds the model (camera through JPEG, BEV through the palette PNG, float32 numbers)."""
    from cmudrive.agents.base import CavPlan
    from cmudrive.model.row import RowBuilder
    from cmudrive.sensors.occupancy import occupancy_to_rgb

    rng = np.random.default_rng(0)
    plan = CavPlan("cav", np.array([[0.0, 0.0], [50.0, 0.0], [50.0, 50.0]]), np.zeros(3, np.int8), np.ones(3))
    builder = RowBuilder((plan, plan, plan))
    camera = np.repeat(np.linspace(0, 255, 256, dtype=np.uint8)[None, None, :, None], 128, 1)
    camera = np.repeat(np.repeat(camera, 3, 3), 2, 0)
    camera[:, 60:80, 100:140] = rng.integers(0, 256, (2, 20, 40, 3))  # edges: JPEG changes them
    grid = rng.random((2, 4, 192, 128)) < 0.05
    relative = np.full((2, 3, 3), np.nan)
    relative[0, 2], relative[1, 0] = (10.123456789, -2.5, 0.1), (-10.1, 2.5, -0.1)
    obs = Observations(
        tick=3, time=0.15, cav_index=np.array([0, 2]), x=np.array([20.0, 48.0]), y=np.zeros(2),
        yaw=np.array([0.0, np.pi / 2]), speed=np.array([4.123456789, 0.0]), accel=np.zeros(2),
        other_cavs=relative, camera=camera, merged_occupancy=grid,
    )  # fmt: skip
    inputs = builder.inputs(obs, grid)
    stored, rows = builder.stored(inputs), builder.model_rows(inputs)
    spec = features()  # the shards' features decode the images, as training reads them
    for a in range(2):
        assert np.array_equal(
            rows[a]["camera"], np.asarray(spec["camera"].decode_example(stored["camera"][a]))
        )
        assert np.array_equal(
            rows[a]["merged_bev"], np.asarray(spec["merged_bev"].decode_example(stored["merged_bev"][a]))
        )
        assert rows[a]["other_cavs"] == stored["other_cavs"][a] and rows[a]["speed"] == stored["speed"][a]
    assert np.array_equal(rows[0]["merged_bev"], occupancy_to_rgb(grid)[0])  # one palette
    assert not np.array_equal(rows[0]["camera"], camera[0])  # JPEG in closed loop, as in training
    assert np.array_equal(builder.model_rows(inputs, jpeg=False)[0]["camera"], camera[0])
    assert rows[0]["other_cavs"] == [[2.0, float(np.float32(10.123456789)), -2.5, float(np.float32(0.1))]]
    assert rows[0]["speed"] == float(np.float32(4.123456789))
    # CAV 0 at x = 20 on the first leg: (50, 0) and (50, 50) ahead; CAV 2 at (48, 0) heading north: the
    # corner is 2 m away (reached), so (50, 50) twice, 50 m ahead and 2 m to the right
    np.testing.assert_allclose(rows[0]["target_points"], [[30.0, 0.0], [30.0, 50.0]], atol=1e-5)
    np.testing.assert_allclose(rows[1]["target_points"], [[50.0, -2.0], [50.0, -2.0]], atol=1e-5)
    assert builder.target_points(obs) is inputs.target_points  # once per tick: the same answer again
    with pytest.raises(ValueError, match="other CAVs"):
        builder.target_points(replace(obs, cav_index=np.array([0, 1])))


def test_the_standing_clock_counts_from_the_first_tick_below_a_tenth_of_a_metre_per_second() -> None:
    """CAV 0 brakes to a stand at 2.0 s and drives off at 5.0 s; CAV 1 drives on. The clock counts every
    tick; the derivation from 4 Hz rows of the same drive starts at the first standing row."""
    from cmudrive.model.row import MOVING, StandingClock, standing_seconds

    dt = 0.05
    times = np.arange(0, 121) * dt  # 0 .. 6 s
    speed0 = np.where((times >= 2.0 - 1e-9) & (times < 5.0 - 1e-9), 0.05, 3.0)
    clock = StandingClock(2)
    both = np.array([0, 1])
    drive = zip(times, speed0, strict=True)
    counted = np.array([clock.update(both, t, np.array([v, 8.0])) for t, v in drive])
    assert counted[times.searchsorted(1.95), 0] == MOVING
    assert counted[times.searchsorted(4.6 - 1e-9), 0] == pytest.approx(2.6, abs=1e-6)
    assert counted[times.searchsorted(5.0 - 1e-9), 0] == MOVING  # it drives off: the clock is reset
    assert (counted[:, 1] == MOVING).all()
    sampled = np.arange(3, 121, 5)  # the collector's rows every 5th tick, from an offset: 0.15, 0.4, ...
    rows_cav = np.repeat([0, 1], len(sampled))
    rows_t = np.tile(times[sampled], 2)
    rows_v = np.concatenate([speed0[sampled], np.full(len(sampled), 8.0)])
    order = np.random.default_rng(0).permutation(len(rows_cav))  # any order of rows
    derived = np.empty(len(order), np.float32)
    derived[order] = standing_seconds(np.full(len(order), "r"), rows_cav[order], rows_t[order], rows_v[order])
    first = sampled[times[sampled] >= 2.0][0]  # the first standing row: 2.15 s
    at = np.flatnonzero(sampled == first + 50)[0]  # 2.5 s later
    assert derived[at] == pytest.approx(2.5, abs=1e-6)
    assert counted[first + 50, 0] - derived[at] == pytest.approx(0.15, abs=1e-6)  # within one interval
    assert (derived[len(sampled) :] == MOVING).all()
