"""Can the labels drive? The expert's path and speed labels through the learned agent's controller.

    cd benchmarks && cmudrive eval --agent label_drive:LabelDrivenAgent [--agent-option stop=expert|rule]
        --routes smoke --out ../runs/label-drive

A model trained to copy a label can at best drive as well as the label drives through the controller
its agent uses. This agent runs the expert (privileged, all of its rules) only to read its decision each
tick, and drives every CAV as the V2V-VLA agent with a speed query does
(:class:`cmudrive.agents.control.WaypointController`): the expert's planned path (map frame -> the CAV's
frame) steers; its ``desired_speed`` (the speed its rules allow, what the speed query learns) is the
speed the controller aims at; go/stop is the expert's own decision (``stop=expert``: a perfect stop head)
or the brake rule on the desired speed alone (``stop=rule``). The route scores against the expert's
(``cmudrive eval --agent expert``) say what the label/controller pair loses before any learning.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmudrive.agents.base import AgentSetupError, Observations, RouteSetup
from cmudrive.agents.control import WaypointController, expert_stops
from cmudrive.agents.expert import ExpertAgent
from cmudrive.maps.coords import to_ego
from cmudrive.sim.dynamics import Controls

SPEED_POINTS = 10  # the controller reads no speed waypoints when a target speed is given


class LabelDrivenAgent(ExpertAgent):
    """The expert's decision, driven through the learned agent's controller (module docstring)."""

    def __init__(self, stop: str = "expert", **kwargs: Any) -> None:
        if stop not in ("expert", "rule"):
            raise AgentSetupError(f"stop must be 'expert' or 'rule', got {stop!r}")
        super().__init__(**kwargs)
        self.stop = stop

    def setup(self, route: RouteSetup) -> None:
        super().setup(route)
        self.controller = WaypointController(len(route.cavs))

    def run_step(self, obs: Observations) -> Controls:
        super().run_step(obs)
        d = self.decision
        assert d is not None
        speed = np.maximum(np.asarray(obs.speed, np.float64), 0.0)
        path = to_ego(d.path, obs.x[:, None], obs.y[:, None], obs.yaw[:, None])
        stop = expert_stops(speed, d.target_speed) if self.stop == "expert" else np.zeros(len(speed), bool)
        steer, throttle, brake = self.controller(
            np.asarray(obs.cav_index),
            speed,
            path,
            np.zeros((len(speed), SPEED_POINTS, 2)),
            d.desired_speed,
            stop,
        )
        return Controls(steer=steer, throttle=throttle, brake=brake)
