"""Whether the lane a detour borrows is clear: the expert's gap check before it pulls out.

An oncoming vehicle blocks the pass when, at its own speed, it would come closer than ``clear_margin`` to
where the CAV is back in its lane by the time the CAV gets there; a same-direction vehicle blocks it when
it is beside the CAV or closing from behind (``DetourConfig``'s ``rear_gap`` and ``rear_time``). The
planner (:mod:`cmudrive.agents.expert.detour`) keeps a CAV waiting before the ramp while this returns
vehicles.
"""

from __future__ import annotations

import numpy as np

from cmudrive.agents.expert.detour_config import DetourConfig
from cmudrive.agents.expert.detour_detect import Ego
from cmudrive.agents.expert.detour_path import RouteLanes, Segment
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot


def busy_traffic(
    lanes: RouteLanes,
    snap: Snapshot,
    seg: Segment,
    me: int,
    i: int,
    k_ego: int,
    ego: Ego,
    v_e: float,
    cfg: DetourConfig,
) -> np.ndarray:
    """Snapshot rows of vehicles that keep the lane ``seg`` borrows busy (empty: clear to go).

    Oncoming: not yet passed the CAV and, at its speed, closer than ``clear_margin`` past the point
    where the CAV is back in its lane (halfway down the ramp) by the time the CAV gets there (pass
    speed ``overtake_speed`` or the limit, reached at ``pass_accel``; + ``clear_extra_time``).
    Same direction: beside the CAV, or behind it closer than ``rear_gap`` + closing speed x
    ``rear_time``."""
    v_pass = max(min(cfg.overtake_speed, float(lanes.speed_limit[i, k_ego])), 1.0)
    back = 0.5 * (seg.p1 + seg.s1)  # [m] the CAV is back in its lane about here
    dist = max(back - ego.s, 0.0)
    t_pass = travel_time(dist, v_e, v_pass, cfg.pass_accel) + cfg.clear_extra_time
    reach = min(cfg.traffic_reach, max(dist + v_pass * t_pass + cfg.clear_margin, cfg.reach))
    p = lanes.pairs(snap, np.array([me]), np.array([i]), np.array([k_ego]), np.array([reach]), cfg)
    p = p.subset(p.row != me)
    kind, role = snap.kind[p.row], snap.role[p.row]
    mobile = ~np.isin(kind, [ActorKind.PROP, ActorKind.PEDESTRIAN]) & (role != Role.PROP)
    mobile &= ~np.isin(p.row, seg.rows)
    d = p.d if seg.amp > 0.0 else -p.d
    band = (d > p.half_w) & (d - p.half_lat < abs(seg.amp) + ego.half_width + cfg.traffic_clearance)
    speed = np.abs(snap.speed[p.row])
    not_passed = p.s + p.half_lon > ego.s - ego.half_len
    arrives = p.s - p.half_lon - speed * t_pass < back + cfg.clear_margin
    oncoming = (p.cos < -0.5) & not_passed & arrives
    rear = ego.s - ego.half_len - cfg.rear_gap - np.maximum(speed - v_e, 0.0) * cfg.rear_time
    same = (p.cos > 0.5) & (p.s + p.half_lon > rear) & (p.s - p.half_lon < ego.s + ego.half_len + 2.0)
    return p.row[mobile & band & (oncoming | same)]


def travel_time(dist: float, v0: float, v1: float, accel: float) -> float:
    """[s] to drive ``dist`` m from speed v0, accelerating at ``accel`` up to v1 (or holding v0 >= v1)."""
    if v0 >= v1:
        return dist / v1
    d_acc = (v1 * v1 - v0 * v0) / (2.0 * accel)
    if dist <= d_acc:
        return (np.sqrt(v0 * v0 + 2.0 * accel * dist) - v0) / accel
    return (v1 - v0) / accel + (dist - d_acc) / v1
