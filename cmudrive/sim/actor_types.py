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
            4.89,
            2.10,
            1.5,
            3.5,
            4.5,
            8.0,
            30.0,
            1.0,
            0.0,
            0.0,
            colour=(30, 120, 255),
        ),
        ActorType(
            "car",
            ActorKind.CAR,
            "passenger",
            4.5,
            1.85,
            1.5,
            2.6,
            4.5,
            8.0,
            50.0,
            1.0,
            0.1,
            colour=(150, 160, 180),
        ),
        ActorType(
            "van",
            ActorKind.VAN,
            "delivery",
            5.4,
            2.05,
            2.3,
            2.0,
            4.0,
            7.5,
            38.0,
            0.95,
            0.1,
            colour=(190, 190, 170),
        ),
        ActorType(
            "truck",
            ActorKind.TRUCK,
            "truck",
            8.5,
            2.5,
            3.4,
            1.3,
            4.0,
            7.0,
            33.0,
            0.9,
            0.08,
            min_gap=3.0,
            tau=1.5,
            colour=(170, 140, 110),
        ),
        ActorType(
            "bus",
            ActorKind.BUS,
            "bus",
            12.0,
            2.55,
            3.2,
            1.2,
            4.0,
            7.0,
            25.0,
            0.9,
            0.05,
            min_gap=3.0,
            tau=1.5,
            colour=(220, 180, 60),
        ),
        ActorType(
            "motorcycle",
            ActorKind.MOTORCYCLE,
            "motorcycle",
            2.2,
            0.8,
            1.4,
            4.0,
            5.0,
            9.0,
            45.0,
            1.05,
            0.12,
            colour=(120, 90, 160),
        ),
        ActorType(
            "bicycle",
            ActorKind.BICYCLE,
            "bicycle",
            1.8,
            0.65,
            1.7,
            1.2,
            3.0,
            6.0,
            7.0,
            1.0,
            0.15,
            min_gap=1.0,
            colour=(60, 170, 90),
        ),
        ActorType(
            "pedestrian",
            ActorKind.PEDESTRIAN,
            "pedestrian",
            0.5,
            0.6,
            1.75,
            1.5,
            2.0,
            5.0,
            1.8,
            1.0,
            0.15,
            min_gap=0.25,
            colour=(240, 120, 60),
        ),
        # emergency vehicle with SUMO's bluelight device: others form a rescue lane and let it pass
        ActorType(
            "ambulance",
            ActorKind.EMERGENCY,
            "emergency",
            6.2,
            2.3,
            2.8,
            3.0,
            5.0,
            8.0,
            36.0,
            1.3,
            0.0,
            sigma=0.0,
            colour=(230, 40, 40),
            params={"has.bluelight.device": "true"},
        ),
        ActorType(
            "police",
            ActorKind.EMERGENCY,
            "emergency",
            5.0,
            2.0,
            1.5,
            3.5,
            5.0,
            8.0,
            45.0,
            1.3,
            0.0,
            sigma=0.0,
            colour=(40, 60, 230),
            params={"has.bluelight.device": "true"},
        ),
        # static props: stopped SUMO vehicles of vClass "custom2" that traffic must drive around
        ActorType(
            "parked_car",
            ActorKind.PROP,
            "custom2",
            4.5,
            1.85,
            1.5,
            0.0,
            1.0,
            1.0,
            0.0,
            colour=(110, 110, 120),
        ),
        ActorType("cone", ActorKind.PROP, "custom2", 0.4, 0.4, 0.7, 0.0, 1.0, 1.0, 0.0, colour=(255, 140, 0)),
        ActorType(
            "warning_sign", ActorKind.PROP, "custom2", 0.3, 1.2, 1.5, 0.0, 1.0, 1.0, 0.0, colour=(255, 200, 0)
        ),
        # an open car door (VehicleOpensDoorTwoWays): part of a vehicle, so a contact is a vehicle collision
        ActorType(
            "car_door", ActorKind.CAR, "custom2", 1.0, 0.15, 1.2, 0.0, 1.0, 1.0, 0.0, colour=(110, 110, 120)
        ),
        # occluders scenarios stand on a sidewalk (CARLA: advertisement board, vending machine, container)
        ActorType(
            "advertisement",
            ActorKind.PROP,
            "custom2",
            2.4,
            0.4,
            2.3,
            0.0,
            1.0,
            1.0,
            0.0,
            colour=(200, 200, 220),
        ),
        ActorType(
            "vending_machine",
            ActorKind.PROP,
            "custom2",
            1.0,
            0.8,
            1.9,
            0.0,
            1.0,
            1.0,
            0.0,
            colour=(200, 60, 60),
        ),
        ActorType(
            "container", ActorKind.PROP, "custom2", 6.0, 2.4, 2.6, 0.0, 1.0, 1.0, 0.0, colour=(60, 110, 160)
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
