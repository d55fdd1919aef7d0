"""The scenario engine: parameters with units and errors, activation on CAV 0's route, the 240 s timeout
(charged to CAV 0, the scenario's ego; the blocked test suspended meanwhile for every CAV whose route
passes the trigger), bad input that names the route, scenario and parameter while the other routes run."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from cmudrive.agents import PidAgent
from cmudrive.bench import EvalConfig, LocalExecutor, RouteSpec, evaluate_route, run_evaluation
from cmudrive.bench.criteria import CriteriaConfig
from cmudrive.bench.evaluator import RouteInputError
from cmudrive.bench.records import STATUS_BLOCKED, STATUS_INVALID_ROUTE, STATUS_SIM_CRASHED
from cmudrive.bench.routes import ScenarioSpec
from cmudrive.bench.runner import InvalidRoutesError
from cmudrive.bench.scenarios import Param, ScenarioConfig, ScenarioError
from cmudrive.bench.scenarios.params import DIRECTION, parse_params
from tests.scenario_helpers import EMPTY, StopsAt, interurban, lane_cav, run, scenario, trigger

PARAMS = (
    Param("distance", "m", 120.0, lo=5.0, hi=400.0),
    Param("speed", "km/h", 60.0, lo=0.0, hi=130.0),
    Param("frequency", "m", (20.0, 100.0), lo=0.0, hi=1000.0, is_range=True),
    DIRECTION,
)


def spec_with(**params: object) -> ScenarioSpec:
    return ScenarioSpec("S1", "Accident", (0.0, 0.0, 0.0, 0.0), params)  # type: ignore[arg-type]


def test_parameters_take_defaults_and_parse_in_their_units() -> None:
    p = parse_params(spec_with(distance="40", frequency={"from": "30", "to": "90"}), "r", PARAMS)
    assert p == {"distance": 40.0, "speed": 60.0, "frequency": (30.0, 90.0), "direction": "right"}


@pytest.mark.parametrize(
    ("params", "words"),
    [
        ({"colour": "red"}, ["unknown parameter 'colour'", "allowed: direction, distance"]),
        ({"distance": "2"}, ["parameter 'distance' [m]", "outside [5, 400]"]),
        ({"speed": "fast"}, ["parameter 'speed' [km/h]", "'fast' is not a number"]),
        ({"distance": "nan"}, ["parameter 'distance'", "not a finite number"]),
        ({"direction": "up"}, ["parameter 'direction'", "not one of right, left"]),
        ({"frequency": {"from": "90", "to": "30"}}, ["parameter 'frequency'", "larger than 'to'"]),
        ({"frequency": "50"}, ["parameter 'frequency'", "expected <frequency from=... to=.../>"]),
    ],
)
def test_bad_parameters_name_route_scenario_and_parameter(params: dict, words: list[str]) -> None:
    with pytest.raises(ScenarioError) as err:
        parse_params(spec_with(**params), "route_7", PARAMS)
    text = str(err.value)
    assert text.startswith("route 'route_7', scenario 'S1': ")
    for w in words:
        assert w in text


def ring_spec(
    route_id: str, kind: str = "Accident", trigger_lane: str = "R1a-R2a_0", **params: str
) -> RouteSpec:
    """CAV 0 on the right lane of interurban's ring road (s 20 -> 230 m), CAV 1 on the left lane; the
    scenario triggers 20 m after CAV 0's start."""
    m = interurban()
    cavs = (lane_cav(m, 0, "R1a-R2a_0", 20.0, 230.0), lane_cav(m, 1, "R1a-R2a_1", 20.0, 230.0))
    return RouteSpec(
        route_id,
        "interurban",
        "ClearNoon",
        0,
        cavs,
        (scenario(kind, trigger(m, trigger_lane, 40.0), **params),),
    )


@pytest.mark.parametrize(
    ("route_id", "kwargs", "words"),
    [
        ("off_route", {"trigger_lane": "R1a-R2a_1"}, ["trigger point", "from CAV 0's route"]),
        ("bad_param", {"distance": "1000"}, ["parameter 'distance' [m]", "outside"]),
        ("unknown", {"lenght": "40"}, ["unknown parameter 'lenght'"]),
        ("no_place", {"distance": "40", "direction": "left"}, ["no place for the scenario", "on its right"]),
        ("junction", {"distance": "400"}, ["no place for the end point", "junction"]),
    ],
)
def test_bad_scenario_input_is_a_route_input_error(route_id: str, kwargs: dict, words: list[str]) -> None:
    with pytest.raises(RouteInputError) as err:
        evaluate_route(ring_spec(route_id, **kwargs), PidAgent, EvalConfig(background=EMPTY, tick_cap=5))
    text = str(err.value)
    assert f"route {route_id!r}, scenario 'S1'" in text
    for w in words:
        assert w in text


def test_a_bad_scenario_refuses_the_run_or_is_skipped_without_stopping_the_other_routes(
    tmp_path: Path,
) -> None:
    """A scenario parameter out of range is the route's fault, found before any route runs: the run is
    refused naming it, or, with skip_invalid, the route is recorded invalid and the others run."""
    routes = [ring_spec("bad", distance="1000"), ring_spec("good", distance="40")]
    config = EvalConfig(background=EMPTY, tick_cap=200)
    with pytest.raises(InvalidRoutesError, match=r"route 'bad', scenario 'S1'.*'distance'"):
        run_evaluation(routes, PidAgent, tmp_path / "refused", LocalExecutor(1), config)
    merged = run_evaluation(routes, PidAgent, tmp_path, LocalExecutor(1), config, skip_invalid=True)
    by_id = {r["route_id"]: r for r in merged["routes"]}
    assert by_id["bad"]["status"] == STATUS_INVALID_ROUTE
    assert "scenario 'S1'" in by_id["bad"]["error"] and "'distance'" in by_id["bad"]["error"]
    assert by_id["good"]["status"] != STATUS_SIM_CRASHED and by_id["good"]["scenario_simulated"] is True


def test_unimplemented_types_are_reported_not_simulated(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A type without behaviour (every type has one now: one is taken out of the registry) still runs."""
    from cmudrive.bench.scenarios import REGISTRY

    monkeypatch.delitem(REGISTRY, "CrossingBicycleFlow")
    result, _ = run(
        ring_spec("vanilla", kind="CrossingBicycleFlow"),
        tmp_path,
        config=EvalConfig(background=EMPTY, tick_cap=40),
    )
    assert result.scenario_simulated is False


def test_scenario_timeout_is_charged_to_cav_0_and_suspends_blocked_on_the_trigger(tmp_path: Path) -> None:
    """CAV 0 and CAV 2 (both through the trigger) stop before the accident and never pass it: after the
    scenario's timeout (10 s here) CAV 0, the scenario's ego, gets scenario_timeouts (x0.7); CAV 2 and
    CAV 1 (on the other lane) do not. The blocked test (5 s here) of CAVs 0 and 2 is suspended while the
    timeout runs, so they only get blocked 5 s after it expired."""
    m = interurban()
    cavs = (
        lane_cav(m, 0, "R1a-R2a_0", 20.0, 230.0),
        lane_cav(m, 1, "R1a-R2a_1", 20.0, 230.0),
        lane_cav(m, 2, "R1a-R2a_0", 5.0, 230.0),
    )
    spec = RouteSpec(
        "timeout",
        "interurban",
        "ClearNoon",
        0,
        cavs,
        (scenario("Accident", trigger(m, "R1a-R2a_0", 25.0), distance="60"),),
    )
    config = EvalConfig(
        background=EMPTY,
        tick_cap=700,
        criteria=replace(CriteriaConfig(), blocked_time=5.0),
        scenarios=ScenarioConfig(timeout=10.0),
    )
    result, log = run(spec, tmp_path, StopsAt, config)
    timeouts = [c.infractions["scenario_timeouts"] for c in result.cavs]
    assert [len(t) for t in timeouts] == [1, 0, 0]
    t_out = timeouts[0][0].time
    assert timeouts[0][0].factor == 0.7 and "timed out after 10 s" in timeouts[0][0].message
    assert 10.5 < t_out < 16.0  # activation when CAV 0 is 2 m short of s = 25 m (~1.2 s), + 10 s
    for i in (0, 2):
        assert result.cavs[i].status == STATUS_BLOCKED
        blocked = result.cavs[i].infractions["vehicle_blocked"][0].time
        assert t_out + 5.0 <= blocked < t_out + 6.0  # not at stop time + 5 s (~9-10 s)
    # CAV 1 is not affected: its blocked test was never suspended, it was blocked 5 s after stopping
    assert result.cavs[1].status == STATUS_BLOCKED
    assert result.cavs[1].infractions["vehicle_blocked"][0].time < t_out
    # the accident is cleared when the scenario ends
    assert "S1:police" not in set(log.snapshot(log.num_ticks - 1).ids.tolist())
