"""A route's free actors in the world: the pedestrians, bicycles, vehicles and props that another
benchmark's route places outside any scenario (``RouteSpec.actors``, imported by
``cmudrive.bench.authoring.interdrive``).

They appear when the route starts, before the first tick, and do what the route says: a moving actor
follows its waypoints as a polyline at its speed (a :class:`~cmudrive.bench.scenarios.behaviours.PathMotion`,
as scenario adversaries do) and stands at the last one when it gets there; a standing one (a static prop,
a parked vehicle, an actor with one waypoint or no speed) stays where it was placed for the whole route.
They are layer actors of the world (``World.add_layer_actor``): the collision checks, the sensors and the
criteria see them like any scenario actor, and a collision is charged by the kind of their actor type
(pedestrian, vehicle, or layout for props). They ignore the CAVs, as a replayed actor does: they have no
reaction of their own, which is what the source formats give them (waypoints and a speed).
"""

from __future__ import annotations

import numpy as np

from cmudrive.bench.route_spec import ActorSpec, RouteSpec
from cmudrive.bench.scenarios.behaviours import PathMotion
from cmudrive.sim.snapshot import Role
from cmudrive.sim.world import World

ACTOR_PREFIX = "actor:"  # layer ids are ``actor:<id>``, apart from scenario actors (``<scenario>:<suffix>``)


def _path(actor: ActorSpec) -> np.ndarray:
    """(n, 2) map-frame polyline of a moving actor, repeated points dropped."""
    xy = actor.map_waypoints()
    keep = np.concatenate([[True], np.linalg.norm(np.diff(xy, axis=0), axis=1) > 1e-6])
    return xy[keep]


class RouteActors:
    """The free actors of one route, spawned into ``world`` at construction and moved by :meth:`update`."""

    def __init__(self, spec: RouteSpec, world: World) -> None:
        self.world = world
        self.motions: dict[str, PathMotion] = {}  # layer id -> its motion (moving actors only)
        self.ids: list[str] = []
        for actor in spec.actors:
            actor_id = f"{ACTOR_PREFIX}{actor.id}"
            path = _path(actor) if actor.moves else actor.map_waypoints()[:1]
            if actor.moves and len(path) >= 2:
                motion = PathMotion(path, actor.speed)
                xy, yaw = motion.pose()
                self.motions[actor_id] = motion
                speed = motion.current_speed
            else:
                xy, yaw, speed = path[0], actor.map_yaw(), 0.0
            role = Role.PROP if actor.static else Role.SCENARIO
            world.add_layer_actor(actor_id, actor.type, float(xy[0]), float(xy[1]), float(yaw), speed, role)
            self.ids.append(actor_id)

    def update(self, dt: float) -> None:
        """Move every moving actor ``dt`` [s] along its path (once per tick, before the world ticks)."""
        for actor_id, motion in self.motions.items():
            if motion.done:
                continue
            motion.advance(dt)
            xy, yaw = motion.pose()
            self.world.set_layer_pose(actor_id, float(xy[0]), float(xy[1]), yaw, motion.current_speed)


__all__ = ["ACTOR_PREFIX", "RouteActors"]
