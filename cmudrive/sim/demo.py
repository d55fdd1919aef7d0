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

import numpy as np
from rich.progress import Progress

from cmudrive.agents.autopilot import LaneFollowingAutopilot
from cmudrive.maps import RoadMap, Route, RouteError, RoutePlanner, load_map
from cmudrive.maps.routing import pick_far_apart
from cmudrive.sim.background import BackgroundActivity, BackgroundConfig
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot
from cmudrive.sim.world import World, WorldConfig

MIN_START_SPACING = 25.0  # [m] between the start points of any two CAVs
MIN_ROUTE_LENGTH = 250.0  # [m]
MAX_FRAME_PX = 1600  # longest side of the video frame [px]


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
) -> DemoStats:
    """Run ``cavs`` CAVs for ``seconds``; with ``output``, write a BEV video of the area their routes span
    (or, with ``follow``, a ``window``-metre view that follows that CAV)."""
    from cmudrive.viz.bev import BevRenderer
    from cmudrive.viz.video import write_video

    road_map = load_map(town)
    rng = np.random.default_rng(seed)
    routes = demo_routes(road_map, cavs, rng)
    stats = DemoStats(cav_distance=np.zeros(cavs))
    ticks = round(seconds / 0.05)
    with World(WorldConfig(town=town, seed=seed), road_map=road_map) as world:
        for route in routes:
            world.add_cav(route)
        world.background = BackgroundActivity(BackgroundConfig())
        world.background.populate(world)
        pilot = LaneFollowingAutopilot(road_map, routes)
        renderer = None
        if output is not None:
            xy = np.concatenate([r.xy for r in routes])
            lo, hi = xy.min(axis=0) - 60.0, xy.max(axis=0) + 60.0
            if follow is not None:
                ppm = pixels_per_meter or MAX_FRAME_PX / 2 / window
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
                    if renderer is not None:
                        paths = [r.xy for r in routes]
                        if follow is None:
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
        stats.background = dict(world.background.stats)
        stats.sumo_collisions = world.sumo.sumo_collisions
    return stats


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
