"""A simple privileged lane-following autopilot for CAVs, vectorised over CAVs.

It is what drives the CAVs in ``cmudrive sim demo`` and the simulator's behaviour tests: pure-pursuit
steering on the CAV's dense route, a target speed that is the lowest of the lane's speed limit, an
arrival profile that brings the CAV to its route's last point at ``ARRIVAL_SPEED``, a stopping profile for
the nearest actor in the route corridor ahead, and one for a red or yellow light at the next junction
entry on the route; a proportional speed controller turns it into throttle/brake.
It is not an expert (no prediction, no right-of-way reasoning beyond lights); issue-level agents build
on the same controllers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from cmudrive.agents.base import Agent, AgentSetupError, Observation, Observations, RouteSetup
from cmudrive.agents.control import nearest_ahead
from cmudrive.agents.corridor import first_in_corridor
from cmudrive.maps import RoadMap, Route
from cmudrive.sim.dynamics import Controls, VehicleParams
from cmudrive.sim.snapshot import Snapshot
from cmudrive.sim.traffic_lights import link_states

LOOKAHEAD_MIN = 4.0  # [m] pure-pursuit look-ahead at standstill
LOOKAHEAD_GAIN = 0.8  # [s] look-ahead grows with speed
HORIZON = 60  # [route points = m] how far ahead obstacles and lights are checked
CORRIDOR = 0.8  # [m] lateral margin added to half the CAV width (to the actors' boxes)
STOP_GAP = 4.0  # [m] standstill distance kept to an obstacle (bumper to bumper)
LIGHT_GAP = 2.0  # [m] stop this far before a red light's stop line
COMFORT_DECEL = 3.0  # [m/s^2] deceleration used to plan stopping profiles
SPEED_GAIN = 0.6  # throttle per m/s of speed error
BRAKE_GAIN = 0.35  # brake per m/s of speed excess
SPEED_LIMIT_FACTOR = 0.9  # cruise at this fraction of the speed limit
ARRIVAL_SPEED = 4.0  # [m/s] speed at which a CAV reaches the last point of its route (it then stops)


@dataclass
class LaneFollowingAutopilot:
    """Drives ``n`` CAVs along their dense routes. ``progress`` is each CAV's index into its route."""

    road_map: RoadMap
    routes: list[Route]
    params: VehicleParams = field(default_factory=VehicleParams)

    def __post_init__(self) -> None:
        self.progress = np.zeros(len(self.routes), np.int64)
        self._pad = max(len(r) for r in self.routes) + HORIZON
        n = len(self.routes)
        # routes padded to one array (their last point repeated) so that all CAVs are handled at once
        self._xy = np.zeros((n, self._pad, 2))
        self._lane = np.full((n, self._pad), -1, np.int32)
        self._speed = np.zeros((n, self._pad))
        self._to_end = np.zeros((n, self._pad))  # [m] distance from each route point to the route's end
        for i, r in enumerate(self.routes):
            k = len(r)
            self._xy[i, :k], self._xy[i, k:] = r.xy, r.xy[-1]
            self._lane[i, :k], self._lane[i, k:] = r.lane, r.lane[-1]
            # past the end the last limit goes on: the arrival profile below, not the padding, slows
            # the CAV down (a padded 0 made every CAV stop a horizon short of its destination)
            self._speed[i, :k], self._speed[i, k:] = r.speed_limit, r.speed_limit[-1]
            self._to_end[i, :k] = r.distance[-1] - r.distance

    def controls(self, snap: Snapshot, cav_rows: np.ndarray, cav_index: np.ndarray) -> Controls:
        """Controls for the CAVs at snapshot rows ``cav_rows``, which are routes ``cav_index``."""
        x, y, yaw, v = snap.x[cav_rows], snap.y[cav_rows], snap.yaw[cav_rows], snap.speed[cav_rows]
        pos = np.stack([x, y], axis=1)
        self._advance_progress(pos, cav_index)
        ahead = self.progress[cav_index][:, None] + np.arange(HORIZON)[None, :]  # (n, H)
        path = self._xy[cav_index[:, None], ahead]  # (n, H, 2)
        steer = self._pure_pursuit(pos, yaw, v, path)
        limit = SPEED_LIMIT_FACTOR * self._speed[cav_index[:, None], ahead].min(axis=1, initial=np.inf)
        to_end = self._to_end[cav_index, self.progress[cav_index]]
        limit = np.minimum(limit, np.sqrt(ARRIVAL_SPEED**2 + 2.0 * COMFORT_DECEL * to_end))
        limit = np.where(self._finished(cav_index), 0.0, limit)
        target = np.minimum(limit, self._obstacle_speed(snap, cav_rows, path))
        target = np.minimum(target, self._light_speed(snap, cav_index, ahead, pos))
        error = target - v
        throttle = np.clip(SPEED_GAIN * error, 0.0, 1.0)
        brake = np.where(error < -0.3, np.clip(-BRAKE_GAIN * error, 0.0, 1.0), 0.0)
        brake = np.where(target < 0.1, np.maximum(brake, 0.5), brake)
        throttle = np.where(brake > 0, 0.0, throttle)
        return Controls(steer=steer, throttle=throttle, brake=brake)

    def _advance_progress(self, pos: np.ndarray, cav_index: np.ndarray) -> None:
        self.progress[cav_index], _ = nearest_ahead(self._xy, self.progress, cav_index, pos, 20)

    def _finished(self, cav_index: np.ndarray) -> np.ndarray:
        lengths = np.array([len(self.routes[i]) for i in cav_index])
        return self.progress[cav_index] >= lengths - 2

    def _pure_pursuit(self, pos: np.ndarray, yaw: np.ndarray, v: np.ndarray, path: np.ndarray) -> np.ndarray:
        lookahead = LOOKAHEAD_MIN + LOOKAHEAD_GAIN * v
        dist = np.linalg.norm(path - pos[:, None, :], axis=-1)
        k = np.argmax(dist >= lookahead[:, None], axis=1)
        target = path[np.arange(len(pos)), k]
        rel = target - pos
        c, s = np.cos(-yaw), np.sin(-yaw)
        local_x = c * rel[:, 0] - s * rel[:, 1]
        local_y = s * rel[:, 0] + c * rel[:, 1]
        ld2 = np.maximum(local_x**2 + local_y**2, 1e-6)
        curvature = 2.0 * local_y / ld2
        wheel = np.arctan(self.params.wheelbase * curvature)
        return np.clip(-wheel / self.params.max_steer, -1.0, 1.0)  # CARLA: + steer = right

    def _obstacle_speed(self, snap: Snapshot, cav_rows: np.ndarray, path: np.ndarray) -> np.ndarray:
        """Speed that lets each CAV stop STOP_GAP short of the first actor in its route corridor."""
        first, _ = first_in_corridor(
            np.ascontiguousarray(path),
            np.asarray(cav_rows, np.int64),
            0.5 * snap.width[cav_rows] + CORRIDOR,
            snap.x,
            snap.y,
            snap.yaw,
            snap.length,
            snap.width,
            snap.other_level(cav_rows) | ~snap.valid[None, :],
            HORIZON + 10.0,
        )
        gap = first.astype(float) - 0.5 * snap.length[cav_rows] - STOP_GAP
        return np.sqrt(2.0 * COMFORT_DECEL * np.maximum(gap, 0.0))

    def _light_speed(
        self, snap: Snapshot, cav_index: np.ndarray, ahead: np.ndarray, pos: np.ndarray
    ) -> np.ndarray:
        """Speed that stops each CAV before the stop line of a red/yellow light on its route ahead."""
        m = self.road_map
        lanes = self._lane[cav_index[:, None], ahead]  # (n, H)
        entering = m.lane_internal[lanes[:, 1:]] & ~m.lane_internal[lanes[:, :-1]]
        state = link_states(m, snap.tls_state)
        out = np.full(len(cav_index), np.inf)
        for row in np.flatnonzero(entering.any(axis=1)):
            k = int(np.argmax(entering[row]))
            into, frm = lanes[row, k + 1], lanes[row, k]
            links = m.successor_links(frm)[m.successors(frm) == into]
            if len(links) and state[links[0]] in ("r", "y", "u"):
                line_xy = self._xy[cav_index[row], ahead[row, k]]
                gap = np.linalg.norm(line_xy - pos[row]) - LIGHT_GAP - 2.5
                if state[links[0]] == "y" and gap < 0.0:
                    continue  # too close to stop for yellow: go on
                out[row] = np.sqrt(2.0 * COMFORT_DECEL * max(gap, 0.0))
        return out


class AutopilotAgent(Agent):
    """The lane-following autopilot as a privileged benchmark agent: it reads the whole snapshot (actors in
    its route corridor, light states) and the dense routes. A baseline, not an expert: it does not stop at
    stop signs, yield at unsignalised junctions or change lanes around obstacles."""

    observations: ClassVar[frozenset[Observation]] = frozenset({Observation.PRIVILEGED})

    def setup(self, route: RouteSetup) -> None:
        if route.road_map is None or any(c.dense_route is None for c in route.cavs):
            raise AgentSetupError("AutopilotAgent needs the privileged set-up (map and dense routes)")
        self.pilot = LaneFollowingAutopilot(route.road_map, [c.dense_route for c in route.cavs])  # type: ignore[misc]

    def run_step(self, obs: Observations) -> Controls:
        snap = obs.snapshot
        if snap is None:
            raise AgentSetupError("AutopilotAgent needs the snapshot (privileged observations)")
        rows, index = snap.cav_rows()
        row_of = dict(zip(index.tolist(), rows.tolist(), strict=True))
        cav_rows = np.array([row_of[int(i)] for i in obs.cav_index], np.int64)
        return self.pilot.controls(snap, cav_rows, obs.cav_index)
