"""Building each tick's :class:`~cmudrive.agents.base.Observations`: ego state always, and the sensors and
V2V an agent declared, computed batched over the active CAVs and only when asked for.

Per tick, in order (each step only when some declared observation needs it):

1. visibility of every actor and scenery object from each CAV's camera (``VISIBILITY``, ``OCCUPANCY``,
   ``MERGED_OCCUPANCY``);
2. the front camera images (``CAMERA``);
3. each CAV's own occupancy from what it sees (``OCCUPANCY``, ``MERGED_OCCUPANCY``);
4. V2V: partners (the default, or the ones the agent named after the last tick), the link, and the
   merged occupancy (``MERGED_OCCUPANCY``, ``V2V``).

The other CAVs' poses relative to each CAV come with every observation (the V2V-VLA prompt lists them).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cmudrive.agents.base import Observation, Observations
from cmudrive.maps import RoadMap
from cmudrive.maps.scenery import StaticScenery
from cmudrive.sensors.camera import CameraConfig, FrontCamera
from cmudrive.sensors.occupancy import (
    DetectionNoise,
    OccupancyConfig,
    OccupancyModel,
    PerceptionFrame,
    SimulatedOccupancy,
)
from cmudrive.sensors.visibility import Visibility, VisibilityConfig, compute_visibility
from cmudrive.sim.snapshot import Snapshot
from cmudrive.sim.weather import Weather
from cmudrive.v2v import LinkConfig, LinkStats, PartnerConfig, V2VNetwork

NEEDS_VISIBILITY = frozenset(
    {Observation.VISIBILITY, Observation.OCCUPANCY, Observation.MERGED_OCCUPANCY, Observation.V2V}
)
NEEDS_OCCUPANCY = frozenset({Observation.OCCUPANCY, Observation.MERGED_OCCUPANCY, Observation.V2V})
NEEDS_V2V = frozenset({Observation.MERGED_OCCUPANCY, Observation.V2V})


@dataclass(frozen=True)
class SensorConfig:
    """Sensor and V2V settings of an evaluation (defaults: the paper's set-up, an ideal link)."""

    camera: CameraConfig = field(default_factory=CameraConfig)
    visibility: VisibilityConfig = field(default_factory=VisibilityConfig)
    occupancy: OccupancyConfig = field(default_factory=OccupancyConfig)
    noise: DetectionNoise = field(default_factory=DetectionNoise)
    link: LinkConfig = field(default_factory=LinkConfig)
    partners: PartnerConfig = field(default_factory=PartnerConfig)

    def __post_init__(self) -> None:
        cam, vis = self.camera, self.visibility
        if (cam.fov_deg, cam.mount_x) != (vis.fov_deg, vis.mount_x):
            raise ValueError(
                f"the camera (fov {cam.fov_deg} deg, {cam.mount_x} m along the heading) and the visibility "
                f"model (fov {vis.fov_deg} deg, {vis.mount_x} m) must describe the same camera"
            )


def relative_poses(
    x: np.ndarray, y: np.ndarray, yaw: np.ndarray, cav_index: np.ndarray, num_cavs: int
) -> np.ndarray:
    """(n, num_cavs, 3): every CAV's pose (x forward, y left [m], yaw [rad]) in each active CAV's frame;
    NaN for the CAV itself and for CAVs not active."""
    n = len(cav_index)
    out = np.full((n, num_cavs, 3), np.nan)
    if n == 0:
        return out
    dx = x[None, :] - x[:, None]
    dy = y[None, :] - y[:, None]
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    rel_yaw = (yaw[None, :] - yaw[:, None] + np.pi) % (2 * np.pi) - np.pi
    block = np.stack([c * dx + s * dy, -s * dx + c * dy, rel_yaw], axis=-1)  # (n, n, 3)
    block[np.arange(n), np.arange(n)] = np.nan
    out[:, cav_index] = block
    return out


class ObservationBuilder:
    """Turns snapshots into the observations one agent declared, for one route. The camera is built
    from ``road_map`` when the agent declared it (its meshes take ~0.2 s per map, its first render in a
    fresh install compiles for several seconds)."""

    def __init__(
        self,
        declared: frozenset[Observation],
        num_cavs: int,
        weather: Weather,
        scenery: StaticScenery | None = None,
        config: SensorConfig | None = None,
        rng: np.random.Generator | None = None,
        road_map: RoadMap | None = None,
        occupancy_model: OccupancyModel | None = None,
    ) -> None:
        self.declared = declared
        self.num_cavs = num_cavs
        self.weather = weather
        self.scenery = scenery if scenery is not None else StaticScenery.empty()
        self.config = config or SensorConfig()
        rng = rng if rng is not None else np.random.default_rng(0)
        self.camera: FrontCamera | None = None
        if Observation.CAMERA in declared:
            if road_map is None:
                raise ValueError("the agent asks for camera images: the observation builder needs the map")
            self.camera = FrontCamera(self.config.camera, road_map, self.scenery)
        self.occupancy_model: OccupancyModel = occupancy_model or SimulatedOccupancy(
            self.config.occupancy, self.config.noise, rng
        )
        self.network = (
            V2VNetwork(self.config.occupancy, self.config.link, self.config.partners, rng)
            if declared & NEEDS_V2V
            else None
        )
        self.last_visibility: Visibility | None = None
        self.last_partner: np.ndarray | None = None  # (n,) of the last tick, for videos

    @property
    def link_stats(self) -> LinkStats | None:
        return self.network.stats if self.network is not None else None

    def build(
        self,
        snap: Snapshot,
        tick: int,
        rows: np.ndarray,
        cav_index: np.ndarray,
        privileged: bool,
        requested_partners: np.ndarray | None = None,
    ) -> Observations:
        d = self.declared
        x, y, yaw = snap.x[rows], snap.y[rows], snap.yaw[rows]
        extra: dict[str, object] = {}
        vis = None
        if d & NEEDS_VISIBILITY:
            vis = compute_visibility(
                snap, rows, self.weather.visibility, self.scenery, self.config.visibility
            )
            self.last_visibility = vis
            if Observation.VISIBILITY in d:
                extra["visible"] = vis.actors
                extra["visible_scenery"] = vis.scenery
        camera = None
        if self.camera is not None:
            camera = self.camera.render(snap, rows, self.weather)
            extra["camera"] = camera
        if d & NEEDS_OCCUPANCY:
            assert vis is not None
            own = self.occupancy_model(PerceptionFrame(snap, rows, vis, self.scenery, camera))
            extra["occupancy"] = own
            if self.network is not None:
                pose = np.stack([x, y, yaw], axis=1)
                ex = self.network.exchange(tick, cav_index, pose, own, requested_partners)
                extra["partner"] = ex.partner
                extra["partner_received"] = ex.received
                extra["merged_occupancy"] = ex.merged
                self.last_partner = ex.partner
        return Observations(
            tick=tick,
            time=snap.time,
            cav_index=cav_index,
            x=x,
            y=y,
            yaw=yaw,
            speed=snap.speed[rows],
            accel=snap.accel[rows],
            other_cavs=relative_poses(x, y, yaw, cav_index, self.num_cavs),
            snapshot=snap if privileged else None,
            **extra,  # type: ignore[arg-type]
        )
