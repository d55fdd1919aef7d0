"""Sensors: each CAV's front camera, what it can see, and its BEV occupancy in its own frame.

Typical use, per tick for the CAVs at snapshot rows ``rows``::

    from cmudrive.sensors import FrontCamera, CameraConfig
    images = FrontCamera(CameraConfig(), road_map, scenery).render(snap, rows, weather)  # (n, 128, 256, 3)

    from cmudrive.sensors import compute_visibility, SimulatedOccupancy, PerceptionFrame
    vis = compute_visibility(snap, rows, weather.visibility, scenery)
    grids = SimulatedOccupancy()(PerceptionFrame(snap, rows, vis, scenery))   # (n, 4, 192, 128) bool
"""

from cmudrive.sensors.camera import CameraConfig, FrontCamera
from cmudrive.sensors.occupancy import (
    NUM_CLASSES,
    DetectionNoise,
    OccupancyClass,
    OccupancyConfig,
    OccupancyModel,
    PerceptionFrame,
    SimulatedOccupancy,
    occupancy_to_rgb,
)
from cmudrive.sensors.visibility import Visibility, VisibilityConfig, camera_poses, compute_visibility

__all__ = [
    "NUM_CLASSES",
    "CameraConfig",
    "DetectionNoise",
    "FrontCamera",
    "OccupancyClass",
    "OccupancyConfig",
    "OccupancyModel",
    "PerceptionFrame",
    "SimulatedOccupancy",
    "Visibility",
    "VisibilityConfig",
    "camera_poses",
    "compute_visibility",
    "occupancy_to_rgb",
]
