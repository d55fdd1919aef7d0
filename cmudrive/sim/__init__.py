"""The embedded simulator: SUMO world (libsumo) + our CAV dynamics, actors, snapshot and collisions.

Typical use::

    from cmudrive.sim import World, WorldConfig, Controls
    with World(WorldConfig("downtown", seed=0)) as world:
        world.add_cav(route)                       # a cmudrive.maps.Route
        snap = world.tick(Controls.zeros(1))       # one 0.05 s step; snap is a Snapshot of arrays
"""

from cmudrive.sim.actor_types import ACTOR_TYPES, ActorType, actor_type
from cmudrive.sim.collisions import TOUCH_TOLERANCE, CollisionEvents, detect_collisions
from cmudrive.sim.dynamics import (
    CavState,
    ControlError,
    Controls,
    VehicleParams,
    check_controls,
    step_bicycle,
    validate_controls,
)
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot
from cmudrive.sim.sumo import SumoError
from cmudrive.sim.traffic_lights import TrafficLights, link_states
from cmudrive.sim.weather import WEATHERS, Weather, get_weather, weather_from_carla
from cmudrive.sim.world import World, WorldConfig

__all__ = [
    "ACTOR_TYPES",
    "TOUCH_TOLERANCE",
    "WEATHERS",
    "ActorKind",
    "ActorType",
    "CavState",
    "CollisionEvents",
    "ControlError",
    "Controls",
    "Role",
    "Snapshot",
    "SumoError",
    "TrafficLights",
    "VehicleParams",
    "Weather",
    "World",
    "WorldConfig",
    "actor_type",
    "check_controls",
    "detect_collisions",
    "get_weather",
    "link_states",
    "step_bicycle",
    "validate_controls",
    "weather_from_carla",
]
