"""A world set up for driving: its CAVs added, then background activity filled in around them.

Written once here for everyone who drives a world (the evaluator, the BEV demo, the engine, gridlock and
sensor benchmarks). It lives in ``sim/`` because it needs nothing above the simulator: a map, the CAV
routes and the background's configuration. The order matters and is the same for all: CAVs first (the
initial fill keeps its distance from them), then the background is bound and populated once.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

from cmudrive.maps import RoadMap, Route
from cmudrive.sim.background import BackgroundActivity, BackgroundConfig
from cmudrive.sim.world import World, WorldConfig


@contextmanager
def populated_world(
    config: WorldConfig,
    road_map: RoadMap,
    routes: Sequence[Route],
    background: BackgroundConfig | None = None,
) -> Iterator[World]:
    """The world of ``config`` on ``road_map`` with one CAV per route and its background activity
    (``background``, default :class:`BackgroundConfig`) populated; closed when the block ends."""
    with World(config, road_map=road_map) as world:
        for route in routes:
            world.add_cav(route)
        activity = BackgroundActivity(background)
        world.background = activity
        activity.populate(world)
        yield world


def background_stats(world: World) -> dict[str, int]:
    """A copy of the counters of ``world``'s background activity (spawned, removed ... by cause)."""
    if not isinstance(world.background, BackgroundActivity):
        raise TypeError(
            f"the world's background is {type(world.background).__name__}, not BackgroundActivity"
        )
    return dict(world.background.stats)
