"""Numba's compile time is ours: it never counts against the agent's step limit, in the route's process or
in the runner's watchdog, and a cold compile cache on a busy machine crashes no route.

A slow compile is stood in for by holding numba's global compiler lock (what numba holds while it compiles,
loads or saves a kernel) and sleeping: the same span the clock watches, made long on purpose."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from numba.core.compiler_lock import global_compiler_lock

from cmudrive.agents import Observations, PidAgent
from cmudrive.bench import EvalConfig, LocalExecutor, evaluate_route, run_evaluation
from cmudrive.bench.evaluator import RouteHooks
from cmudrive.bench.records import STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED
from cmudrive.bench.runner import WATCHDOG_GRACE
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.dynamics import Controls

from .test_evaluator import ring_route

EMPTY = BackgroundConfig(vehicles=0, pedestrians=0)
LIMIT = 1.0  # [s] the step limit of these routes
QUICK = EvalConfig(background=EMPTY, tick_cap=40, step_timeout=LIMIT)


class CompilesSlowly(PidAgent):
    """At tick 2, numba's compiler runs for ``compile_s``; then the agent itself works ``work_s``."""

    compile_s = 2.5 * LIMIT
    work_s = 0.0

    def run_step(self, obs: Observations) -> Controls:
        if obs.tick == 2:
            with global_compiler_lock:
                time.sleep(self.compile_s)
            time.sleep(self.work_s)
        return super().run_step(obs)


class SlowWithoutCompiling(CompilesSlowly):
    """The same wait, outside numba's compiler: the agent's own time."""

    def run_step(self, obs: Observations) -> Controls:
        if obs.tick == 2:
            time.sleep(self.compile_s)
        return PidAgent.run_step(self, obs)


class CompilesThenDawdles(CompilesSlowly):
    """After the compile, 0.6 + 0.6 s of its own work: over the limit once the clock resumes."""

    work_s = 1.2 * LIMIT


class CompilesPastTheGrace(CompilesSlowly):
    """Compiles for longer than the watchdog lets an agent's step run."""

    compile_s = LIMIT + WATCHDOG_GRACE + 2.0


def test_compile_time_in_run_step_is_not_charged_to_the_agent() -> None:
    phases: list[str] = []
    result = evaluate_route(ring_route(), CompilesSlowly, QUICK, hooks=RouteHooks(phase=phases.append))
    assert result.status != STATUS_AGENT_CRASHED, result.error
    assert result.ticks == QUICK.tick_cap
    # the route told its watchdog that numba, not the agent, was running, then went back to the agent
    assert any(phases[i - 1 : i + 2] == ["agent", "compile", "agent"] for i in range(1, len(phases) - 1))


def test_the_same_wait_outside_the_compiler_is_still_an_agent_crash() -> None:
    result = evaluate_route(ring_route(), SlowWithoutCompiling, QUICK)
    assert result.status == STATUS_AGENT_CRASHED
    assert "run_step took longer than 1.0 s at tick 2" in (result.error or "")


def test_the_agents_clock_resumes_after_a_compile_with_the_time_that_was_left() -> None:
    result = evaluate_route(ring_route(), CompilesThenDawdles, QUICK)
    assert result.status == STATUS_AGENT_CRASHED  # 1.2 s of its own work: the limit holds after compiling
    assert "at tick 2" in (result.error or "")


def test_a_compile_during_setup_is_not_charged_either() -> None:
    class CompilesInSetup(PidAgent):
        def setup(self, setup):  # type: ignore[no-untyped-def]
            with global_compiler_lock:
                time.sleep(2.5)
            super().setup(setup)

    config = EvalConfig(background=EMPTY, tick_cap=10, step_timeout=LIMIT, setup_timeout=1.0)
    result = evaluate_route(ring_route(), CompilesInSetup, config)
    assert result.status != STATUS_AGENT_CRASHED, result.error


def test_the_watchdog_gives_a_compile_in_run_step_our_time_limit(tmp_path: Path) -> None:
    """In a worker, a compile longer than step limit + grace is not killed as a hung agent."""
    merged = run_evaluation([ring_route()], CompilesPastTheGrace, tmp_path, LocalExecutor(1), QUICK)
    (route,) = merged["routes"]
    assert route["status"] not in (STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED), route["error"]
    assert route["ticks"] == QUICK.tick_cap


# The end-to-end case: a newcomer's first run on a busy laptop. Two routes of the main job side by side
# (two workers filling one empty compile cache), two CPU-bound processes beside them on the 2 cores, and a
# step limit of 1 s, which a warm expert step meets ~20x over but its cold first step (~2 s of compiling on
# an idle machine) did not: before the clock, both routes ended "Agent crashed" at tick 0.
COLD_TICKS = 60


def _hog() -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


@pytest.mark.slow
def test_a_cold_cache_on_a_busy_machine_crashes_no_route(tmp_path: Path) -> None:
    from cmudrive.bench.routes import read_routes, write_routes

    main_job = Path(__file__).resolve().parents[1] / "cmudrive" / "assets" / "routes" / "cmudrive44.xml"
    routes = tmp_path / "two.xml"
    write_routes(read_routes(main_job)[:2], routes)  # one of our towns, one imported CARLA town
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    cmd = [sys.executable, "-m", "cmudrive.cli", "eval", "--routes", str(routes), "--agent", "expert"]
    cmd += ["--workers", "2", "--step-timeout", str(LIMIT), "--tick-cap", str(COLD_TICKS)]
    hogs = [_hog(), _hog()]
    try:
        done = subprocess.run(
            [*cmd, "--out", str(tmp_path / "out")], env=env, capture_output=True, timeout=900
        )
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
    assert done.returncode == 0, done.stderr.decode()[-2000:]
    records = json.loads((tmp_path / "out" / "results.json").read_text())["routes"]
    assert len(records) == 2
    for record in records:
        assert record["status"] not in (STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED), record["error"]
        assert record["ticks"] == COLD_TICKS
    # the two workers left a complete cache: a third process runs the route without compiling anything
    check = subprocess.run(
        [sys.executable, "-c", _COUNT_COMPILES, str(routes), str(COLD_TICKS)],
        env=env,
        capture_output=True,
        timeout=600,
    )
    assert check.returncode == 0, check.stderr.decode()[-2000:]
    assert json.loads(check.stdout.decode().splitlines()[-1]) == []


_COUNT_COMPILES = """
import json, sys
from pathlib import Path
from numba.core import event
from cmudrive.agents import load_agent_class
from cmudrive.bench import EvalConfig, evaluate_route
from cmudrive.bench.routes import read_routes

compiled = []

class Count(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__qualname__)

    def on_end(self, ev):
        pass

spec = read_routes(Path(sys.argv[1]))[0]
with event.install_listener("numba:compile", Count()):
    evaluate_route(spec, load_agent_class("expert"), EvalConfig(tick_cap=int(sys.argv[2])))
print(json.dumps(compiled))
"""


def test_a_worker_runs_numba_kernels_on_its_share_and_still_compiles() -> None:
    """Numba reads NUMBA_NUM_THREADS when imported, before a worker sets its share; the worker applies it
    (a parallel kernel then runs on one thread) and a kernel compiled afterwards does not stumble on the
    changed variable (numba re-reads it at every compile: a cold cache crashed every route once)."""
    script = """
import os
os.environ.pop("NUMBA_NUM_THREADS", None)
import numba, numpy as np
from cmudrive.bench.runner import limit_numba_threads
os.environ["NUMBA_NUM_THREADS"] = "1"
limit_numba_threads()
@numba.njit(parallel=True)
def total(a):
    s = 0.0
    for i in numba.prange(a.shape[0]):
        s += a[i]
    return s
@numba.njit
def inside():
    return numba.get_num_threads()
print(total(np.ones(100)), inside(), numba.config.NUMBA_NUM_THREADS)
"""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_NUM_THREADS"}
    cmd = [sys.executable, "-c", script]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["100.0", "1", "1"]
