"""The agent interface: declarations checked at setup, import by path, sparse plans like the leaderboard's."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from cmudrive.agents.base import (
    Agent,
    AgentSetupError,
    Observation,
    Observations,
    RouteSetup,
    check_observations,
    load_agent_class,
    sparse_plan,
)
from cmudrive.agents.pid import PidAgent
from cmudrive.maps import LanePos, RoadMap, RoadOption, RoutePlanner
from cmudrive.sim.dynamics import Controls


class CameraAgent(Agent):
    observations: ClassVar[frozenset[Observation]] = frozenset({Observation.EGO_STATE, Observation.CAMERA})

    def setup(self, route: RouteSetup) -> None:
        pass

    def run_step(self, obs: Observations) -> Controls:
        return Controls.zeros(len(obs.cav_index))


def test_missing_observations_are_refused_at_setup() -> None:
    ego_only = frozenset({Observation.EGO_STATE, Observation.PRIVILEGED})
    with pytest.raises(AgentSetupError, match=r"CameraAgent needs observations .*: camera"):
        check_observations(CameraAgent(), provided=ego_only)
    check_observations(PidAgent(), provided=ego_only)
    check_observations(CameraAgent())  # the evaluator provides cameras


def test_visibility_needs_the_privileged_snapshot() -> None:
    class Peeker(CameraAgent):
        observations: ClassVar[frozenset[Observation]] = frozenset({Observation.VISIBILITY})

    with pytest.raises(AgentSetupError, match="declare privileged too"):
        check_observations(Peeker())


def test_agents_load_by_import_path_with_clear_errors() -> None:
    assert load_agent_class("cmudrive.agents.pid:PidAgent") is PidAgent
    with pytest.raises(AgentSetupError, match=r"must look like 'package\.module:ClassName'"):
        load_agent_class("cmudrive.agents.pid.PidAgent")
    with pytest.raises(
        AgentSetupError, match=r"cannot import module 'no_such_pkg\.mod': No module named 'no_such_pkg'"
    ):
        load_agent_class("no_such_pkg.mod:Agent")
    with pytest.raises(
        AgentSetupError, match=r"'Controls' in cmudrive\.sim\.dynamics is not a cmudrive Agent"
    ):
        load_agent_class("cmudrive.sim.dynamics:Controls")


def test_a_class_name_typo_says_there_is_no_such_class() -> None:
    with pytest.raises(
        AgentSetupError, match=r"no class 'PidAgnt' in module cmudrive\.agents\.pid.*PidAgent"
    ):
        load_agent_class("cmudrive.agents.pid:PidAgnt")
    with pytest.raises(AgentSetupError, match="not a cmudrive Agent subclass"):
        load_agent_class("cmudrive.agents.pid:np")  # exists, but is no agent


def test_the_current_folder_is_on_the_agent_import_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pkg = tmp_path / "cliux_pkg_here"
    pkg.mkdir()
    (pkg / "agent.py").write_text("from cmudrive.agents import PidAgent\n\nclass Mine(PidAgent):\n    pass\n")
    monkeypatch.chdir(tmp_path)
    keep = [p for p in sys.path if p and Path(p).resolve() != tmp_path.resolve()]
    monkeypatch.setattr(sys, "path", keep)  # as under the console script: no '' and no cwd
    assert load_agent_class("cliux_pkg_here.agent:Mine").__name__ == "Mine"
    assert sys.path[0] == str(tmp_path)


def test_sparse_plan_keeps_manoeuvres_and_spacing(mini: RoadMap) -> None:
    """W -> N with a lane change and a left turn: targets at most 50 m apart, both ends of the turn kept."""
    route = RoutePlanner(mini).plan_lanes(LanePos(mini.lane("WC_1"), 5.0), LanePos(mini.lane("CN_1"), 150.0))
    plan = sparse_plan("cav0", route, privileged=False)
    gaps = np.linalg.norm(np.diff(plan.target_points, axis=0), axis=1)
    assert gaps.max() <= 50.0 + 1e-6
    assert len(plan.target_points) < len(route) / 10
    assert RoadOption.LEFT in plan.target_options.tolist()
    assert plan.target_points[-1] == pytest.approx(route.xy[-1])
    assert plan.dense_route is None and sparse_plan("cav0", route, privileged=True).dense_route is route


def test_pid_agent_steers_towards_its_path_with_carla_signs(mini: RoadMap) -> None:
    """A CAV 1 m to the right of its path steers left (CARLA: negative steer) and accelerates."""
    route = RoutePlanner(mini).plan_lanes(LanePos(mini.lane("WC_2"), 5.0), LanePos(mini.lane("WC_2"), 150.0))
    agent = PidAgent()
    agent.setup(RouteSetup("r", "mini", "ClearNoon", 0.05, (sparse_plan("cav0", route, False),)))
    x0, y0 = route.xy[20]
    obs = Observations(
        0, 0.0, np.array([0]), np.array([x0]), np.array([y0 - 1.0]), np.zeros(1), np.zeros(1), np.zeros(1)
    )
    controls = agent.run_step(obs)
    assert controls.steer[0] < -0.05 and controls.throttle[0] > 0.5 and controls.brake[0] == 0.0
