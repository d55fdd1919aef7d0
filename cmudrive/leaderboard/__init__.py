"""Run agents written for the CARLA Leaderboard 2.0 / Bench2Drive on cmudrive's CAVs.

A leaderboard agent file runs here with only its imports changed (README, "Bring a leaderboard agent"):

    import carla
        -> from cmudrive.leaderboard import carla
    from leaderboard.autoagents.autonomous_agent import AutonomousAgent, Track
        -> from cmudrive.leaderboard.autonomous_agent import AutonomousAgent, Track
    from agents.navigation.local_planner import RoadOption
        -> from cmudrive.leaderboard import RoadOption

and runs with ``cmudrive eval --agent leaderboard:my_agent.py --agent-option conf=my_conf``: one instance
per CAV (:class:`LeaderboardAgent`), its ``sensors()`` made from our world (RGB cameras through our
rasteriser, speedometer, GNSS, IMU; anything else refused before the run starts, naming the sensor).

Why a package of our own instead of modules named ``carla`` and ``leaderboard`` put on the import path: a
user who also has CARLA installed keeps the real ``carla``, nothing is found by import side effects, and a
file that still imports ``carla`` fails with the line to write instead.
"""

from cmudrive.leaderboard import carla
from cmudrive.leaderboard.adapter import LeaderboardAgent, global_plan, load_leaderboard_class
from cmudrive.leaderboard.autonomous_agent import AutonomousAgent, Track, downsample_plan
from cmudrive.leaderboard.carla import Location, Rotation, Transform, VehicleControl
from cmudrive.leaderboard.geo import GeoReference, geo_reference, gnss_to_map, map_to_gnss
from cmudrive.leaderboard.sensors import PROVIDED, SensorError, SensorRig, SensorSpec, parse_sensors
from cmudrive.maps import RoadOption

__all__ = [
    "PROVIDED",
    "AutonomousAgent",
    "GeoReference",
    "LeaderboardAgent",
    "Location",
    "RoadOption",
    "Rotation",
    "SensorError",
    "SensorRig",
    "SensorSpec",
    "Track",
    "Transform",
    "VehicleControl",
    "carla",
    "downsample_plan",
    "geo_reference",
    "global_plan",
    "gnss_to_map",
    "load_leaderboard_class",
    "map_to_gnss",
    "parse_sensors",
]
