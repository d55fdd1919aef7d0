"""The detour planner's settings and the names it reports (:mod:`cmudrive.agents.expert.detour`): why a
path is shifted, which lane beside the route a shift borrows, and every distance, time and margin the
detection (``detour_detect``), the path fitting (``detour_path``) and the gap check (``detour_gap``) read.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum


class DetourReason(IntEnum):
    """Why a CAV's path is shifted (or not)."""

    NONE = 0
    OBSTACLE = 1  # around an obstacle within the CAV's lane or a same-direction lane
    ONCOMING_LANE = 2  # around an obstacle through the oncoming lane (the *TwoWays types)
    INVADING = 3  # right, away from oncoming vehicles over the centre line (InvadingTurn)
    EMERGENCY = 4  # aside for an emergency vehicle coming from behind (YieldToEmergencyVehicle)
    BLOCKED = 5  # an obstacle blocks the lane and the road has no room to pass it: no shift


class Borrow(IntEnum):
    """The lane beside the CAV's lane that a shift moves into."""

    NONE = 0  # none there (road edge)
    SAME = 1  # a same-direction driving lane
    ONCOMING = 2  # the oncoming lane of a two-way road


@dataclass(frozen=True)
class DetourConfig:
    horizon: int = 80  # [route points = m] offsets returned for this many points from the CAV's progress
    look_ahead: float = 50.0  # [m] obstacles this far ahead along the route are gone around
    reach: float = 60.0  # [m] actors farther than this from a CAV are not looked at (except for a gap)
    traffic_reach: float = 200.0  # [m] at most this far for traffic when a borrowed lane must be clear
    margin: float = 0.6  # [m] lateral clearance the shifted CAV keeps to an obstacle
    block_margin: float = 0.3  # [m] an obstacle this close to the CAV's side of the unshifted path blocks
    invading_margin: float = 0.5  # [m] clearance kept to an oncoming vehicle over the centre line
    edge_margin: float = 0.2  # [m] the CAV's side stays this far inside the paved road's edge
    transition: float = 8.0  # [m] ramp length before and after an obstacle
    transition_construction: float = 10.5  # [m] ramp length around cones (ConstructionObstacle)
    min_transition: float = 4.0  # [m] shortest ramp when an obstacle is found late (or when hurrying back)
    hurry_distance: float = 15.0  # [m] an oncoming vehicle this close ahead of a CAV past the obstacles ...
    hurry_time: float = 3.0  # [s] ... or closer than this at the closing speed: back over the shortest ramp
    buffer: float = 1.0  # [m] full shift from this far before the obstacle to this far past it (bumpers)
    full_lane_change: bool = True  # a shift that squeezes same-direction traffic goes to that lane's centre
    nominal_half_width: float = 0.95  # [m] half width of a vehicle assumed at a neighbour lane's centre
    traffic_clearance: float = 0.3  # [m] a shift coming closer than this to that vehicle borrows its lane
    min_standing: float = 1.0  # [s] a scenario vehicle standing this long may be an obstacle
    standing_speed: float = 0.1  # [m/s] slower counts as standing
    moving_speed: float = 0.5  # [m/s] faster counts as moving (queue leaders, invading cars)
    side_fraction: float = 0.15  # [lane widths] a standing vehicle this far off the lane centre is parked
    queue_gap: float = 10.0  # [m] a standing vehicle this close behind a moving one is queued
    stop_line_gap: float = 10.0  # [m] a standing vehicle this close before a junction entry is waiting
    bicycle_speed: float = 4.5  # [m/s] scenario bicycles slower than this are passed
    clear_margin: float = 10.0  # [m] oncoming traffic must stay this far past the end of the pass
    clear_extra_time: float = 0.2  # [s] added to the pass time
    overtake_speed: float = 50.0 / 3.6  # [m/s] assumed pass speed (PDM-Lite overtakes at <= 50 km/h)
    pass_accel: float = 3.0  # [m/s^2] assumed acceleration to the pass speed (the caller must keep up)
    rear_gap: float = 5.0  # [m] a same-direction vehicle behind must be this far back ...
    rear_time: float = 2.0  # [s] ... plus its closing speed times this
    yield_distance: float = 80.0  # [m] an emergency vehicle this close behind is yielded to
    yield_transition_time: float = 1.5  # [s] ramp length when yielding = max(transition, this x speed)
    yield_hold: float = 15.0  # [m] full shift at least this far ahead while the vehicle is behind
    stop_before_start: float = 0.0  # [m] a waiting CAV's centre stops this far before the ramp starts

    def __post_init__(self) -> None:
        if self.horizon < 2 or self.transition <= 0.0 or self.min_transition <= 0.0:
            raise ValueError(f"DetourConfig: horizon >= 2 and positive transitions needed, got {self}")
