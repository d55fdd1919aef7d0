"""Route workers and every process an agent starts end with their route and with their run: when the route
ends, when the watchdog kills a hung worker, and when ``cmudrive eval`` is stopped with SIGTERM or killed
with SIGKILL (then the worker's guard cleans up). The agent here starts ``sleep 901`` and a forked child
that left the worker's session (``setsid``), the hardest kind to find; multiprocessing's resource tracker
must end too."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from cmudrive.agents import Observations, PidAgent
from cmudrive.bench import EvalConfig, LocalExecutor, run_evaluation
from cmudrive.bench.records import STATUS_AGENT_CRASHED
from cmudrive.bench.routes import write_routes
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.dynamics import Controls

from .test_evaluator import ring_route

pytestmark = pytest.mark.skipif(
    not Path("/proc/self/task").exists(), reason="reads processes from /proc (Linux)"
)
ROOT = Path(__file__).resolve().parents[1]
EMPTY = BackgroundConfig(vehicles=0, pedestrians=0)
PATIENCE = 20.0  # [s] for processes to end (a loaded 2-core machine)


class StartsChildren(PidAgent):
    """At tick 1, starts ``sleep 901`` and a forked child in a session of its own, writes the pids to
    ``pidfile``, then ``then``: "drive" on, "sleep" two minutes, or "hang" two minutes where no in-process
    timeout reaches it (SIGALRM blocked, as in native code)."""

    def __init__(self, pidfile: str, then: str = "drive") -> None:
        super().__init__()
        self.pidfile, self.then = pidfile, then

    def run_step(self, obs: Observations) -> Controls:
        if obs.tick == 1:
            sleeper = subprocess.Popen(["sleep", "901"])
            read, write = os.pipe()
            pid = os.fork()
            if pid == 0:  # the child: leave the worker's session and group, and stay
                os.setsid()
                os.write(write, b"x")
                time.sleep(902)
                os._exit(0)
            os.read(read, 1)  # it has called setsid
            tmp = f"{self.pidfile}.tmp"
            Path(tmp).write_text(json.dumps({"worker": os.getpid(), "sleep": sleeper.pid, "fork": pid}))
            os.replace(tmp, self.pidfile)
            if self.then == "hang":
                signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGALRM])
            if self.then != "drive":
                time.sleep(120.0)
        return super().run_step(obs)


AGENT = f"{__name__}:StartsChildren"


def _gone(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True
    return state in ("Z", "X")


def _wait_for(condition: Callable[[], bool], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.1)
    return True


def _children(pid: int) -> set[int]:
    kids: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            kids.update(int(k) for k in (task / "children").read_text().split())
        except OSError:
            pass
    return kids


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _pids(pidfile: Path) -> dict[str, int]:
    assert _wait_for(pidfile.exists, 120.0), "the agent never started its children"
    return json.loads(pidfile.read_text())


def _assert_all_end(pids: dict[str, int]) -> None:
    _wait_for(lambda: all(_gone(p) for p in pids.values()), PATIENCE)
    left = {name: pid for name, pid in pids.items() if not _gone(pid)}
    for pid in left.values():  # do not leave them to the next test
        os.kill(pid, signal.SIGKILL)
    assert not left, f"still running {PATIENCE:.0f} s later: {left}"


def test_what_the_agent_started_ends_with_its_route(tmp_path: Path) -> None:
    pidfile = tmp_path / "pids.json"
    config = EvalConfig(background=EMPTY, tick_cap=10, agent_options={"pidfile": str(pidfile)})
    merged = run_evaluation([ring_route()], AGENT, tmp_path / "out", LocalExecutor(1), config)
    assert merged["routes"][0]["status"] != STATUS_AGENT_CRASHED
    _assert_all_end(_pids(pidfile))


def test_a_hung_worker_is_killed_with_what_its_agent_started(tmp_path: Path) -> None:
    pidfile = tmp_path / "pids.json"
    options = {"pidfile": str(pidfile), "then": "hang"}
    config = EvalConfig(background=EMPTY, tick_cap=10, step_timeout=1.0, agent_options=options)
    merged = run_evaluation([ring_route()], AGENT, tmp_path / "out", LocalExecutor(1), config)
    assert merged["routes"][0]["status"] == STATUS_AGENT_CRASHED
    assert "worker killed" in merged["routes"][0]["error"]
    _assert_all_end(_pids(pidfile))


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_stopping_an_evaluation_ends_its_workers_their_children_and_the_tracker(
    tmp_path: Path, sig: signal.Signals
) -> None:
    """``kill -9`` of ``cmudrive eval`` (or a scheduler's SIGTERM) mid-route: the worker, the agent's
    ``sleep`` and its setsid'ed child, the worker's guard and multiprocessing's resource tracker all end
    within seconds (a worker left behind would also write into the folder of a later --resume)."""
    routes, pidfile = tmp_path / "ring.xml", tmp_path / "pids.json"
    write_routes([ring_route()], routes)
    command = [sys.executable, "-c", "from cmudrive.cli import app; app()", "eval", "--routes", str(routes),
               "--agent", AGENT, "--agent-option", f"pidfile={pidfile}", "--agent-option", "then=sleep",
               "--out", str(tmp_path / "out"), "--workers", "1", "--step-timeout", "300"]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    quiet = subprocess.DEVNULL
    parent = subprocess.Popen(command, cwd=ROOT, env=env, stdout=quiet, stderr=quiet)
    try:
        pids = _pids(pidfile)
        kids = _children(parent.pid)
        (tracker,) = (k for k in kids if "resource_tracker" in _cmdline(k))
        (guard,) = (k for k in _children(pids["worker"]) if "reaper.py" in _cmdline(k))
        assert pids["worker"] in kids and "spawn_main" in _cmdline(pids["worker"])
        parent.send_signal(sig)
        parent.wait(timeout=PATIENCE)
        _assert_all_end({**pids, "tracker": tracker, "guard": guard})
    finally:
        if parent.poll() is None:
            parent.kill()


def test_one_exported_omp_thread_limits_every_runtime_of_a_worker() -> None:
    """A user who exports OMP_NUM_THREADS=1 beside other work gets one thread in MKL (torch's matrix
    products), OpenBLAS and numba too, not the worker's share of the cores; a variable the user exported
    is kept; with nothing exported every runtime gets the share."""
    from cmudrive.bench.runner import worker_threads

    assert worker_threads(2, {"OMP_NUM_THREADS": "1"}) == {
        "OMP_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
        "NUMBA_NUM_THREADS": "1",
    }
    assert worker_threads(2, {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "3"})["MKL_NUM_THREADS"] == "3"
    assert set(worker_threads(4, {}).values()) == {"4"}
