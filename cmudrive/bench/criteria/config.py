"""Thresholds of the route criteria, as one frozen dataclass. Defaults are Bench2Drive's (``SCORING.md``)."""

from __future__ import annotations

from dataclasses import dataclass, fields


@dataclass(frozen=True)
class CriteriaConfig:
    """Every threshold the criteria use, with its unit. Unknown keys are rejected by the constructor."""

    # route completion
    completion_window: int = 2  # route points looked at beyond the current one per tick (WINDOWS_SIZE)
    completion_threshold: float = 99.0  # [%] above this and near the last point, completion is set to 100
    completion_distance: float = 10.0  # [m] "near the last point"
    # route deviation
    deviation_window: int = 6  # route points (the current one first) searched for the closest one
    deviation_distance: float = 30.0  # [m] closest of them this far or farther: deviated
    offroute_distance: float = (
        15.0  # [m] route progress made farther than this from the route counts as off route
    )
    offroute_max_fraction: float = 0.3  # off-route progress above this share of the route length: deviated
    # blocked
    blocked_time: float = 60.0  # [s] standing longer than this: blocked (stock leaderboard: 180 s)
    blocked_speed: float = 0.1  # [m/s] "standing" is slower than this
    # timeouts
    route_timeout_base: float = 300.0  # [s] route time budget before any progress
    route_timeout_speed_fraction: float = 0.1  # each metre advanced adds 1 / (this * speed limit) seconds
    # collisions
    collision_min_speed: float = 0.1  # [m/s] contacts while the CAV is slower than this are ignored
    collision_same_actor_time: float = 5.0  # [s] the same other actor counts once within this time
    collision_min_distance: float = 5.0  # [m] a contact this close to the last counted one is ignored
    # red lights
    red_light_tail_near: float = 0.8  # rear segment starts this fraction of the half length behind the centre
    red_light_tail_extra: float = 1.0  # [m] and ends this far behind the rear bumper
    stop_line_width_factor: float = 1.2  # the stop line is this many lane widths long, centred on the lane
    red_light_rearm_distance: float = 15.0  # [m] a light counts again once the CAV was this far from its line
    # stop signs
    stop_area_length: float = 4.0  # [m] the stop area: the last metres of the approach lane (front bumper)
    stop_speed: float = 0.1  # [m/s] a stop is a speed below this inside the stop area
    # lanes
    lane_margin: float = 0.5  # [m] outside a lane: farther than half its width plus this from its centre
    wrong_direction_angle: float = 120.0  # [deg] driving at this angle or more to the lane is wrong-way
    # minimum speed (recorded only)
    min_speed_checkpoints: int = 20  # equal parts of the route
    min_speed_radius: float = (
        50.0  # [m] background vehicles this close to the CAV are its surrounding traffic
    )

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not value > 0:
                raise ValueError(f"CriteriaConfig.{f.name} must be positive, got {value!r}")
        if not 0.0 < self.completion_threshold <= 100.0:
            raise ValueError(
                f"CriteriaConfig.completion_threshold must be in (0, 100], got {self.completion_threshold}"
            )
        if not 0.0 < self.wrong_direction_angle <= 180.0:
            raise ValueError(
                f"CriteriaConfig.wrong_direction_angle must be in (0, 180], got {self.wrong_direction_angle}"
            )
