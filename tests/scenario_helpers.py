"""Named scenes for scenario tests: lane-following CAV routes, trigger points, a recorded run, tracks."""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import numpy as np

from cmudrive.agents import Observation, Observations, PidAgent
from cmudrive.bench import CavSpec, EvalConfig, RouteSpec, evaluate_route
from cmudrive.bench.records import RouteResult
from cmudrive.bench.route_log import RouteLog, load_route_log
from cmudrive.bench.routes import ScenarioSpec
from cmudrive.maps import RoadMap, load_map
from cmudrive.maps.coords import map_to_carla
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.dynamics import Controls

EMPTY = BackgroundConfig(vehicles=0, pedestrians=0)


def lane_cav(m: RoadMap, cav: int, lane: str, s0: float, s1: float, n: int = 5) -> CavSpec:
    """A CAV whose waypoints follow one lane from s0 to s1 [m]."""
    i = m.lane(lane)
    xy = m.index.frenet_to_xy(np.full(n, i), np.linspace(s0, s1, n))
    return CavSpec(cav, np.column_stack([map_to_carla(xy), np.zeros(n)]))


def path_cav(m: RoadMap, cav: int, xy: np.ndarray) -> CavSpec:
    """A CAV whose waypoints are map-frame points (n, 2)."""
    return CavSpec(cav, np.column_stack([map_to_carla(np.asarray(xy, np.float64)), np.zeros(len(xy))]))


def trigger(m: RoadMap, lane: str, s: float) -> tuple[float, float, float, float]:
    """A CARLA-frame trigger pose at arc length s of a lane."""
    xy = m.index.frenet_to_xy(np.array([m.lane(lane)]), np.array([s]))
    c = map_to_carla(xy)[0]
    return (float(c[0]), float(c[1]), 0.0, 0.0)


def scenario(kind: str, where: tuple[float, float, float, float], **params: str) -> ScenarioSpec:
    return ScenarioSpec("S1", kind, where, dict(params))


def run(
    spec: RouteSpec, tmp_path: Path, agent: type = PidAgent, config: EvalConfig | None = None
) -> tuple[RouteResult, RouteLog]:
    """Evaluate the route in an empty town with a log, and load the log."""
    config = config or EvalConfig(background=EMPTY)
    from dataclasses import replace

    config = replace(config, record_dir=tmp_path)
    result = evaluate_route(spec, agent, config)
    assert result.error is None, result.error
    logs = sorted(tmp_path.glob("*.npz"))
    return result, load_route_log(logs[-1])


def track(log: RouteLog, actor_id: str) -> np.ndarray:
    """(T, 4) x, y, yaw, speed of one actor per log tick, NaN where it is absent."""
    a = log.arrays
    out = np.full((log.num_ticks, 4), np.nan)
    ids = a["actor_id"]
    hit = np.flatnonzero(ids == actor_id)
    if len(hit) == 0:
        return out
    rows = np.flatnonzero(a["actor"] == hit[0])
    ticks = np.searchsorted(a["tick_ptr"], rows, side="right") - 1
    out[ticks] = np.column_stack([a["x"][rows], a["y"][rows], a["yaw"][rows], a["speed"][rows]])
    return out


def cav_track(log: RouteLog, cav: int) -> np.ndarray:
    return track(log, f"cav{cav}")


def frenet(m: RoadMap, lane: str, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(s, d) of points on a given lane (d + left)."""
    return m.index.project(np.atleast_2d(xy), np.full(len(np.atleast_2d(xy)), m.lane(lane)))


class StopsAt(PidAgent):
    """Follows its route like the PID agent, then brakes to a standstill from ``STOP_TIME`` on."""

    STOP_TIME: ClassVar[float] = 4.0  # [s]
    observations: ClassVar[frozenset[Observation]] = PidAgent.observations

    def run_step(self, obs: Observations) -> Controls:
        c = super().run_step(obs)
        if obs.time < self.STOP_TIME:
            return c
        n = len(obs.cav_index)
        return Controls(np.zeros(n), np.zeros(n), np.ones(n))


class StopsSome(PidAgent):
    """Follows its route like the PID agent; each CAV in ``STOP_AT`` brakes to a standstill from its time
    [s] on, the others drive on."""

    STOP_AT: ClassVar[dict[int, float]] = {}
    observations: ClassVar[frozenset[Observation]] = PidAgent.observations

    def run_step(self, obs: Observations) -> Controls:
        return stop_cavs(super().run_step(obs), obs, self.STOP_AT)


def stop_cavs(c: Controls, obs: Observations, stop_at: dict[int, float]) -> Controls:
    """``c`` with full brake for each CAV of ``stop_at`` from its time [s] on."""
    stop = np.array([obs.time >= stop_at.get(int(i), np.inf) for i in obs.cav_index], bool)
    steer, throttle = np.where(stop, 0.0, c.steer), np.where(stop, 0.0, c.throttle)
    return Controls(steer, throttle, np.where(stop, 1.0, c.brake))


def interurban() -> RoadMap:
    return load_map("interurban")
