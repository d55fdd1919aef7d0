"""The committed benchmark route sets (cmudrive220, cmudrive44, training) and their generator."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cmudrive.agents import PidAgent
from cmudrive.bench import EvalConfig, evaluate_route
from cmudrive.bench.authoring.benchmark_gen import CAV_MEAN, PRESETS, SAME_PLACE, cav_counts, generate_set
from cmudrive.bench.authoring.route_gen import MIN_START_GAP
from cmudrive.bench.route_check import check_route_file, place_scenarios
from cmudrive.bench.routes import RouteSpec, read_routes
from cmudrive.bench.scenario_types import SCENARIO_TYPES
from cmudrive.cli import app
from cmudrive.maps import Route, load_map
from cmudrive.sim.background import BackgroundConfig

ROUTES = Path(__file__).resolve().parents[1] / "cmudrive" / "assets" / "routes"


@pytest.fixture(scope="module")
def sets() -> dict[str, list[RouteSpec]]:
    return {name: read_routes(ROUTES / f"{name}.xml") for name in ("cmudrive220", "cmudrive44", "training")}


@pytest.fixture(scope="module")
def dense(sets: dict[str, list[RouteSpec]]) -> dict[str, list[Route]]:
    """Every CAV's dense route of cmudrive220 and training, by route id."""
    out = {}
    for name in ("cmudrive220", "training"):
        for spec in sets[name]:
            out[spec.id] = spec.dense_routes(load_map(spec.town_path()))
    return out


def _type(spec: RouteSpec) -> str:
    return spec.scenarios[0].type


def test_sizes_types_and_weathers(sets: dict[str, list[RouteSpec]]) -> None:
    for name, per_type in (("cmudrive220", 5), ("cmudrive44", 1), ("training", 3)):
        specs = sets[name]
        assert len(specs) == 44 * per_type
        assert all(len(s.scenarios) == 1 for s in specs)
        types = [_type(s) for s in specs]
        assert {t: types.count(t) for t in SCENARIO_TYPES} == dict.fromkeys(SCENARIO_TYPES, per_type)
    weathers = [s.weather for s in sets["cmudrive220"]]
    assert {w: weathers.count(w) for w in PRESETS} == dict.fromkeys(PRESETS, 44)
    for t in SCENARIO_TYPES:  # the five routes of a type: five presets
        assert sorted(s.weather for s in sets["cmudrive220"] if _type(s) == t) == sorted(PRESETS)


def test_cav_counts_match_table_1(sets: dict[str, list[RouteSpec]]) -> None:
    n = np.array([len(s.cavs) for s in sets["cmudrive220"]])
    assert n.min() == 2 and n.max() == 16
    assert abs(n.mean() - 6.56) < 0.005
    for size, seed in ((220, 0), (132, 1), (40, 3)):
        c = cav_counts(size, seed)
        assert c.min() == 2 and c.max() == 16 and abs(c.mean() - CAV_MEAN) < 0.5 / size + 1e-12


def test_places_differ_within_a_type(sets: dict[str, list[RouteSpec]]) -> None:
    """The five routes of a type are on different towns or at triggers far apart."""
    for t in SCENARIO_TYPES:
        routes = [s for s in sets["cmudrive220"] if _type(s) == t]
        for i, a in enumerate(routes):
            for b in routes[i + 1 :]:
                if a.town == b.town:
                    xa, ya, _ = a.scenarios[0].map_trigger()
                    xb, yb, _ = b.scenarios[0].map_trigger()
                    assert math.hypot(xa - xb, ya - yb) >= SAME_PLACE, (a.id, b.id)


def test_mini_split_is_part_of_the_benchmark(sets: dict[str, list[RouteSpec]]) -> None:
    full = {s.id: s for s in sets["cmudrive220"]}
    for spec in sets["cmudrive44"]:
        assert full[spec.id] == spec
    assert len({s.town for s in sets["cmudrive44"]}) >= 8  # spread over towns, not the first town of each


def test_cav0_routes_and_triggers(sets: dict[str, list[RouteSpec]], dense: dict[str, list[Route]]) -> None:
    for name in ("cmudrive220", "training"):
        for spec in sets[name]:
            r0 = dense[spec.id][0]
            assert 50.0 <= r0.length <= 220.0, (spec.id, r0.length)
            x, y, _ = spec.scenarios[0].map_trigger()
            gap = np.hypot(r0.xy[:, 0] - x, r0.xy[:, 1] - y)
            assert gap.min() < 1.0, spec.id
            assert r0.distance[int(np.argmin(gap))] <= 35.0, spec.id  # in the first part of the route


def test_no_overlapping_spawns(sets: dict[str, list[RouteSpec]], dense: dict[str, list[Route]]) -> None:
    """Start boxes (4.9 x 2.1 m cars at the start pose) of two CAVs never overlap: their centres are at
    least MIN_START_GAP apart, more than a box diagonal."""
    assert MIN_START_GAP > math.hypot(4.9, 2.1)
    for name in ("cmudrive220", "training"):
        for spec in sets[name]:
            starts = np.array([r.xy[0] for r in dense[spec.id]])
            d = np.linalg.norm(starts[:, None] - starts[None], axis=2) + np.eye(len(starts)) * 1e9
            assert d.min() >= MIN_START_GAP - 0.01, (spec.id, d.min())


def test_training_is_disjoint_from_the_benchmark(sets: dict[str, list[RouteSpec]]) -> None:
    bench = sets["cmudrive220"]
    bench_ids = {s.id for s in bench}
    for spec in sets["training"]:
        assert spec.id not in bench_ids
        x, y, _ = spec.scenarios[0].map_trigger()
        for other in bench:
            assert not np.array_equal(spec.cavs[0].waypoints, other.cavs[0].waypoints)
            if other.town == spec.town and _type(other) == _type(spec):
                ox, oy, _ = other.scenarios[0].map_trigger()
                assert math.hypot(x - ox, y - oy) >= SAME_PLACE, (spec.id, other.id)


@pytest.mark.parametrize("name", ["cmudrive220", "cmudrive44", "training"])
def test_every_route_checks_and_places(name: str) -> None:
    """``cmudrive routes check`` passes: towns, planning, triggers and scenario placement, and no route
    breaks a placement rule (``route_rules``: the generator rejects a layout that does)."""
    checks = check_route_file(ROUTES / f"{name}.xml")
    assert [c.problem for c in checks if c.problem] == []
    assert [(c.route_id, r.rule) for c in checks for r in c.rules] == []


def test_check_reports_a_scenario_that_does_not_place(sets: dict[str, list[RouteSpec]]) -> None:
    spec = next(s for s in sets["cmudrive220"] if _type(s) == "Accident")
    sc = spec.scenarios[0]
    far = dataclasses.replace(
        spec, scenarios=(dataclasses.replace(sc, params={**sc.params, "distance": "390"}),)
    )
    m = load_map(spec.town_path())
    problem = place_scenarios(far, m, far.dense_routes(m))
    assert problem is not None and "Accident_1" in problem
    assert place_scenarios(spec, m, spec.dense_routes(m)) is None


def test_generation_is_deterministic_and_matches_the_committed_file(sets: dict[str, list[RouteSpec]]) -> None:
    types = ["Accident", "SignalizedJunctionLeftTurn", "HighwayCutIn", "CrossingBicycleFlow"]
    a = generate_set("cmudrive220", types)
    b = generate_set("cmudrive220", types)
    assert a == b
    committed = [s for s in sets["cmudrive220"] if _type(s) in types]
    assert sorted(a, key=lambda s: s.id) == sorted(committed, key=lambda s: s.id)


def test_stats_command_prints_table_1() -> None:
    result = CliRunner().invoke(app, ["routes", "stats", "cmudrive220"])
    assert result.exit_code == 0, result.output
    assert "220" in result.output and "6.56" in result.output and "ClearNight" in result.output
    assert "Town03" in result.output and "downtown" in result.output


@pytest.mark.slow
def test_mini_split_routes_run_with_the_pid_agent(sets: dict[str, list[RouteSpec]]) -> None:
    """A junction-flow route and an obstacle route of cmudrive44 run 300 ticks without a crash."""
    picks = [s for s in sets["cmudrive44"] if _type(s) in ("SignalizedJunctionLeftTurn", "Accident")]
    config = EvalConfig(tick_cap=300, background=BackgroundConfig(vehicles=10, pedestrians=5))
    for spec in picks:
        result = evaluate_route(spec, PidAgent, config)
        assert result.error is None, (spec.id, result.error)


def test_layouts_the_rules_ask_for(sets: dict[str, list[RouteSpec]], dense: dict[str, list[Route]]) -> None:
    """SequentialLaneChange routes move two lanes left; stop-sign turns approach a stop line; the
    CrossingBicycleFlow source lies on a bike lane."""
    from cmudrive.maps.model import LaneKind
    from cmudrive.maps.routing import RoadOption

    for spec in sets["cmudrive220"]:
        r0, t = dense[spec.id][0], _type(spec)
        m = load_map(spec.town_path())
        if t == "SequentialLaneChange":
            change = r0.option == RoadOption.CHANGELANELEFT
            assert int(np.sum(change[1:] & ~change[:-1]) + change[0]) >= 2, spec.id
        elif t == "VanillaNonSignalizedTurnEncounterStopsign":
            first = int(np.flatnonzero(r0.in_junction)[0])
            out = first + int(np.flatnonzero(~r0.in_junction[first:])[0])
            links = (m.link_from == r0.lane[first - 1]) & (m.link_to == r0.lane[out])
            assert set(m.link_state[links].tolist()) <= {"s", "w"} and links.any(), spec.id
        elif t == "CrossingBicycleFlow":
            p = spec.scenarios[0].params["start_actor_flow"]
            assert isinstance(p, dict)
            xy = np.array([[float(p["x"]), -float(p["y"])]])
            bike = np.flatnonzero(m.lane_kind == LaneKind.BIKE)
            _, d = m.index.project(np.repeat(xy, len(bike), axis=0), bike)
            assert np.min(np.abs(d)) < 1.0, spec.id
