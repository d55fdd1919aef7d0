"""Step callbacks of the evaluation loop: code that watches a route being driven without driving it.

In the spirit of nuPlan's simulation callbacks, :func:`cmudrive.bench.evaluate_route` takes callbacks
that hear the route start (:meth:`RouteCallback.on_route_start`, once the world and the scenarios are
built, before the agent's ``setup``), every tick once the world has moved on it
(:meth:`RouteCallback.on_step`: the state the agent saw, the observations it got, the controls it
returned and those the world applied, and the state after the tick, scored), and the route end
(:meth:`RouteCallback.on_route_end`, with the final record, before the agent's ``destroy``). The driving
agent is any agent: data collection (``cmudrive.data.collector.RowCollector``), the replay log
(``cmudrive.bench.recording.LogRecorder``) and the partial scores a runner's worker sends its parent
(``RouteHooks.partial``) are callbacks, so the expert or a learned model can drive while rows, logs or
scores are recorded.

What a callback raises is not the agent's fault: in ``on_route_start`` or ``on_step`` it ends the route as
"Failed - Simulation crashed" (the traceback in the record); from ``on_route_end`` it propagates out of
``evaluate_route`` to the caller that installed the callback. Callbacks run outside the agent's step time
limit, and see the world through the privileged set-up (map and dense routes), whatever the agent
declared: they must not change what they are given.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cmudrive.agents.base import Agent, Observations, RouteSetup
from cmudrive.sim.dynamics import Controls
from cmudrive.sim.snapshot import Snapshot

if TYPE_CHECKING:  # records imports nothing of this module; the import is for annotations only
    from cmudrive.bench.records import RouteResult
    from cmudrive.bench.routes import RouteSpec


@dataclass(frozen=True)
class RouteStart:
    """What a callback learns when the route starts."""

    spec: RouteSpec
    setup: RouteSetup  # the privileged set-up (road map, dense routes), whatever the agent declared
    agent: Agent  # the driving agent, constructed; its setup comes next


@dataclass(frozen=True)
class Step:
    """One tick: as the agent saw and answered it, and the world after it."""

    tick: int
    time: float  # [s]
    snapshot: Snapshot  # the world the agent's observations were built from
    rows: np.ndarray  # (n,) snapshot rows of the active CAVs
    cav_index: np.ndarray  # (n,) their CAV indices
    observations: Observations  # what the agent got (only what it declared)
    controls: Controls  # what it returned, checked, before the scenarios' perturbation
    agent: Agent
    applied: Controls  # what the world applied (ControlLoss perturbs the agent's controls)
    after: Snapshot  # the world after the tick (criteria updated, finished CAVs not yet removed)
    scores: Callable[[], RouteResult]  # the route's scores so far (comfort, first-junction share: at the end)


class RouteCallback:
    """Override any of the three; the defaults do nothing."""

    def on_route_start(self, start: RouteStart) -> None:
        """The route is about to run its first tick."""

    def on_step(self, step: Step) -> None:
        """The tick ``step.tick`` has run."""

    def on_route_end(self, result: RouteResult) -> None:
        """The route is over (any status, crashes included); ``result`` is its final record."""


__all__ = ["RouteCallback", "RouteStart", "Step"]
