"""The batched agent interface: one agent drives every CAV of a route, one call per tick.

An agent declares the observations it needs (:attr:`Agent.observations`); the evaluator checks the
declaration against what it provides before the route starts (:func:`check_observations`) and raises
:class:`AgentSetupError` naming the missing ones, so a mismatch fails at setup rather than mid-route.

Per route, ``setup(RouteSetup)`` gives each CAV its global plan: sparse target points like the
leaderboard's (the dense route downsampled to at most ``TARGET_SPACING`` metres, keeping every point
where the road option changes), and, for agents that declare :attr:`Observation.PRIVILEGED`, the dense
1 m route and the map. Then ``run_step(Observations)`` receives all *active* CAVs at once and returns
their :class:`~cmudrive.sim.dynamics.Controls` as arrays in the same order.

Coordinates are the map frame (x east, y north, metres; yaw counter-clockwise, radians); controls are
CARLA's (steer + = right).
"""

from __future__ import annotations

import difflib
import functools
import importlib
import inspect
import os
import sys
from abc import ABC, abstractmethod
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from cmudrive.maps import RoadMap, RoadOption, Route
from cmudrive.sim.dynamics import Controls

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

    from cmudrive.sim.snapshot import Snapshot

TARGET_SPACING = 50.0  # [m] at most between two sparse target points (leaderboard: every 50th point)


class Observation(str, Enum):
    """What an agent may ask for."""

    EGO_STATE = "ego_state"  # pose, speed and acceleration of each active CAV, other CAVs' relative poses
    PRIVILEGED = "privileged"  # the full snapshot every tick, plus the map and dense routes at setup
    CAMERA = "camera"  # front camera images (n, H, W, 3) uint8
    OCCUPANCY = "occupancy"  # each CAV's own BEV occupancy (n, C, H, W) bool, from what its camera sees
    MERGED_OCCUPANCY = "merged_occupancy"  # own occupancy OR the partner's, warped (implies V2V)
    V2V = "v2v"  # the partner of each CAV; the agent may name partners (Agent.next_partners)
    VISIBILITY = "visibility"  # which snapshot actors each CAV's camera sees (with PRIVILEGED)


PROVIDED: frozenset[Observation] = frozenset(Observation)


class AgentSetupError(ValueError):
    """The agent cannot run here: it cannot be imported, or it needs observations that are not provided."""


@dataclass(frozen=True)
class CavPlan:
    """The global plan of one CAV."""

    cav_id: str
    target_points: np.ndarray  # (k, 2) sparse target points, map frame [m]
    target_options: np.ndarray  # (k,) int8 RoadOption at each target point
    target_speed_limits: np.ndarray  # (k,) [m/s] speed limit at each target point
    dense_route: Route | None = None  # the 1 m route, for privileged agents only


@dataclass(frozen=True)
class RouteSetup:
    route_id: str
    town: str
    weather: str
    dt: float  # [s] one tick
    cavs: tuple[CavPlan, ...]
    road_map: RoadMap | None = None  # for privileged agents only


@dataclass(frozen=True)
class Observations:
    """What the agent sees at one tick, for the ``n`` active CAVs (in ``cav_index`` order)."""

    tick: int
    time: float  # [s]
    cav_index: np.ndarray  # (n,) int: which CAV of the route (index into RouteSetup.cavs)
    x: np.ndarray  # (n,) [m]
    y: np.ndarray  # (n,) [m]
    yaw: np.ndarray  # (n,) [rad]
    speed: np.ndarray  # (n,) [m/s]
    accel: np.ndarray  # (n,) [m/s^2]
    # (n, K, 3) every CAV of the route in each active CAV's frame: x forward, y left [m], yaw [rad];
    # NaN for the CAV itself and CAVs no longer driving (K = CAVs of the route)
    other_cavs: np.ndarray | None = None
    snapshot: Snapshot | None = None  # the whole world, for privileged agents only
    camera: np.ndarray | None = None  # (n, H, W, 3) uint8 front camera (CAMERA)
    occupancy: np.ndarray | None = None  # (n, C, H, W) bool own occupancy, cmudrive.sensors conventions
    merged_occupancy: np.ndarray | None = None  # (n, C, H, W) bool own OR warped partner (MERGED_OCCUPANCY)
    partner: np.ndarray | None = None  # (n,) CAV index each CAV talks to this tick, -1 none (V2V)
    partner_received: np.ndarray | None = None  # (n,) bool: the partner's map arrived (V2V)
    visible: np.ndarray | None = None  # (n, A) bool over snapshot rows: seen by each CAV (VISIBILITY)
    visible_scenery: np.ndarray | None = None  # (n, S) bool over the route's static scenery (VISIBILITY)


class Agent(ABC):
    """Subclass this, declare :attr:`observations`, and implement :meth:`setup` and :meth:`run_step`."""

    observations: ClassVar[frozenset[Observation]] = frozenset({Observation.EGO_STATE})

    @abstractmethod
    def setup(self, route: RouteSetup) -> None:
        """Called once per route, before the first tick."""

    @abstractmethod
    def run_step(self, obs: Observations) -> Controls:
        """Controls for every active CAV, arrays of shape (n,) in ``obs.cav_index`` order."""

    def needed_observations(self) -> frozenset[Observation]:
        """The observations this agent, made with its options, needs: its class's :attr:`observations` by
        default. An agent whose options add an input widens it here (the V2V-VLA baseline's safety brake
        reads the CAV's own occupancy); the evaluator asks every agent it sets up, so the extra input is
        computed only for the runs that read it."""
        return self.observations

    def next_partners(self) -> np.ndarray | None:
        """Partners the agent names for the next tick, after ``run_step``: (n,) CAV indices in the last
        ``obs.cav_index`` order, -1 for the default (the closest CAV in front); None: defaults for all.
        Only agents that declare V2V or MERGED_OCCUPANCY are asked."""
        return None

    def destroy(self) -> None:  # noqa: B027 - optional hook, nothing to do by default
        """Called once when the route ends (also after a crash)."""

    @classmethod  # noqa: B027 - optional hook, nothing to check by default
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """Called once before an evaluation starts, with the constructor's keyword arguments: raise
        (naming the file or option) when the agent cannot run with them, e.g. a checkpoint that does not
        load, so that the run stops with the reason instead of crashing every route. Runs in the main
        process: keep it to what a route's setup would read anyway."""

    @classmethod
    def input_files(cls, options: Mapping[str, Any]) -> dict[str, Path]:
        """The files and folders (checkpoints, weights) an agent made with ``cls(**options)`` loads, by
        name: a run records a hash of their content, and ``--resume`` refuses other content. By default
        the ``checkpoint`` option (``cmudrive eval --checkpoint``) when it names an existing path; an agent
        that loads other files, or a default checkpoint when none is named, adds them here (other options
        are compared as they are written, paths by name)."""
        path = options.get("checkpoint")
        if isinstance(path, str | os.PathLike) and Path(path).exists():
            return {"checkpoint": Path(path).resolve()}
        return {}


def declared_observations(agent: Agent | type[Agent]) -> frozenset[Observation]:
    """The agent class's :attr:`Agent.observations` (an agent's :meth:`Agent.needed_observations`) as
    Observations, or AgentSetupError naming the agent and what is wrong with the declaration (not a set of
    observation names, an unknown name)."""
    cls = agent if isinstance(agent, type) else type(agent)
    raw = getattr(cls, "observations", None)
    if isinstance(agent, Agent):
        raw = agent.needed_observations()
    if isinstance(raw, str | bytes) or not isinstance(raw, set | frozenset | list | tuple):
        raise AgentSetupError(
            f"agent {cls.__name__}: observations must be a set of Observation values, got {raw!r}"
        )
    known = ", ".join(o.value for o in Observation)
    declared = []
    for o in raw:
        try:
            declared.append(Observation(o))
        except (ValueError, TypeError):
            raise AgentSetupError(
                f"agent {cls.__name__}: observations declares {o!r}, which is no observation (known: {known})"
            ) from None
    return frozenset(declared)


def check_observations(
    agent: Agent | type[Agent], provided: frozenset[Observation] = PROVIDED
) -> frozenset[Observation]:
    """The agent's declared observations, checked: each known, visibility only with privileged, every
    one provided here (AgentSetupError naming the agent and the problem)."""
    declared = declared_observations(agent)
    name = agent.__name__ if isinstance(agent, type) else type(agent).__name__
    if Observation.VISIBILITY in declared and Observation.PRIVILEGED not in declared:
        raise AgentSetupError(
            f"agent {name} asks for visibility, which indexes the privileged snapshot: declare privileged too"
        )
    missing = declared - provided
    if missing:
        names = ", ".join(sorted(o.value for o in missing))
        raise AgentSetupError(
            f"agent {name} needs observations this evaluator does not provide: {names} "
            f"(provided: {', '.join(sorted(o.value for o in provided))})"
        )
    return declared


# short names of the bundled agents (``cmudrive eval --agent expert``)
BUNDLED_AGENTS: dict[str, str] = {
    "expert": "cmudrive.agents.expert:ExpertAgent",
    "autopilot": "cmudrive.agents.autopilot:AutopilotAgent",
    "pid": "cmudrive.agents.pid:PidAgent",
    "v2v-vla": "cmudrive.model.agent:V2VVLAAgent",  # needs the model extra and a checkpoint
    "v2v-vla-baseline": "cmudrive.model.agent:V2VVLABaselineAgent",
    # a CARLA leaderboard agent file on every CAV (option agent=FILE; cmudrive eval --agent leaderboard:FILE)
    "leaderboard": "cmudrive.leaderboard.adapter:LeaderboardAgent",
}


def load_agent_class(spec: str) -> type[Agent]:
    """``"package.module:ClassName"`` or a bundled agent's short name -> the class (clear errors for each
    way this can fail: no such module, no such class in it (with close names), not an Agent subclass).

    For a class path the current folder goes first on the import path, as ``python -m`` puts it, so that
    ``cmudrive eval --agent my_pkg.my_agent:MyAgent`` finds ``./my_pkg`` from the installed ``cmudrive``
    command too (route workers inherit the parent's path; a folder without ``__init__.py`` never hides an
    installed package of its name, a module file in the current folder does, as under ``python -m``)."""
    bundled = spec in BUNDLED_AGENTS
    spec = BUNDLED_AGENTS.get(spec, spec)
    module_name, sep, class_name = spec.partition(":")
    if not sep or not module_name or not class_name:
        names = ", ".join(sorted(BUNDLED_AGENTS))
        raise AgentSetupError(
            f"agent {spec!r} must look like 'package.module:ClassName' or be one of {names}"
        )
    if not bundled:  # a bundled agent needs no user folder on the path (nothing of it can shadow ours)
        _put_cwd_on_path()
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise AgentSetupError(f"agent {spec!r}: cannot import module {module_name!r}: {exc}") from exc
    if not hasattr(module, class_name):
        agents = {n: v for n, v in vars(module).items() if isinstance(v, type) and issubclass(v, Agent)}
        classes = [n for n, v in agents.items() if v is not Agent]
        close = difflib.get_close_matches(class_name, classes, n=3, cutoff=0.5)
        hint = f"; did you mean {' or '.join(close)}?" if close else ""
        known = f" (Agent classes there: {', '.join(sorted(classes))})" if classes else ""
        raise AgentSetupError(
            f"agent {spec!r}: there is no class {class_name!r} in module {module_name} "
            f"({getattr(module, '__file__', None) or 'a namespace package'}){hint}{known}"
        )
    cls = getattr(module, class_name)
    if not isinstance(cls, type) or not issubclass(cls, Agent):
        what = f"a {type(cls).__name__}" if not isinstance(cls, type) else "a class that does not subclass it"
        raise AgentSetupError(
            f"agent {spec!r}: {class_name!r} in {module_name} is not a cmudrive Agent subclass ({what}; "
            "subclass cmudrive.agents.Agent)"
        )
    return cls


def _put_cwd_on_path() -> None:
    """The current folder first on ``sys.path`` (``python -m`` does this; a console script does not)."""
    cwd = os.getcwd()
    if not any(os.path.abspath(p or os.curdir) == cwd for p in sys.path):
        sys.path.insert(0, cwd)


def agent_factory(cls: type[Agent], options: Mapping[str, Any] | None = None) -> Callable[[], Agent]:
    """What makes the agent: ``cls(**options)`` (``EvalConfig.agent_options``, e.g. ``checkpoint=PATH``),
    checked against the constructor's signature now, so that an option it does not take fails before any
    route starts; the class's observations declaration is checked too (:func:`check_observations`)."""
    check_observations(cls)
    if not options:
        return cls
    try:
        inspect.signature(cls).bind(**options)
    except TypeError as exc:
        names = sorted(options)
        raise AgentSetupError(f"agent {cls.__name__} does not take the options {names}: {exc}") from exc
    return functools.partial(cls, **options)


def sparse_plan(cav_id: str, route: Route, privileged: bool, spacing: float = TARGET_SPACING) -> CavPlan:
    """Downsample a dense route to target points: every point where the road option changes, and
    enough points in between that no two are more than ``spacing`` metres apart."""
    option = route.option
    keep = np.zeros(len(route), bool)
    keep[[0, -1]] = True
    keep[1:] |= option[1:] != option[:-1]
    keep[:-1] |= option[1:] != option[:-1]  # both ends of a manoeuvre
    last = 0.0
    for i in range(len(route)):  # one pass over the dense route at setup: not a hot path
        if keep[i]:
            last = route.distance[i]
        elif route.distance[i] - last >= spacing:
            keep[i] = True
            last = route.distance[i]
    idx = np.flatnonzero(keep)
    return CavPlan(
        cav_id=cav_id,
        target_points=route.xy[idx],
        target_options=route.option[idx].astype(np.int8),
        target_speed_limits=route.speed_limit[idx],
        dense_route=route if privileged else None,
    )


def is_turn(option: np.ndarray) -> np.ndarray:
    return np.isin(option, [RoadOption.LEFT, RoadOption.RIGHT])
