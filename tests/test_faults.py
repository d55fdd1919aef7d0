"""Faults blamed on whoever caused them: what the agent hands over is
checked at the boundary, its clean-up is timed and cannot undo a finished route, its constructor's own
exit is its crash; routes that cannot run are refused (or skipped and counted apart) before the first
one starts; a checkpoint that does not load stops the run before any route."""

from __future__ import annotations

import json
import re
import shutil
import signal
import time
from dataclasses import replace
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
from typer.testing import CliRunner

from cmudrive.agents import Agent, Observations, PidAgent
from cmudrive.agents.base import AgentSetupError
from cmudrive.bench import CavSpec, EvalConfig, LocalExecutor, RouteSpec, evaluate_route, run_evaluation
from cmudrive.bench.evaluator import AgentCrash
from cmudrive.bench.records import (
    STATUS_AGENT_CRASHED,
    STATUS_INVALID_ROUTE,
    STATUS_TICK_CAP,
)
from cmudrive.bench.route_check import TRIGGER_TOLERANCE, check_route
from cmudrive.bench.routes import ScenarioSpec, write_routes
from cmudrive.bench.runner import InvalidRoutesError, RouteTask, run_task
from cmudrive.bench.scenarios import ScenarioConfig
from cmudrive.cli import app
from cmudrive.maps import load_map
from cmudrive.maps.coords import map_to_carla
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.dynamics import Controls

from .test_evaluator import ring_route

EMPTY = BackgroundConfig(vehicles=0, pedestrians=0)
QUICK = EvalConfig(background=EMPTY, tick_cap=60, step_timeout=1.0)
LANE = "R1a-R2a_0"  # CAV 0's lane on the ring route (tests/test_evaluator.py)


def _lane_xy(s: float, offset: float = 0.0) -> np.ndarray:
    """Map-frame point at arc length s [m] of CAV 0's lane, ``offset`` metres to its left."""
    m = load_map("interurban")
    i = m.lane(LANE)
    xy = m.index.frenet_to_xy(np.array([i, i]), np.array([s, s + 1.0]))
    along = (xy[1] - xy[0]) / np.linalg.norm(xy[1] - xy[0])
    return xy[0] + offset * np.array([-along[1], along[0]])


def _trigger(s: float, offset: float = 0.0) -> tuple[float, float, float, float]:
    c = map_to_carla(_lane_xy(s, offset)[None])[0]
    return (float(c[0]), float(c[1]), 0.0, 0.0)


# ---- defect 4: what the agent hands over ---------------------------------------------------------


class StringThrottle(PidAgent):
    def run_step(self, obs: Observations) -> Controls:
        c = super().run_step(obs)
        if obs.tick == 3:
            return Controls(c.steer, np.array(["full"] * len(c.throttle)), c.brake)
        return c


class NumericStringSteer(PidAgent):
    """Strings that parse as numbers are still not numbers: they used to pass silently."""

    def run_step(self, obs: Observations) -> Controls:
        c = super().run_step(obs)
        if obs.tick == 4:
            return Controls(np.array(["0.1"] * len(c.steer)), c.throttle, c.brake)
        return c


class InfiniteBrakeOnCav1(PidAgent):
    def run_step(self, obs: Observations) -> Controls:
        c = super().run_step(obs)
        if obs.tick == 2:
            brake = np.array(c.brake, np.float64)
            brake[1] = np.inf
            return Controls(c.steer, c.throttle, brake)
        return c


@pytest.mark.parametrize(
    ("agent", "match"),
    [
        (StringThrottle, r"at tick 3: throttle is .*full.* controls must be numbers \(CAVs cav0, cav1\)"),
        (NumericStringSteer, r"at tick 4: steer is .*0\.1.* controls must be numbers"),
        (InfiniteBrakeOnCav1, r"at tick 2: CAV cav1: brake is inf"),
    ],
)
def test_unusable_controls_are_the_agents_crash_naming_control_tick_and_cav(
    agent: type[Agent], match: str
) -> None:
    result = evaluate_route(ring_route(), agent, QUICK)
    assert result.status == STATUS_AGENT_CRASHED, result.error
    assert all(c.status == STATUS_AGENT_CRASHED for c in result.cavs)
    last = (result.error or "").strip().splitlines()[-1]
    assert "AgentCrash: run_step returned unusable controls" in last
    assert re.search(match, last), last


class WrongShapeInControlLossPatch(PidAgent):
    """Two CAVs, three throttle values once CAV 0 is in a ControlLoss patch: before the boundary check it
    only failed inside the scenario's perturbation, as a simulation crash."""

    patch: ClassVar[np.ndarray] = np.zeros(2)

    def run_step(self, obs: Observations) -> Controls:
        c = super().run_step(obs)
        cav0 = np.flatnonzero(obs.cav_index == 0)
        if len(cav0) and np.hypot(obs.x[cav0[0]] - self.patch[0], obs.y[cav0[0]] - self.patch[1]) < 1.0:
            return Controls(c.steer, np.append(c.throttle, 0.5), c.brake)
        return c


def test_a_wrong_shaped_throttle_under_control_loss_is_the_agents_crash() -> None:
    WrongShapeInControlLossPatch.patch = _lane_xy(54.0)  # the first patch: T (s = 40 m) + 14 m
    spec = replace(ring_route(), scenarios=(ScenarioSpec("S1", "ControlLoss", _trigger(40.0)),))
    result = evaluate_route(spec, WrongShapeInControlLossPatch, replace(QUICK, tick_cap=400))
    assert result.status == STATUS_AGENT_CRASHED, result.error
    assert "throttle has shape (3,), expected (2,)" in (result.error or "")


class UnknownObservation(PidAgent):
    observations = frozenset({"lidar"})  # type: ignore[arg-type]  # the point of this agent


class ObservationsAsString(PidAgent):
    observations = "camera"  # type: ignore[assignment]  # the point of this agent


@pytest.mark.parametrize(
    ("agent", "match"), [(UnknownObservation, "'lidar'"), (ObservationsAsString, "'camera'")]
)
def test_an_invalid_observations_declaration_is_the_agents_fault(
    agent: type[Agent], match: str, tmp_path: Path
) -> None:
    with pytest.raises(AgentSetupError, match=f"{agent.__name__}: observations.*{match}"):
        run_evaluation([ring_route()], f"{__name__}:{agent.__name__}", tmp_path, LocalExecutor(1), QUICK)
    assert not (tmp_path / "routes").exists()  # refused before any route
    record = run_task(RouteTask(ring_route(), f"{__name__}:{agent.__name__}", QUICK))
    assert record.status == STATUS_AGENT_CRASHED and match in (record.error or "")


class ExitsInConstructor(PidAgent):
    error: ClassVar[type[BaseException]] = SystemExit

    def __init__(self) -> None:
        raise self.error(7)


class InterruptedInConstructor(ExitsInConstructor):
    error = KeyboardInterrupt


@pytest.mark.parametrize("agent", [ExitsInConstructor, InterruptedInConstructor])
def test_the_constructors_own_exit_is_its_crash_with_its_traceback(agent: type[Agent]) -> None:
    with pytest.raises(AgentCrash, match=f"constructor raised: {agent.error.__name__}"):
        evaluate_route(ring_route(), agent, QUICK)
    record = run_task(RouteTask(ring_route(), f"{__name__}:{agent.__name__}", QUICK))
    assert record.status == STATUS_AGENT_CRASHED
    assert "raise self.error(7)" in (record.error or "")  # the agent's own frame is in the record


class DestroyHangs(PidAgent):
    def destroy(self) -> None:
        time.sleep(30.0)


class DestroyRaises(PidAgent):
    def destroy(self) -> None:
        raise RuntimeError("could not close the camera")


class DestroyHangsInNativeCode(PidAgent):
    """Blocks SIGALRM and sleeps in destroy(): only the runner's watchdog can stop it."""

    def destroy(self) -> None:
        signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGALRM])
        time.sleep(40.0)


@pytest.mark.parametrize(("agent", "match"), [(DestroyHangs, "longer than 1.0 s"), (DestroyRaises, "camera")])
def test_a_failing_clean_up_keeps_the_routes_result(agent: type[Agent], match: str) -> None:
    started = time.monotonic()
    result = evaluate_route(ring_route(), agent, QUICK)
    assert time.monotonic() - started < 25.0  # destroy() gets run_step's 1 s, not 30 s
    reference = evaluate_route(ring_route(), PidAgent, QUICK)
    assert result.status == reference.status == STATUS_TICK_CAP and result.error is None
    assert [c.status for c in result.cavs] == [c.status for c in reference.cavs]
    assert result.driving_score == reference.driving_score
    assert match in (getattr(result, "cleanup_error", None) or "")


def test_a_destroy_hung_in_native_code_is_killed_and_the_route_keeps_its_result(tmp_path: Path) -> None:
    started = time.monotonic()
    merged = run_evaluation(
        [ring_route()], f"{__name__}:DestroyHangsInNativeCode", tmp_path, LocalExecutor(1), QUICK
    )
    assert time.monotonic() - started < 35.0  # killed after 1 s + 5 s grace, not after 40 s (or 300 s)
    (route,) = merged["routes"]
    assert route["status"] == STATUS_TICK_CAP and route["error"] is None
    assert [c["status"] for c in route["cavs"]] == [STATUS_TICK_CAP] * 2
    assert "destroy() made no progress" in route["cleanup_error"]
    assert merged["summary"]["num_crashed"] == 0


# ---- defect 5: routes that cannot run --------------------------------------------------------------


def _bad_routes() -> list[RouteSpec]:
    ring = ring_route()
    still = np.tile(ring.cavs[0].waypoints[:1], (5, 1))  # five times the same point: a 0 m route
    return [
        replace(ring, id="no_town", town="NoSuchTown"),
        replace(ring, id="path_town", town="../../no_such_folder/Town01"),  # resolved from any cwd
        replace(ring, id="zero_length", cavs=(CavSpec(0, still), ring.cavs[1])),
        replace(
            ring,
            id="bad_param",
            scenarios=(ScenarioSpec("S1", "Accident", _trigger(40.0), {"distance": "1000"}),),
        ),
    ]


def test_eval_refuses_invalid_routes_before_any_runs_and_lists_them_all(tmp_path: Path) -> None:
    routes = [ring_route("ok"), *_bad_routes()]
    with pytest.raises(InvalidRoutesError) as info:
        run_evaluation(routes, "pid", tmp_path, LocalExecutor(1), QUICK)
    message = str(info.value)
    assert "4 of 5 routes cannot run" in message and "--skip-invalid" in message
    for rid, problem in [
        ("no_town", "unknown town 'NoSuchTown'"),
        ("path_town", "map file not found"),
        ("zero_length", "shorter than 10 m"),
        ("bad_param", "distance"),
    ]:
        assert any(rid in line and problem in line for line in message.splitlines()), (rid, message)
    assert not (tmp_path / "routes").exists()


def test_cli_eval_exits_non_zero_or_skips_invalid_routes_and_counts_them_apart(tmp_path: Path) -> None:
    file = tmp_path / "routes.xml"
    write_routes([ring_route("ok"), *_bad_routes()], file)
    runner = CliRunner()
    args = ["eval", "--routes", str(file), "--agent", "pid", "--tick-cap", "3", "--workers", "1"]
    refused = runner.invoke(app, [*args, "--out", str(tmp_path / "a")])
    assert refused.exit_code == 1, refused.output
    assert "no_town" in refused.output and "bad_param" in refused.output
    assert not (tmp_path / "a" / "results.json").exists()
    skipped = runner.invoke(app, [*args, "--skip-invalid", "--out", str(tmp_path / "b")])
    assert skipped.exit_code == 0, skipped.output
    assert "4 invalid routes skipped" in skipped.output
    merged = json.loads((tmp_path / "b" / "results.json").read_text())
    status = {r["route_id"]: r["status"] for r in merged["routes"]}
    assert status == {"ok": STATUS_TICK_CAP, **{r.id: STATUS_INVALID_ROUTE for r in _bad_routes()}}
    summary = merged["summary"]
    assert summary["num_invalid"] == 4 and summary["num_routes"] == 1 and summary["num_crashed"] == 0
    ok = next(r for r in merged["routes"] if r["route_id"] == "ok")
    assert summary["driving_score"] == pytest.approx(ok["driving_score"])  # the invalid ones do not count 0


def test_cli_eval_refuses_routes_the_reader_rejects_unless_skip_invalid(tmp_path: Path) -> None:
    file = tmp_path / "routes.xml"
    write_routes([ring_route("ok"), ring_route("foggy")], file)
    text = file.read_text()
    at = text.index('id="foggy"')
    file.write_text(text[:at] + text[at:].replace('weather="ClearNoon"', 'weather="Sunnyish"', 1))
    runner = CliRunner()
    args = ["eval", "--routes", str(file), "--agent", "pid", "--tick-cap", "3", "--workers", "1"]
    refused = runner.invoke(app, [*args, "--out", str(tmp_path / "a")])
    assert refused.exit_code == 1 and "route foggy" in refused.output and "Sunnyish" in refused.output
    assert not (tmp_path / "a").exists()
    skipped = runner.invoke(app, [*args, "--skip-invalid", "--out", str(tmp_path / "b")])
    assert skipped.exit_code == 0, skipped.output
    assert "skipping route foggy" in skipped.output


def test_resume_checks_a_skipped_route_again(tmp_path: Path) -> None:
    """A route recorded invalid is not finished: fixed in the route file, --resume runs it."""
    ring = ring_route("fixed")
    broken = replace(ring, town="NoSuchTown")
    first = run_evaluation([broken], "pid", tmp_path, LocalExecutor(1), QUICK, skip_invalid=True)
    assert [r["status"] for r in first["routes"]] == [STATUS_INVALID_ROUTE]
    assert first["summary"]["num_invalid"] == 1 and first["summary"]["driving_score"] == 0.0
    again = run_evaluation([ring], "pid", tmp_path, LocalExecutor(1), QUICK, resume=True)
    assert [r["status"] for r in again["routes"]] == [STATUS_TICK_CAP]
    assert again["summary"]["num_invalid"] == 0


def test_one_trigger_tolerance_for_routes_check_and_eval() -> None:
    assert ScenarioConfig().activation_distance == TRIGGER_TOLERANCE == 2.0
    off = replace(ring_route(), scenarios=(ScenarioSpec("S1", "ControlLoss", _trigger(40.0, offset=3.5)),))
    problem = check_route(off, {}).problem or ""
    assert "trigger point is 3.5 m from CAV 0's route (at most 2 m)" in problem
    near = replace(ring_route(), scenarios=(ScenarioSpec("S1", "ControlLoss", _trigger(40.0, offset=1.5)),))
    assert check_route(near, {}).problem is None


# ---- defect 8: a checkpoint that does not load ---------------------------------------------------

TINY = Path(__file__).resolve().parents[1] / "cmudrive" / "assets" / "models" / "v2v-vla-tiny-no-speed"


def _copy_checkpoint(tmp_path: Path) -> Path:
    dst = tmp_path / "ckpt"
    shutil.copytree(TINY, dst)
    return dst


def test_a_broken_checkpoint_stops_the_run_before_any_route(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    ckpt = _copy_checkpoint(tmp_path)
    weights = ckpt / "model.safetensors"
    weights.write_bytes(weights.read_bytes()[: weights.stat().st_size // 2])  # a cut-off download
    file = tmp_path / "one.xml"
    write_routes([ring_route("ok")], file)
    out = tmp_path / "out"
    args = ["eval", "--routes", str(file), "--agent", "v2v-vla", "--checkpoint", str(ckpt), "--tick-cap", "3"]
    result = CliRunner().invoke(app, [*args, "--workers", "1", "--out", str(out)])
    assert result.exit_code == 1, result.output
    assert "V2VVLAAgent cannot run" in result.output
    assert not (out / "routes").exists()


def test_a_missing_checkpoint_stops_the_run_naming_the_path(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    file = tmp_path / "one.xml"
    write_routes([ring_route("ok")], file)
    out, missing = tmp_path / "out", tmp_path / "runs" / "nothing-here"
    args = ["eval", "--routes", str(file), "--agent", "v2v-vla-baseline", "--checkpoint", str(missing)]
    result = CliRunner().invoke(app, [*args, "--workers", "1", "--out", str(out)])
    assert result.exit_code == 1, result.output
    text = " ".join(result.output.split())  # rich wraps long lines
    assert "V2VVLABaselineAgent cannot run" in text and "nothing-here" in text and "--baseline" in text
    assert not (out / "routes").exists()


def test_a_checkpoint_whose_config_names_another_size_is_refused(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    from cmudrive.model.modeling import V2VVLA

    ckpt = _copy_checkpoint(tmp_path)
    meta = json.loads((ckpt / "vla_config.json").read_text())
    meta["config"]["text"]["hidden_size"] = 512  # the config of a bigger model next to tiny weights
    (ckpt / "vla_config.json").write_text(json.dumps(meta))
    with pytest.raises(
        ValueError, match=r"vla_config.json does not describe.*text.hidden_size is 512, the backbone's 128"
    ):
        V2VVLA.from_pretrained(ckpt)
    V2VVLA.from_pretrained(TINY)  # a consistent one still loads
