"""Rule-following at junctions and on the route, with few or no actors (``reference/SCENARIOS.md`` #3,
#31, #36-#40): BlockedIntersection, SequentialLaneChange, T_Junction, VanillaNonSignalizedTurn,
VanillaNonSignalizedTurnEncounterStopsign, VanillaSignalizedTurnEncounterGreenLight,
VanillaSignalizedTurnEncounterRedLight.

=========================================  ===============================================================
type                                       behaviour and end
=========================================  ===============================================================
BlockedIntersection                        at activation the junction is cleared of background traffic and
                                           a car (brake lights) stands 5 m past the route's junction exit;
                                           once CAV 0 is within 13 m of it, 10 s idle, then it is removed
                                           and the scenario ends; ST240
SequentialLaneChange, T_Junction           no actors: a 200 m drive counter from activation; ST240
VanillaNonSignalizedTurn(+Stopsign)        no actors: ends once CAV 0 left the junction + 10 m
VanillaSignalizedTurnEncounterGreenLight   lights: 5 s CAV 0's approach green / all others red, then 5 s
                                           all red, then released; ends when that sequence finishes or
                                           CAV 0 left the junction + 10 m
VanillaSignalizedTurnEncounterRedLight     lights: 5 s all red, then CAV 0's approach green / others red
                                           until the end (junction + 10 m), then released
=========================================  ===============================================================

"Left the junction + 10 m" and the drive counters are CAV 0's, along its route (CAV 0 is the scenario's
ego, ``base.py``). A forced light is a whole approach, as a CARLA traffic light is (``approach_lanes``:
every signalised lane of CAV 0's road into the junction), forced through ``World.lights.force_lanes`` and
held until the scenario ends; then ``release`` gives the light back to its program (the program and phase
resume, with the time the phase had left).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from cmudrive.bench.scenarios.base import EGO, RouteProgress, Scenario, first_real_junction
from cmudrive.bench.scenarios.behaviours import within
from cmudrive.bench.scenarios.placement import heading, point_xy, walk
from cmudrive.bench.scenarios.plan import PlanItem, point
from cmudrive.maps import RoadMap, Route
from cmudrive.sim.dynamics import Controls
from cmudrive.sim.snapshot import Snapshot

AFTER_JUNCTION = 10.0  # [m] driven past the junction exit
DRIVE_COUNTER = 200.0  # [m] SequentialLaneChange, T_Junction
LIGHT_PHASE = 5.0  # [s] each forced light phase


def red_then_green_stage(elapsed: float) -> int:
    """The stage of a scenario's "red, then green" light sequence ``elapsed`` s after activation: 0 the
    LIGHT_PHASE s of red, 1 the forced green, held until the scenario ends."""
    return 0 if elapsed < LIGHT_PHASE else 1


def approach_lanes(m: RoadMap, lane: int) -> list[int]:
    """The signalised lanes of ``lane``'s road (its edge) into the junction: one CARLA traffic light
    governs them all, so a scenario forces them together (``lane`` first)."""
    signalised = np.zeros(len(m.lane_edge), bool)
    signalised[m.link_from[m.link_tls >= 0]] = True
    same = np.flatnonzero((m.lane_edge == m.lane_edge[lane]) & signalised)
    return [lane, *(int(i) for i in same if i != lane)]


def exit_distance(m: RoadMap, route: Route, k0: int) -> float:
    """[m] route distance of the first point after the first junction past index ``k0`` that is not a
    mere road join (``first_real_junction``; inf: none)."""
    first = first_real_junction(m, route, k0)
    if first < 0:
        return math.inf
    after = np.flatnonzero(~route.in_junction[first:]) + first
    return float(route.distance[after[0]]) if len(after) else math.inf


class RouteRule(Scenario):
    """No-actor scenarios that end once CAV 0 drove a distance along its route: past its first junction
    after T + ``AFTER_JUNCTION`` (``counter`` None) or ``counter`` m from T."""

    uses_timeout = False
    counter: ClassVar[float | None] = None  # [m]
    needs_junction: ClassVar[bool] = True

    def place(self) -> None:
        if self.needs_junction:
            self.junction_exit()  # refuses a route without a junction after T
        r, k0 = self.ctx.routes[EGO], self.trigger_index
        if self.counter is None:  # [m] along CAV 0's route
            self.goal = exit_distance(self.map, r, k0) + AFTER_JUNCTION
        else:
            self.goal = float(r.distance[k0]) + self.counter

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        self.passed |= self.ego_driven(progress) >= self.goal
        return self.ego_passed()


class T_Junction(RouteRule):
    """#36: obey the T-junction's control; a 200 m drive counter with the scenario timeout."""

    type_name = "T_Junction"
    uses_timeout = True
    counter = DRIVE_COUNTER


class SequentialLaneChange(RouteRule):
    """#31: successive lane changes along the route; a 200 m drive counter with the scenario timeout."""

    type_name = "SequentialLaneChange"
    uses_timeout = True
    counter = DRIVE_COUNTER
    needs_junction = False


class VanillaNonSignalizedTurn(RouteRule):
    """#37: turn at an unsignalized junction; ends 10 m past its exit."""

    type_name = "VanillaNonSignalizedTurn"


class VanillaNonSignalizedTurnEncounterStopsign(RouteRule):
    """#38: turn at a stop-controlled junction (the route's stop-sign test does the checking)."""

    type_name = "VanillaNonSignalizedTurnEncounterStopsign"


class SignalizedTurn(RouteRule):
    """Forced light phases on CAV 0's approach to its junction: ``phases`` of (ego signal, others) for
    ``LIGHT_PHASE`` s each; the last one holds until the scenario ends unless ``end_with_lights``."""

    phases: ClassVar[tuple[tuple[str, str], ...]] = ()
    end_with_lights: ClassVar[bool] = False

    def place(self) -> None:
        super().place()
        before, _, _ = self.junction_exit()
        route = self.ctx.routes[0]
        self.approach = int(route.lane[before])
        self.junction = int(self.map.lane_junction[route.lane[before + 1]])
        m = self.map
        if not np.any((m.link_from == self.approach) & (m.link_tls >= 0)):
            raise self.error(
                f"no place for the scenario: CAV 0 enters its junction from lane "
                f"{m.lane_ids[self.approach]}, which has no traffic light"
            )

    def plan(self) -> list[PlanItem]:
        return [self.light_point(self.approach)]

    def on_activate(self, snap: Snapshot) -> None:
        self.phase_index = -1
        self.hold_at(self.junction)  # its forced reds

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        elapsed = self.time - self.activated_at
        k = min(int(elapsed // LIGHT_PHASE), len(self.phases))
        if k < len(self.phases) and k != self.phase_index:
            ego, others = self.phases[k]
            self.world.lights.force_lanes(approach_lanes(self.map, self.approach), ego, others)
            self.phase_index = k
        if k == len(self.phases) and self.end_with_lights:
            return True
        return super().on_update(snap, progress)

    def on_end(self) -> None:
        self.world.lights.release()


class VanillaSignalizedTurnEncounterGreenLight(SignalizedTurn):
    """#39: 5 s green for CAV 0 (others red), then 5 s all red; then the normal cycle."""

    type_name = "VanillaSignalizedTurnEncounterGreenLight"
    phases = (("G", "r"), ("r", "r"))
    end_with_lights = True


class VanillaSignalizedTurnEncounterRedLight(SignalizedTurn):
    """#40: 5 s all red, then green for CAV 0 (others red) until it left the junction."""

    type_name = "VanillaSignalizedTurnEncounterRedLight"
    phases = (("r", "r"), ("G", "r"))


class BlockedIntersection(Scenario):
    """#3: a car stands just past the junction exit; the CAV must stop behind it and wait."""

    type_name = "BlockedIntersection"
    BEYOND_EXIT = 5.0  # [m] past the route's junction exit
    CLOSE = 13.0  # [m]
    IDLE = 10.0  # [s]

    def place(self) -> None:
        _, after, _ = self.junction_exit()
        self.at = walk(self.map, self.route_point(after), self.BEYOND_EXIT, through_junctions=False)
        self.xy = point_xy(self.map, self.at)
        self.junction = int(self.map.lane_junction[self.ctx.routes[0].lane[after - 1]])
        self.close_at = math.nan

    def plan(self) -> list[PlanItem]:
        return [point("car", self.xy, heading(self.map, self.at))]

    def on_activate(self, snap: Snapshot) -> None:
        if self.background is not None and self.junction >= 0:
            self.background.clear_junction(self.junction)
        self.stop_entries(self.junction)
        self.spawn("blocker", "car", self.xy, heading(self.map, self.at))

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        if math.isnan(self.close_at) and within(progress, self.xy, self.CLOSE):
            self.close_at = self.time
        return self.time - self.close_at >= self.IDLE


class ControlLoss(RouteRule):
    """#6: three patches on the ego lane 14, 48 and 74 m past T_wp; a CAV within 2 m of a patch gets noise
    added to its own controls every tick: throttle + N(+-0.03, 0.01) in [0, 1], steer + N(+-0.055, 0.015)
    in [-1, 1], the signs drawn once per patch. Ends once CAV 0 drove 110 m from T (the third patch + 36 m).
    The patches are cosmetic upstream (dirt decals); we place none. Unlike the triggers, the noise acts on
    every CAV that drives over a patch, as the road under it would: another CAV on CAV 0's lane meets
    the same patches, as it meets the same obstacles."""

    type_name = "ControlLoss"
    counter = 110.0
    needs_junction = False
    PATCHES = (14.0, 48.0, 74.0)  # [m] past T_wp
    RADIUS = 2.0  # [m]
    THROTTLE, STEER = (0.03, 0.01), (0.055, 0.015)  # (|mean|, standard deviation)

    def place(self) -> None:
        super().place()
        m = self.map
        points = [
            walk(m, self.t_wp, d, through_junctions=False, prefer=self.route_lanes) for d in self.PATCHES
        ]
        self.patches = np.array([point_xy(m, p) for p in points])  # (3, 2) [m]
        signs = self.ctx.rng.choice([-1.0, 1.0], size=(len(self.PATCHES), 2))
        self.means = signs * np.array([self.THROTTLE[0], self.STEER[0]])  # (3, 2) throttle, steer

    def plan(self) -> list[PlanItem]:
        return [point("patch", xy) for xy in self.patches]

    def perturb(self, controls: Controls, cav: np.ndarray, progress: RouteProgress) -> Controls:
        xy = progress.xy[cav]
        gap = np.linalg.norm(xy[:, None, :] - self.patches[None], axis=2)  # (n, 3)
        near = gap < self.RADIUS
        hit = near.any(axis=1)
        if not hit.any():
            return controls
        patch = np.argmax(near, axis=1)
        rng, n = self.ctx.rng, len(cav)
        throttle = controls.throttle + hit * rng.normal(self.means[patch, 0], self.THROTTLE[1], n)
        steer = controls.steer + hit * rng.normal(self.means[patch, 1], self.STEER[1], n)
        return Controls(np.clip(steer, -1.0, 1.0), np.clip(throttle, 0.0, 1.0), controls.brake)


class HardBreakRoute(Scenario):
    """#10: the background traffic ahead brakes to a standstill for 10 s (``StopFront``), then drives on
    (``StartFront``); the scenario ends once CAV 0 drove 15 m more. The stopped lanes are every driving lane
    of the edges CAV 0's route takes from T for ``AHEAD`` m (so vehicles behind CAV 0 on its own edge stop
    too: our background commands work by lane)."""

    type_name = "HardBreakRoute"
    uses_timeout = False
    STOP = 10.0  # [s]
    AFTER = 15.0  # [m] CAV 0 drives after the traffic restarts
    AHEAD = 200.0  # [m] along CAV 0's route from T whose edges' lanes are stopped

    def place(self) -> None:
        m, route = self.map, self.ctx.routes[0]
        k0 = self.trigger_index
        ahead = (route.distance >= route.distance[k0]) & (route.distance <= route.distance[k0] + self.AHEAD)
        edges = np.unique(m.lane_edge[route.lane[ahead]])
        self.lanes = np.flatnonzero(np.isin(m.lane_edge, edges) & (m.lane_kind == 0)).tolist()
        self.restart_at = math.nan  # [m] CAV 0's route distance when the traffic restarted

    def on_activate(self, snap: Snapshot) -> None:
        if self.background is not None:
            self.background.stop_lane(self.lanes)

    def on_update(self, snap: Snapshot, progress: RouteProgress) -> bool:
        driven = float(self.ctx.routes[0].distance[progress.index[0]])
        if math.isnan(self.restart_at):
            if self.time - self.activated_at >= self.STOP:
                if self.background is not None:
                    self.background.release_lane(self.lanes)
                self.restart_at = driven
            return False
        return driven - self.restart_at >= self.AFTER
