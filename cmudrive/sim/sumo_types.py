"""Our actor types as SUMO vehicle types: every :data:`~cmudrive.sim.actor_types.ACTOR_TYPES` entry becomes
a vType (copied from SUMO's default car, bicycle or pedestrian type) with its size, speeds, car-following
parameters and colour, deceleration scaled by the weather's road friction. ``start_sumo`` calls
:func:`define_vehicle_types` once per simulation.
"""

from __future__ import annotations

from cmudrive.sim.actor_types import ACTOR_TYPES, ActorType
from cmudrive.sim.snapshot import ActorKind


def define_vehicle_types(friction: float) -> None:
    """Create every :data:`ACTOR_TYPES` entry as a SUMO vType (deceleration scaled by road friction)."""
    import libsumo

    existing = set(libsumo.vehicletype.getIDList())
    for t in ACTOR_TYPES.values():
        if t.kind == ActorKind.PEDESTRIAN:
            base = "DEFAULT_PEDTYPE"
        elif t.kind == ActorKind.BICYCLE:
            base = "DEFAULT_BIKETYPE"
        else:
            base = "DEFAULT_VEHTYPE"
        if t.name not in existing:
            libsumo.vehicletype.copy(base, t.name)
        _apply_type(t, friction)


def _apply_type(t: ActorType, friction: float) -> None:
    import libsumo

    vt = libsumo.vehicletype
    vclass = "ignoring" if t.static else t.vclass
    vt.setVehicleClass(t.name, vclass)
    vt.setLength(t.name, t.length)
    vt.setWidth(t.name, t.width)
    vt.setHeight(t.name, t.height)
    vt.setMaxSpeed(t.name, max(t.max_speed, 0.1))
    vt.setMinGap(t.name, t.min_gap)
    if t.kind != ActorKind.PEDESTRIAN:
        vt.setAccel(t.name, max(t.accel, 0.1))
        vt.setDecel(t.name, t.decel * friction)
        vt.setEmergencyDecel(t.name, t.emergency_decel * friction)
        vt.setApparentDecel(t.name, t.decel * friction)
        vt.setTau(t.name, t.tau)
        vt.setImperfection(t.name, t.sigma)
    vt.setSpeedFactor(t.name, t.speed_factor)
    vt.setSpeedDeviation(t.name, t.speed_dev)
    vt.setColor(t.name, (*t.colour, 255))
    for key, value in t.params.items():
        vt.setParameter(t.name, key, value)
