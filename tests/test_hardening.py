"""The evaluator against hostile but fair input: hung and dying agents, odd route ids, reused output
folders, malformed numbers and nonsense routes. Each case is one that stopped or misled a run before."""

from __future__ import annotations

import json
import os
import signal
import stat
import time
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
from typer.testing import CliRunner

from cmudrive.agents import Agent, Observations, PidAgent, RouteSetup
from cmudrive.bench import EvalConfig, LocalExecutor, RouteSpec, evaluate_route, run_evaluation
from cmudrive.bench.evaluator import AgentCrash
from cmudrive.bench.records import STATUS_AGENT_CRASHED, record_stem
from cmudrive.bench.route_check import check_route_file
from cmudrive.bench.routes import RouteSpecError, read_routes, write_routes
from cmudrive.bench.runner import OutputFolderError, RouteTask, run_task
from cmudrive.cli import app
from cmudrive.maps import RouteError, load_map
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.dynamics import Controls

from .test_evaluator import ring_route

EMPTY = BackgroundConfig(vehicles=0, pedestrians=0)
QUICK = EvalConfig(background=EMPTY, tick_cap=120, step_timeout=1.0)


class HangsInNativeCode(PidAgent):
    """At tick 30, blocks SIGALRM and sleeps: no in-process timeout can reach it (like a C loop)."""

    def run_step(self, obs: Observations) -> Controls:
        if obs.tick == 30:
            signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGALRM])
            time.sleep(120.0)
        return super().run_step(obs)


class SwallowsExceptions(PidAgent):
    def run_step(self, obs: Observations) -> Controls:
        try:
            if obs.tick == 3:
                time.sleep(5.0)
        except Exception:  # the point of this agent
            pass
        return super().run_step(obs)


class ExitsAtTick30(PidAgent):
    def run_step(self, obs: Observations) -> Controls:
        if obs.tick == 30:
            os._exit(3)
        return super().run_step(obs)


class RaisesBase(PidAgent):
    error: ClassVar[type[BaseException]] = SystemExit

    def run_step(self, obs: Observations) -> Controls:
        if obs.tick == 5:
            raise self.error("agent gave up")
        return super().run_step(obs)


class Interrupted(RaisesBase):
    error = KeyboardInterrupt


class SetupFails(PidAgent):
    def setup(self, route: RouteSetup) -> None:
        raise RuntimeError("weights not found")


class ConstructorFails(PidAgent):
    def __init__(self) -> None:
        raise RuntimeError("no GPU")


class Greedy(PidAgent):
    def run_step(self, obs: Observations) -> Controls:
        if obs.tick == 5:
            self.hoard = np.ones(2**30)  # 8 GiB
        return super().run_step(obs)


def _run(tmp_path: Path, agent: type[Agent], routes: list[RouteSpec] | None = None, **kw: object) -> dict:
    return run_evaluation(routes or [ring_route()], f"{__name__}:{agent.__name__}", tmp_path,
                          LocalExecutor(1), QUICK, **kw)  # type: ignore[arg-type]  # fmt: skip


# ---- 1 and 5: hung and dying agents --------------------------------------------------------------


def test_agent_hung_in_native_code_is_killed_and_keeps_its_scores(tmp_path: Path) -> None:
    started = time.monotonic()
    merged = _run(tmp_path, HangsInNativeCode)
    (route,) = merged["routes"]
    assert time.monotonic() - started < 100.0  # killed after 1 s + 5 s grace, not after the 120 s sleep
    assert route["status"] == STATUS_AGENT_CRASHED and "run_step made no progress" in route["error"]
    assert [c["status"] for c in route["cavs"]] == [STATUS_AGENT_CRASHED] * 2
    assert route["ticks"] >= 20 and route["route_completion"] > 0.0  # the scores sent before the hang


def test_step_timeout_cannot_be_swallowed_by_the_agent() -> None:
    result = evaluate_route(ring_route(), SwallowsExceptions, QUICK)
    assert result.status == STATUS_AGENT_CRASHED and "longer than 1.0 s at tick 3" in (result.error or "")


def test_agent_exiting_its_process_is_an_agent_crash_with_scores(tmp_path: Path) -> None:
    (route,) = _run(tmp_path, ExitsAtTick30)["routes"]
    assert route["status"] == STATUS_AGENT_CRASHED and "exit code 3" in route["error"]
    assert route["ticks"] >= 20 and route["route_completion"] > 0.0


@pytest.mark.parametrize("agent", [RaisesBase, Interrupted, SetupFails])
def test_every_agent_fault_is_an_agent_crash(agent: type[Agent]) -> None:
    result = evaluate_route(ring_route(), agent, QUICK)
    assert result.status == STATUS_AGENT_CRASHED
    assert all(c.status == STATUS_AGENT_CRASHED for c in result.cavs)


def test_agent_constructor_failing_is_an_agent_crash() -> None:
    with pytest.raises(AgentCrash, match="constructor raised: RuntimeError"):
        evaluate_route(ring_route(), ConstructorFails, QUICK)
    record = run_task(RouteTask(ring_route(), f"{__name__}:ConstructorFails", QUICK))
    assert record.status == STATUS_AGENT_CRASHED and "no GPU" in (record.error or "")


def test_memory_limit_per_worker(tmp_path: Path) -> None:
    (route,) = _run(tmp_path, Greedy, max_memory=4.0)["routes"]
    assert route["status"] == STATUS_AGENT_CRASHED and "MemoryError" in route["error"]


def test_step_timeout_must_be_positive() -> None:
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="step_timeout must be a positive number"):
            EvalConfig(step_timeout=bad)


# ---- 2, 3, 4: ids and output folders --------------------------------------------------------------


def test_long_and_colliding_route_ids_get_their_own_files(tmp_path: Path) -> None:
    long_id = "x" * 240
    routes = [ring_route(long_id), ring_route("a/b", seed=1), ring_route("a_b", seed=2)]
    config = EvalConfig(background=EMPTY, tick_cap=10)
    merged = run_evaluation(routes, PidAgent, tmp_path, LocalExecutor(2), config)
    assert [r["route_id"] for r in merged["routes"]] == [long_id, "a/b", "a_b"]
    files = sorted(p.name for p in (tmp_path / "routes").glob("*.json"))
    assert len(files) == 3 and max(len(f) for f in files) < 120
    assert record_stem("a_b") == "a_b" and record_stem("a/b").startswith("a_b~")
    assert len(record_stem(long_id)) == 80 + 1 + 12
    mode = stat.S_IMODE((tmp_path / "results.json").stat().st_mode)
    assert mode == 0o666 & ~_umask()  # readable by others under the usual umask, not 0600


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_a_used_output_folder_is_refused_and_resume_merges_only_this_file(tmp_path: Path) -> None:
    config = EvalConfig(background=EMPTY, tick_cap=10)
    run_evaluation([ring_route("a"), ring_route("b")], PidAgent, tmp_path, LocalExecutor(2), config)
    with pytest.raises(OutputFolderError, match="--resume"):
        run_evaluation([ring_route("c")], PidAgent, tmp_path, LocalExecutor(1), config)
    merged = run_evaluation([ring_route("c")], PidAgent, tmp_path, LocalExecutor(1), config, resume=True)
    assert [r["route_id"] for r in merged["routes"]] == ["c"]
    on_disk = json.loads((tmp_path / "results.json").read_text())
    assert on_disk["summary"]["num_routes"] == 1


# ---- 6, 7, 8: route files -------------------------------------------------------------------------


def _route_xml(seed: str = "0", x: str = "10.0", cav_id: str = "1", encoding: str = "utf-8") -> str:
    cav = '<cav id="{i}"><waypoints><position x="{x}" y="0"/><position x="50" y="0"/></waypoints></cav>'
    return (
        f'<?xml version="1.0" encoding="{encoding}"?><routes>'
        f'<route id="r1" town="downtown" weather="ClearNoon" seed="{seed}">'
        f"{cav.format(i=0, x=x)}{cav.format(i=cav_id, x=x)}</route></routes>"
    )


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"seed": "²"}, "seed must be an integer in 0..2147483647, got '²'"),
        ({"seed": "١٢"}, "seed must be an integer"),
        ({"seed": "4294967296"}, "seed must be an integer in 0..2147483647"),
        ({"seed": "9" * 5000}, "seed must be an integer in 0..2147483647"),
        ({"cav_id": "１"}, "the id of <cav> number 1 must be an integer"),
        ({"x": "５６２"}, "non-numeric x='５６２' (ASCII decimal numbers only)"),
        ({"x": "1_000"}, "non-numeric x='1_000'"),
        ({"x": "\u00a012.0"}, "non-numeric x="),
        ({"x": "1e154"}, "x=1e154 is beyond +-1e+06 m"),
        ({"encoding": "klingon"}, "not readable as XML"),
    ],
)
def test_malformed_numbers_and_encodings_name_the_file(tmp_path: Path, kw: dict, message: str) -> None:
    path = tmp_path / "routes.xml"
    path.write_bytes(_route_xml(**kw).encode("utf-8"))
    with pytest.raises(RouteSpecError) as info:
        read_routes(path)
    assert str(path) in str(info.value) and message in str(info.value)


@pytest.mark.filterwarnings("ignore:overflow encountered")
def test_far_away_points_are_a_route_error_not_an_index_error() -> None:
    with pytest.raises(RouteError, match="more than 10 m from any driving lane"):
        from cmudrive.maps import densify

        densify(load_map("downtown"), np.array([[1e200, 0.0], [1e200 + 10.0, 0.0]]))


def test_back_and_forth_and_identical_waypoints_are_refused(tmp_path: Path) -> None:
    good = ring_route()
    start = good.cavs[0].waypoints[0]
    zigzag = start + np.array([[0.01 * (k % 2), 0.0, 0.0] for k in range(5000)])  # 1 cm back and forth
    still = np.repeat(start[None], 4, axis=0)
    for points, message in ((zigzag, "longer than 650 m by route point"), (still, "shorter than 10 m")):
        cavs = (type(good.cavs[0])(0, points), good.cavs[1])
        spec = RouteSpec("bad", good.town, good.weather, 0, cavs)
        t0 = time.monotonic()
        with pytest.raises(RouteError, match=message):
            spec.dense_routes(load_map(good.town))
        assert time.monotonic() - t0 < 30.0  # refused early, not after planning 5000 legs
    write_routes([spec, good], tmp_path / "r.xml")
    checks = check_route_file(tmp_path / "r.xml")
    assert [c.problem is None for c in checks] == [False, True]
    assert "shorter than 10 m" in (checks[0].problem or "")


# ---- 9: the command line --------------------------------------------------------------------------


def test_cli_refuses_an_empty_route_file_and_checks_routes(tmp_path: Path) -> None:
    empty = tmp_path / "empty.xml"
    empty.write_text("<routes></routes>")
    runner = CliRunner()
    result = runner.invoke(app, ["eval", "--routes", str(empty), "--out", str(tmp_path / "out")])
    assert result.exit_code == 1 and "no route to run" in result.output
    result = runner.invoke(app, ["eval", "--routes", "smoke", "--step-timeout", "0", "--out", str(tmp_path)])
    assert result.exit_code == 1 and "step_timeout must be a positive number" in result.output
    result = runner.invoke(app, ["routes", "check", "smoke"])
    assert result.exit_code == 0 and "4 of 4 routes can run" in result.output
    result = runner.invoke(app, ["routes", "check", str(empty)])
    assert result.exit_code == 1 and "no route in the file" in result.output


def test_cli_eval_seed_shifts_every_routes_seed(tmp_path: Path) -> None:
    """--seed N evaluates the same routes with seed + N (other background draws), recorded per route."""
    spec = read_routes(Path(__file__).parents[1] / "cmudrive" / "assets" / "routes" / "smoke.xml")[0]
    write_routes([spec], tmp_path / "one.xml")
    args = [
        "eval",
        "--routes",
        str(tmp_path / "one.xml"),
        "--agent",
        "pid",
        "--tick-cap",
        "3",
        "--workers",
        "1",
    ]
    result = CliRunner().invoke(app, [*args, "--seed", "7", "--out", str(tmp_path / "s7")])
    assert result.exit_code == 0, result.output
    routes = json.loads((tmp_path / "s7" / "results.json").read_text())["routes"]
    assert [r["seed"] for r in routes] == [spec.seed + 7]


def test_cli_agent_options_reach_the_constructor_check(tmp_path: Path) -> None:
    """--agent-option KEY=VALUE (JSON values) goes to the agent's constructor, checked before any route."""
    runner = CliRunner()
    out = ["--out", str(tmp_path / "o"), "--routes", "smoke", "--agent", "pid"]
    result = runner.invoke(app, ["eval", *out, "--agent-option", "no_equals_sign"])
    assert result.exit_code == 1 and "expected KEY=VALUE" in result.output
    result = runner.invoke(app, ["eval", *out, "--agent-option", "wheels=4"])
    assert result.exit_code != 0 and "wheels" in result.output
    assert not (tmp_path / "o" / "results.json").exists()
