"""Which CAV each CAV talks to: one partner per CAV and tick.

The default partner of a CAV is the closest other active CAV *in front* of it: its centre lies within
``front_half_angle_deg`` (60 deg) of the ego's heading, measured from the ego's centre, and within
``range_m`` (70 m, OpenCOOD's communication range). When no CAV is in front, the closest CAV within
range at any bearing is taken (a partner behind still shares what it sees beside and behind the ego);
with no CAV in range the ego has no partner (-1) and its merged map is its own.

An agent may name a partner for the next tick (V2V-VLA's communication output); a named partner
replaces the default when it is active, is not the ego itself, and is within range; otherwise the
default stands.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NO_PARTNER = -1


@dataclass(frozen=True)
class PartnerConfig:
    front_half_angle_deg: float = 60.0  # [deg] "in front": bearing within this of the ego heading
    range_m: float = 70.0  # [m] farthest partner (centre to centre)

    def __post_init__(self) -> None:
        if not 0.0 < self.front_half_angle_deg <= 180.0:
            raise ValueError(f"front_half_angle_deg must be in (0, 180], got {self.front_half_angle_deg}")
        if not self.range_m > 0.0:
            raise ValueError(f"range_m must be positive, got {self.range_m}")


def select_partners(
    x: np.ndarray,
    y: np.ndarray,
    yaw: np.ndarray,
    cav_index: np.ndarray,
    requested: np.ndarray | None = None,
    config: PartnerConfig | None = None,
) -> np.ndarray:
    """(n,) partner CAV index for each of the ``n`` active CAVs (poses (n,), CAV indices (n,)), or -1.

    ``requested`` (n,) CAV indices named by the agent for this tick, -1 where it named none."""
    config = config or PartnerConfig()
    n = len(cav_index)
    if n == 0:
        return np.zeros(0, np.int64)
    dx = x[None, :] - x[:, None]  # (ego, other)
    dy = y[None, :] - y[:, None]
    dist = np.hypot(dx, dy)
    bearing = np.arctan2(dy, dx) - yaw[:, None]
    bearing = (bearing + np.pi) % (2 * np.pi) - np.pi
    in_range = (dist <= config.range_m) & ~np.eye(n, dtype=bool)
    in_front = in_range & (np.abs(bearing) <= np.radians(config.front_half_angle_deg))
    front_dist = np.where(in_front, dist, np.inf)
    any_dist = np.where(in_range, dist, np.inf)
    pick = np.where(in_front.any(axis=1), front_dist.argmin(axis=1), any_dist.argmin(axis=1))
    partner = np.where(in_range.any(axis=1), cav_index[pick], NO_PARTNER)
    if requested is not None:
        requested = np.asarray(requested, np.int64)
        if requested.shape != (n,):
            raise ValueError(f"requested partners have shape {requested.shape}, expected ({n},)")
        slot = {int(c): j for j, c in enumerate(cav_index)}
        for i, req in enumerate(requested):  # n <= 16: not a hot loop
            j = slot.get(int(req), -1)
            if j >= 0 and in_range[i, j]:
                partner[i] = req
    return partner.astype(np.int64)
