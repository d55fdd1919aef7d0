"""The leaderboard's agent base class and tracks, for agents written against CARLA Leaderboard 2.0.

A leaderboard agent file changes its import of ``leaderboard.autoagents.autonomous_agent`` to this module
(``from cmudrive.leaderboard.autonomous_agent import AutonomousAgent, Track``) and nothing else.

The life of an instance follows the leaderboard's evaluator: ``cls(host, port, debug)``, then
``set_global_plan(gps_plan, world_plan)`` with the dense route (one point per metre), then
``setup(path_to_conf_file)``, then ``sensors()``; ``run_step(input_data, timestamp)`` every tick;
``destroy()`` at the end. The base ``set_global_plan`` keeps the points where the road option changes,
every lane change, the last point, and enough points that no two are more than ``PLAN_SPACING`` apart,
as the leaderboard's does; an agent that wants the dense plan overrides it.

There is no CARLA server: ``carla_host`` and ``carla_port`` are accepted and unused, and the base class
has no ``sensor_interface`` (cmudrive hands ``run_step`` its sensor data directly).
"""

from __future__ import annotations

from enum import Enum
from typing import Any

from cmudrive.leaderboard.carla import Transform, VehicleControl
from cmudrive.maps import RoadOption

PLAN_SPACING = 200.0  # [m] Leaderboard 2.0 keeps a plan point at least this often


class Track(Enum):
    """The leaderboard's tracks. cmudrive provides the sensors of SENSORS; MAP's OpenDRIVE map is not."""

    SENSORS = "SENSORS"
    MAP = "MAP"
    SENSORS_QUALIFIER = "SENSORS_QUALIFIER"
    MAP_QUALIFIER = "MAP_QUALIFIER"


GpsPoint = dict[str, float]  # {"lat": deg, "lon": deg, "z": m}
PlanPoint = tuple[Any, RoadOption]  # (GpsPoint or Transform, RoadOption)


class AutonomousAgent:
    """Subclass this as for the leaderboard (module docstring)."""

    def __init__(self, carla_host: str = "localhost", carla_port: int = 2000, debug: bool = False) -> None:
        self.track = Track.SENSORS
        self._global_plan: list[tuple[GpsPoint, RoadOption]] | None = None
        self._global_plan_world_coord: list[tuple[Transform, RoadOption]] | None = None
        self.wallclock_t0 = None

    def setup(self, path_to_conf_file: str) -> None:
        """Load what the agent needs (models, its configuration); set ``self.track``."""

    def sensors(self) -> list[dict[str, Any]]:
        """The sensor suite, as the leaderboard's: dicts with ``type``, ``id``, pose ``x y z roll pitch
        yaw`` (vehicle frame, CARLA's axes, metres and degrees) and per type ``width height fov``."""
        return []

    def run_step(self, input_data: dict[str, tuple[int, Any]], timestamp: float) -> VehicleControl:
        """One tick: ``input_data`` maps each sensor id to ``(frame, data)``; ``timestamp`` [s] of
        simulated time. Returns the vehicle's controls."""
        return VehicleControl()

    def destroy(self) -> None:
        """Release what ``setup`` took."""

    def set_global_plan(
        self,
        global_plan_gps: list[tuple[GpsPoint, RoadOption]],
        global_plan_world_coord: list[tuple[Transform, RoadOption]],
    ) -> None:
        """Keep the downsampled plan in ``_global_plan`` (GPS) and ``_global_plan_world_coord``."""
        keep = downsample_plan(global_plan_world_coord, PLAN_SPACING)
        self._global_plan_world_coord = [global_plan_world_coord[i] for i in keep]
        self._global_plan = [global_plan_gps[i] for i in keep]


LANE_CHANGES = (RoadOption.CHANGELANELEFT, RoadOption.CHANGELANERIGHT)


def downsample_plan(plan: list[tuple[Transform, RoadOption]], spacing: float) -> list[int]:
    """Indices of the plan points to keep: every lane-change point, the first point of each other
    manoeuvre (unless it follows a lane change), the last point, and a point whenever more than
    ``spacing`` metres [m] were driven since the last kept one."""
    keep: list[int] = []
    driven = 0.0
    previous: RoadOption | None = None
    for i, (transform, option) in enumerate(plan):
        starts = option != previous and previous not in LANE_CHANGES
        if option in LANE_CHANGES or starts or driven > spacing or i == len(plan) - 1:
            keep.append(i)
            driven = 0.0
        else:
            driven += transform.location.distance(plan[i - 1][0].location)
        previous = option
    return keep


__all__ = ["PLAN_SPACING", "AutonomousAgent", "Track", "downsample_plan"]
