"""Actor types as data: extents, dynamics limits and SUMO parameters of every kind of actor.

Each :class:`ActorType` becomes a SUMO ``vType`` (``vehicletype.copy`` + setters at world start) and is
the single source of the extents that the snapshot, collisions and sensors use. Numbers are for typical
European/US vehicles (CARLA's blueprints are in the same range); each carries its unit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from cmudrive.sim.snapshot import ActorKind


@dataclass(frozen=True)
class ActorType:
    """One kind of actor. SUMO-only fields are ignored for actors that our layer moves."""

    name: str
    kind: ActorKind
    vclass: str  # SUMO vehicle class ("passenger", "delivery", "truck", "bicycle", "pedestrian", ...)
    length: float  # [m]
    width: float  # [m]
    height: float  # [m], for the camera renderer
    accel: float  # [m/s^2] comfortable maximum acceleration
    decel: float  # [m/s^2] comfortable deceleration
    emergency_decel: float  # [m/s^2] physical maximum deceleration on dry road
    max_speed: float  # [m/s]
    speed_factor: float = 1.0  # mean multiplier of the speed limit the driver chooses
    speed_dev: float = 0.1  # standard deviation of that multiplier
    sigma: float = 0.5  # Krauss driver imperfection [0, 1]
    min_gap: float = 2.5  # [m] standstill gap to the leader
    tau: float = 1.0  # [s] desired time headway
    colour: tuple[int, int, int] = (120, 130, 150)  # RGB for renderers
    params: dict[str, str] = field(default_factory=dict)  # extra SUMO vType parameters
    static: bool = False  # never moves (props, parked cars): SUMO class "ignoring", placed where it stands


ACTOR_TYPES: dict[str, ActorType] = {
    t.name: t
    for t in (
        # connected autonomous vehicle: a mid-size sedan (CARLA's Lincoln MKZ 2020 is 4.89 x 2.10 m)
        ActorType(
            "cav",
            ActorKind.CAR,
            "passenger",
            length=4.89,
            width=2.10,
            height=1.5,
            accel=3.5,
            decel=4.5,
            emergency_decel=8.0,
            max_speed=30.0,
            speed_factor=1.0,
            speed_dev=0.0,
            sigma=0.0,
            colour=(30, 120, 255),
        ),
        ActorType(
            "car",
            ActorKind.CAR,
            "passenger",
            length=4.5,
            width=1.85,
            height=1.5,
            accel=2.6,
            decel=4.5,
            emergency_decel=8.0,
            max_speed=50.0,
            speed_factor=1.0,
            speed_dev=0.1,
            colour=(150, 160, 180),
        ),
        ActorType(
            "van",
            ActorKind.VAN,
            "delivery",
            length=5.4,
            width=2.05,
            height=2.3,
            accel=2.0,
            decel=4.0,
            emergency_decel=7.5,
            max_speed=38.0,
            speed_factor=0.95,
            speed_dev=0.1,
            colour=(190, 190, 170),
        ),
        ActorType(
            "truck",
            ActorKind.TRUCK,
            "truck",
            length=8.5,
            width=2.5,
            height=3.4,
            accel=1.3,
            decel=4.0,
            emergency_decel=7.0,
            max_speed=33.0,
            speed_factor=0.9,
            speed_dev=0.08,
            min_gap=3.0,
            tau=1.5,
            colour=(170, 140, 110),
        ),
        ActorType(
            "bus",
            ActorKind.BUS,
            "bus",
            length=12.0,
            width=2.55,
            height=3.2,
            accel=1.2,
            decel=4.0,
            emergency_decel=7.0,
            max_speed=25.0,
            speed_factor=0.9,
            speed_dev=0.05,
            min_gap=3.0,
            tau=1.5,
            colour=(220, 180, 60),
        ),
        ActorType(
            "motorcycle",
            ActorKind.MOTORCYCLE,
            "motorcycle",
            length=2.2,
            width=0.8,
            height=1.4,
            accel=4.0,
            decel=5.0,
            emergency_decel=9.0,
            max_speed=45.0,
            speed_factor=1.05,
            speed_dev=0.12,
            colour=(120, 90, 160),
        ),
        ActorType(
            "bicycle",
            ActorKind.BICYCLE,
            "bicycle",
            length=1.8,
            width=0.65,
            height=1.7,
            accel=1.2,
            decel=3.0,
            emergency_decel=6.0,
            max_speed=7.0,
            speed_factor=1.0,
            speed_dev=0.15,
            min_gap=1.0,
            colour=(60, 170, 90),
        ),
        ActorType(
            "pedestrian",
            ActorKind.PEDESTRIAN,
            "pedestrian",
            length=0.5,
            width=0.6,
            height=1.75,
            accel=1.5,
            decel=2.0,
            emergency_decel=5.0,
            max_speed=1.8,
            speed_factor=1.0,
            speed_dev=0.15,
            min_gap=0.25,
            colour=(240, 120, 60),
        ),
        # emergency vehicle with SUMO's bluelight device: others form a rescue lane and let it pass
        ActorType(
            "ambulance",
            ActorKind.EMERGENCY,
            "emergency",
            length=6.2,
            width=2.3,
            height=2.8,
            accel=3.0,
            decel=5.0,
            emergency_decel=8.0,
            max_speed=36.0,
            speed_factor=1.3,
            speed_dev=0.0,
            sigma=0.0,
            colour=(230, 40, 40),
            params={"has.bluelight.device": "true"},
        ),
        ActorType(
            "police",
            ActorKind.EMERGENCY,
            "emergency",
            length=5.0,
            width=2.0,
            height=1.5,
            accel=3.5,
            decel=5.0,
            emergency_decel=8.0,
            max_speed=45.0,
            speed_factor=1.3,
            speed_dev=0.0,
            sigma=0.0,
            colour=(40, 60, 230),
            params={"has.bluelight.device": "true"},
        ),
        # static props: stopped SUMO vehicles of vClass "custom2" that traffic must drive around
        ActorType(
            "parked_car",
            ActorKind.PROP,
            "custom2",
            length=4.5,
            width=1.85,
            height=1.5,
            accel=0.0,
            decel=1.0,
            emergency_decel=1.0,
            max_speed=0.0,
            colour=(110, 110, 120),
        ),
        ActorType(
            "cone",
            ActorKind.PROP,
            "custom2",
            length=0.4,
            width=0.4,
            height=0.7,
            accel=0.0,
            decel=1.0,
            emergency_decel=1.0,
            max_speed=0.0,
            colour=(255, 140, 0),
        ),
        ActorType(
            "warning_sign",
            ActorKind.PROP,
            "custom2",
            length=0.3,
            width=1.2,
            height=1.5,
            accel=0.0,
            decel=1.0,
            emergency_decel=1.0,
            max_speed=0.0,
            colour=(255, 200, 0),
        ),
        # an open car door (VehicleOpensDoorTwoWays): part of a vehicle, so a contact is a vehicle collision
        ActorType(
            "car_door",
            ActorKind.CAR,
            "custom2",
            length=1.0,
            width=0.15,
            height=1.2,
            accel=0.0,
            decel=1.0,
            emergency_decel=1.0,
            max_speed=0.0,
            colour=(110, 110, 120),
        ),
        # occluders scenarios stand on a sidewalk (CARLA: advertisement board, vending machine, container)
        ActorType(
            "advertisement",
            ActorKind.PROP,
            "custom2",
            length=2.4,
            width=0.4,
            height=2.3,
            accel=0.0,
            decel=1.0,
            emergency_decel=1.0,
            max_speed=0.0,
            colour=(200, 200, 220),
        ),
        ActorType(
            "vending_machine",
            ActorKind.PROP,
            "custom2",
            length=1.0,
            width=0.8,
            height=1.9,
            accel=0.0,
            decel=1.0,
            emergency_decel=1.0,
            max_speed=0.0,
            colour=(200, 60, 60),
        ),
        ActorType(
            "container",
            ActorKind.PROP,
            "custom2",
            length=6.0,
            width=2.4,
            height=2.6,
            accel=0.0,
            decel=1.0,
            emergency_decel=1.0,
            max_speed=0.0,
            colour=(60, 110, 160),
        ),
    )
}

BACKGROUND_VEHICLE_MIX: dict[str, float] = {  # share of background vehicles by type
    "car": 0.78,
    "van": 0.08,
    "truck": 0.05,
    "bus": 0.02,
    "motorcycle": 0.03,
    "bicycle": 0.04,
}


def actor_type(name: str) -> ActorType:
    try:
        return ACTOR_TYPES[name]
    except KeyError:
        raise ValueError(f"unknown actor type {name!r}; known: {', '.join(ACTOR_TYPES)}") from None
