"""Oncoming cars that cut the centre line: InvadingTurn (``reference/SCENARIOS.md`` #17).

A two-way road with one lane each way. At activation: the ego lane is removed from background traffic,
background oncoming traffic is paused, and cones appear on the oncoming lane, 0.4 w toward its outer
edge, every 5 m from 15 m (toward the CAV) past the flow's source while they cover less than half of
``distance``. The InvadingFlow is scripted by our layer (a path and a speed, pushed into SUMO like the
CAVs): cars start at S = the oncoming lane beside next(``distance`` + 30) every 40 m of headway, drive the
oncoming lane toward the oncoming point abreast T at the ego lane's speed limit, shifted
``offset`` + w/2 - 0.7 m toward the ego lane (so they cross the centre line by about ``offset`` + 0.2 m),
and leave at its end. End: CAV 0 is past S and within 50 m of it, or ST240; then cones and cars
are removed, the ego lane re-added and oncoming traffic resumed.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from cmudrive.bench.scenarios.base import EGO, RouteProgress, Scenario
from cmudrive.bench.scenarios.behaviours import PathMotion, ahead_of, lane_path
from cmudrive.bench.scenarios.params import Param
from cmudrive.bench.scenarios.placement import LanePoint, heading, point_xy, walk
from cmudrive.bench.scenarios.plan import PlanItem, path, point
from cmudrive.maps.model import NO_INDEX
from cmudrive.sim.snapshot import Snapshot

HEADWAY = 40.0  # [m] between invading cars
CONE_START, CONE_STEP = 15.0, 5.0  # [m]
PAST_NEAR = 50.0  # [m]


class InvadingTurn(Scenario):
    """#17: oncoming cars invade the ego lane on a two-way road."""

    type_name = "InvadingTurn"
    params: ClassVar[tuple[Param, ...]] = (
        Param("distance", "m", 100.0, lo=10.0, hi=400.0),
        Param("offset", "m", 0.25, lo=0.0, hi=2.0),
    )

    def place(self) -> None:
        m, d = self.map, self.num("distance")
        far = walk(m, self.t_wp, d + 30.0, through_junctions=True, prefer=self.route_lanes)
        opposite = int(m.lane_opposite[far.lane])
        near_opposite = int(m.lane_opposite[self.t_wp.lane])
        if opposite == NO_INDEX or near_opposite == NO_INDEX or m.lane_internal[far.lane]:
            raise self.error(
                f"no place for the scenario: no oncoming lane beside the ego lane at T and {d + 30:g} m "
                "past it"
            )
        self.s_xy, self.s_heading = point_xy(m, far), heading(m, far)
        s_src, _ = m.index.project(self.s_xy[None], np.array([opposite]))
        self.source = LanePoint(opposite, float(s_src[0]))
        length = float(np.linalg.norm(point_xy(m, self.t_wp) - self.s_xy))
        w = float(m.lane_width[opposite])
        self.shift = (
            self.num("offset") + 0.5 * w - 0.7
        )  # [m] toward the ego lane (+ left of the oncoming lane)
        self.path = lane_path(m, self.source, max(length, 1.0), self.shift)
        self.speed = float(m.lane_speed[self.t_wp.lane])
        self.cones = []
        covered, k = 0.0, 0
        while covered < 0.5 * d:
            at = walk(m, self.source, CONE_START + k * CONE_STEP, through_junctions=True)
            self.cones.append((point_xy(m, at, -0.4 * w), heading(m, at)))
            covered, k = covered + CONE_STEP, k + 1
        self.cars: list[tuple[str, PathMotion]] = []
        self.spawned = 0

    def plan(self) -> list[PlanItem]:
        items: list[PlanItem] = [point("cone", xy, yaw) for xy, yaw in self.cones]
        return [*items, path("invading", self.path)]

    def on_activate(self, snap: Snapshot) -> None:
        background = self.background
        if background is not None:
            background.remove_lane([self.t_wp.lane])
            background.opposite_traffic(False)
        for k, (xy, yaw) in enumerate(self.cones):
            self.spawn(f"cone{k}", "cone", xy, yaw, prop=True)

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        if not self.cars or self.cars[-1][1].s >= HEADWAY:
            name = f"inv{self.spawned}"
            self.spawned += 1
            motion = PathMotion(self.path, self.speed)
            xy, yaw = motion.pose()
            self.spawn(name, "car", xy, yaw, self.speed)
            self.cars.append((name, motion))
        for name, motion in list(self.cars):
            motion.advance(self.world.dt)
            if motion.done:
                self.despawn(f"{self.spec.name}:{name}")
                self.cars.remove((name, motion))
                continue
            xy, yaw = motion.pose()
            self.world.set_layer_pose(f"{self.spec.name}:{name}", xy[0], xy[1], yaw, motion.speed)
        ego = progress.xy[EGO : EGO + 1]
        past = bool(ahead_of(ego, self.s_xy, self.s_heading)[0])
        near = float(np.linalg.norm(ego[0] - self.s_xy)) < PAST_NEAR
        self.passed |= bool(progress.present[EGO]) and past and near
        return self.ego_passed()

    def on_end(self) -> None:
        background = self.background
        if background is not None:
            background.readd_lane([self.t_wp.lane])
            background.opposite_traffic(True)
