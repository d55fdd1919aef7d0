"""``cmudrive sim demo``: CAVs on lane-following autopilot among SUMO traffic, rendered as a BEV video.

It exercises the whole embedded world: background activity around the CAVs, traffic lights, pedestrians,
CAVs pushed into SUMO, collisions, and the BEV renderer. The returned :class:`DemoStats` says what
happened (collision events, CAV distance driven, background counters) so that a run can be checked
without watching it.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from rich.progress import Progress

from cmudrive.agents.autopilot import LaneFollowingAutopilot
from cmudrive.agents.base import Observations
from cmudrive.maps import RoadMap, Route, RouteError, RoutePlanner, load_map, load_scenery
from cmudrive.maps.routing import pick_far_apart
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.populated import background_stats, populated_world
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot
from cmudrive.sim.world import World, WorldConfig

if TYPE_CHECKING:
    from cmudrive.viz.bev import BevRenderer

MIN_START_SPACING = 25.0  # [m] between the start points of any two CAVs
MIN_ROUTE_LENGTH = 250.0  # [m]
MAX_FRAME_PX = 1600  # longest side of the video frame [px]
SENSOR_PANEL_PX = 512  # [px] side of the BEV window in the --sensors video


@dataclass
class DemoStats:
    ticks: int = 0
    collisions: list[tuple[float, str, str]] = field(default_factory=list)  # (time [s], actor a, actor b)
    cav_distance: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [m] per CAV
    background: dict[str, int] = field(default_factory=dict)
    max_background_vehicles: int = 0
    max_pedestrians: int = 0
    sumo_collisions: int = 0  # collisions SUMO's own lane-based check saw among its vehicles


def demo_routes(road_map: RoadMap, n: int, rng: np.random.Generator) -> list[Route]:
    """``n`` routes of at least MIN_ROUTE_LENGTH whose starts are MIN_START_SPACING apart."""
    planner = RoutePlanner(road_map)
    routes: list[Route] = []
    for _ in range(50 * n):
        if len(routes) == n:
            return routes
        try:
            route = pick_far_apart(planner, rng, min_distance=MIN_ROUTE_LENGTH, attempts=20)
        except RouteError:
            continue
        if route.length < MIN_ROUTE_LENGTH:
            continue
        starts = np.array([r.xy[0] for r in routes]).reshape(-1, 2)
        if len(starts) and np.min(np.linalg.norm(starts - route.xy[0], axis=1)) < MIN_START_SPACING:
            continue
        routes.append(route)
    raise RouteError(f"could not find {n} well-separated CAV routes on map {road_map.name!r}")


def run_demo(
    town: str | Path,
    cavs: int = 8,
    seconds: float = 30.0,
    seed: int = 0,
    output: Path | None = None,
    pixels_per_meter: float | None = None,
    follow: int | None = None,
    window: float = 100.0,
    sensors: bool = False,
) -> DemoStats:
    """Run ``cavs`` CAVs for ``seconds``; with ``output``, write a BEV video of the area their routes span
    (or, with ``follow``, a ``window``-metre view that follows that CAV). With ``sensors``, each frame
    shows what the followed CAV (CAV 0 by default) perceives: front camera | own occupancy | merged
    occupancy | a BEV window around it with every CAV's V2V link drawn as an arrow to its partner."""
    from cmudrive.viz.bev import BevRenderer
    from cmudrive.viz.video import write_video

    road_map = load_map(town)
    rng = np.random.default_rng(seed)
    routes = demo_routes(road_map, cavs, rng)
    stats = DemoStats(cav_distance=np.zeros(cavs))
    ticks = round(seconds / 0.05)
    with populated_world(WorldConfig(town=town, seed=seed), road_map, routes, BackgroundConfig()) as world:
        pilot = LaneFollowingAutopilot(road_map, routes)
        renderer = None
        perceive = _Perception(world, follow or 0) if sensors else None
        if output is not None:
            xy = np.concatenate([r.xy for r in routes])
            lo, hi = xy.min(axis=0) - 60.0, xy.max(axis=0) + 60.0
            if follow is not None or sensors:
                panel = SENSOR_PANEL_PX if sensors else MAX_FRAME_PX / 2
                ppm = pixels_per_meter or _fitting_ppm(panel / window, hi - lo)
            else:
                ppm = pixels_per_meter or min(4.0, MAX_FRAME_PX / float(np.max(hi - lo)))
            renderer = BevRenderer(road_map, ppm, bounds=(lo[0], lo[1], hi[0], hi[1]))

        def frames() -> Iterator[np.ndarray]:
            snap = world.snapshot()
            with Progress(transient=True) as progress:
                task = progress.add_task(f"demo on {road_map.name}", total=ticks)
                for _ in range(ticks):
                    rows, index = snap.cav_rows()
                    before = world.cav_state.x.copy(), world.cav_state.y.copy()
                    snap = world.tick(pilot.controls(snap, rows, index))
                    stats.cav_distance += np.hypot(
                        world.cav_state.x - before[0], world.cav_state.y - before[1]
                    )
                    _record(stats, world, snap)
                    progress.advance(task)
                    if perceive is not None:
                        perceive.observe(snap)
                    if renderer is not None:
                        paths = [r.xy for r in routes]
                        if perceive is not None:
                            yield perceive.frame(snap, renderer, window, paths)
                        elif follow is None:
                            yield renderer.render(snap, routes=paths, title=road_map.name)
                        else:
                            yield renderer.render(
                                snap, center=f"cav{follow}", size_m=window, routes=paths, title=road_map.name
                            )

        if output is not None:
            write_video(frames(), output, fps=20)
        else:
            for _ in frames():
                pass
        stats.background = background_stats(world)
        stats.sumo_collisions = world.sumo.sumo_collisions
    return stats


def _fitting_ppm(ppm: float, extent: np.ndarray) -> float:
    """``ppm`` [px/m], lowered where the pre-rendered background of ``extent`` [m] would be too large."""
    from cmudrive.viz.bev import MAX_BACKGROUND_PIXELS, MAX_BACKGROUND_SIDE

    w, h = float(extent[0]), float(extent[1])
    return min(ppm, 0.95 * MAX_BACKGROUND_SIDE / max(w, h), (0.9 * MAX_BACKGROUND_PIXELS / (w * h)) ** 0.5)


class _Perception:
    """Sensors and V2V of every CAV, as an agent declaring camera and merged occupancy gets them."""

    def __init__(self, world: World, follow: int) -> None:
        from cmudrive.agents.base import Observation
        from cmudrive.bench.observe import ObservationBuilder

        if not 0 <= follow < len(world.cav_ids):
            raise ValueError(f"cannot follow CAV {follow}: there are CAVs 0-{len(world.cav_ids) - 1}")
        self.follow = follow
        self.scenery = load_scenery(world.map)
        self.builder = ObservationBuilder(
            frozenset({Observation.CAMERA, Observation.MERGED_OCCUPANCY}),
            len(world.cav_ids),
            world.weather,
            self.scenery,
            road_map=world.map,
        )
        self.obs: Observations | None = None
        self.world = world

    def observe(self, snap: Snapshot) -> None:
        rows, index = snap.cav_rows()
        keep = self.world.cav_active[index]
        self.obs = self.builder.build(snap, snap.step, rows[keep], index[keep], privileged=False)

    def frame(
        self, snap: Snapshot, renderer: BevRenderer, window: float, paths: list[np.ndarray]
    ) -> np.ndarray:
        from cmudrive.sensors import occupancy_to_rgb
        from cmudrive.viz.sensor_view import sensor_row

        obs = self.obs
        assert obs is not None and obs.partner is not None
        links = [(f"cav{a}", f"cav{b}") for a, b in zip(obs.cav_index, obs.partner, strict=True) if b >= 0]
        at = np.flatnonzero(obs.cav_index == self.follow)
        centre = f"cav{self.follow}" if len(at) else None
        bev = renderer.render(snap, center=centre, size_m=window, routes=paths, links=links)
        assert obs.camera is not None and obs.occupancy is not None and obs.merged_occupancy is not None
        if len(at):
            i = int(at[0])
            camera, own, merged = obs.camera[i], obs.occupancy[i : i + 1], obs.merged_occupancy[i : i + 1]
            partner = int(obs.partner[i])
            merged_label = f"merged with CAV {partner}" if partner >= 0 else "merged (no partner)"
        else:  # the followed CAV has left the world: the same layout, its panels blank
            config = self.builder.config
            camera = np.zeros((config.camera.height, config.camera.width, 3), np.uint8)
            own = merged = np.zeros((1, obs.occupancy.shape[1], *config.occupancy.shape), bool)
            merged_label = "merged (CAV gone)"
        return sensor_row(
            [
                (f"CAV {self.follow} camera", camera),
                ("own occupancy", occupancy_to_rgb(own)[0]),
                (merged_label, occupancy_to_rgb(merged)[0]),
                ("BEV, V2V links", bev),
            ],
            height=SENSOR_PANEL_PX,
        )


def _record(stats: DemoStats, world: World, snap: Snapshot) -> None:
    stats.ticks += 1
    ev = world.collisions
    for a, b in zip(ev.id_a.tolist(), ev.id_b.tolist(), strict=True):
        stats.collisions.append((snap.time, a, b))
    background = snap.role == Role.BACKGROUND
    stats.max_background_vehicles = max(
        stats.max_background_vehicles, int(np.count_nonzero(background & (snap.kind != ActorKind.PEDESTRIAN)))
    )
    stats.max_pedestrians = max(
        stats.max_pedestrians, int(np.count_nonzero(snap.kind == ActorKind.PEDESTRIAN))
    )
