"""The commands scenarios give the background activity (Bench2Drive's BA commands), and their implementation.

Scenarios type against :class:`BackgroundCommands` (``Scenario.background``); the density keeper,
:class:`~cmudrive.sim.background.BackgroundActivity`, implements it through :class:`CommandsMixin`.

Commands (Bench2Drive's BA commands; each takes effect immediately, works on vehicles only, and touches
only actors whose role is :attr:`Role.BACKGROUND`, never CAVs, scenario actors or props; lanes are map
lane indices, and a command before :meth:`BackgroundActivity.populate` raises ``RuntimeError``):

==========================================  =========================================================
method                                      Bench2Drive
==========================================  =========================================================
``leave_space(cav, d)``                     ``LeaveSpace`` (we delete the cars; B2D moves them ahead)
``remove_lane(lanes)``/``readd_lane``       ``RemoveLane`` / ``ReAddLane``
``stop_lane(lanes, before)``/``release``   ``StopFront``/``StartFront``, ``StopBack``/``StartBack`` (by lane)
``opposite_traffic(enabled)``               ``OppOff`` / ``OppOn``
``clear_junction(j, approach)``             ``Junction{clear}`` (interior and entries of a junction)
``max_speed(v)``                            ``MaxSpeed`` (B2D takes km/h; we take m/s)
==========================================  =========================================================
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Protocol

import numpy as np

from cmudrive.sim.actor_types import ACTOR_TYPES
from cmudrive.sim.background_geometry import (
    CavPoses,
    Pending,
    Scene,
    active_cavs,
    lane_offsets,
    live_vehicles,
)

if TYPE_CHECKING:
    from cmudrive.sim.world import World


class BackgroundCommands(Protocol):
    """The background activity as scenarios see it: Bench2Drive's BA commands (module docstring)."""

    def leave_space(self, cav_index: int, distance: float) -> int: ...
    def remove_lane(self, lanes: Iterable[int]) -> int: ...
    def readd_lane(self, lanes: Iterable[int]) -> None: ...
    def stop_lane(self, lanes: Iterable[int], before: float = np.inf) -> int: ...
    def release_lane(self, lanes: Iterable[int]) -> int: ...
    def opposite_traffic(self, enabled: bool) -> int: ...
    def clear_junction(self, junction_index: int, approach: float = 30.0) -> int: ...
    def max_speed(self, v_mps: float | None) -> None: ...


class _Keeper(Protocol):
    """What the commands use of the density keeper: its command state and its removal."""

    _lane_removed: np.ndarray  # (lanes,) bool: no spawns on these map lanes
    _stopped_lanes: dict[int, float]  # map lane -> arc length [m] before which its background halts
    _halted: dict[str, int]  # vehicle -> the stopped lane that halted it
    _opposite: bool  # oncoming traffic on (False: OppOff)
    _speed_cap: float | None  # [m/s] MaxSpeed, None: each type's own
    _pending: dict[str, Pending]
    _type_of: dict[str, str]

    def _need_world(self) -> World: ...
    def _scene(self, world: World, cavs: CavPoses) -> Scene: ...
    def _remove(self, world: World, scene: Scene, rows: np.ndarray, counter: str) -> int: ...
    def _remove_opposite(self, world: World, scene: Scene, cavs: CavPoses, min_distance: float) -> int: ...
    def _halt_on_stopped_lanes(self, scene: Scene) -> None: ...
    def _command_scene(self) -> tuple[World, Scene, CavPoses]: ...


class CommandsMixin:
    """:class:`BackgroundCommands` for :class:`~cmudrive.sim.background.BackgroundActivity`, which owns
    the state these methods change (:class:`_Keeper`)."""

    def _halt_on_stopped_lanes(self: _Keeper, scene: Scene) -> None:
        """Halt the background vehicles on the stopped lanes (each update: also those that drove on since)."""
        if not self._stopped_lanes:
            return
        import libsumo

        rows = live_vehicles(scene)
        on = rows[np.isin(scene.lane[rows], list(self._stopped_lanes))]
        limit = np.array([self._stopped_lanes[int(ln)] for ln in scene.lane[on].tolist()])
        part = np.isfinite(limit)
        if part.any():  # StopBack: only what is behind the point (and what was halted before)
            s = np.full(len(on), -np.inf)
            s[part], _ = self._need_world().map.index.project(scene.xy[on[part]], scene.lane[on[part]])
            before = np.array([scene.ids[r] in self._halted for r in on.tolist()], bool)
            on = on[(s < limit) | before]
        for r in on.tolist():
            actor_id = scene.ids[r]
            if actor_id not in self._halted:
                self._halted[actor_id] = int(scene.lane[r])
            libsumo.vehicle.setSpeed(actor_id, 0.0)  # re-applied: a collision hold may have released it

    def _command_scene(self: _Keeper) -> tuple[World, Scene, CavPoses]:
        world = self._need_world()
        cavs = active_cavs(world)
        return world, self._scene(world, cavs), cavs

    def leave_space(self: _Keeper, cav_index: int, distance: float) -> int:
        """Bench2Drive ``LeaveSpace``: remove background vehicles ahead of CAV ``cav_index`` in its lane
        corridor (its lane and every lane reachable from it) up to ``distance`` [m]. Returns the count."""
        world, scene, _ = self._command_scene()
        if not world.cav_active[cav_index]:
            return 0
        m, st = world.map, world.cav_state
        pos = np.array([st.x[cav_index], st.y[cav_index]])
        yaw = float(st.yaw[cav_index])
        proj = m.index.nearest_lane(pos[None], heading=yaw)
        lane = int(proj.lane[0])
        rows = live_vehicles(scene)
        # straight corridor in the CAV frame: catches vehicles straddling lanes (sublane model)
        rel = scene.xy[rows] - pos
        lon = rel[:, 0] * np.cos(yaw) + rel[:, 1] * np.sin(yaw)
        lat = -rel[:, 0] * np.sin(yaw) + rel[:, 1] * np.cos(yaw)
        half_width = 0.5 * float(m.lane_width[lane]) if lane >= 0 else 1.75
        half_len = 0.5 * scene.length[rows]
        hit = (lon > 0.0) & (lon - half_len <= distance) & (np.abs(lat) <= half_width)
        if lane >= 0:  # along the lane graph: follows curves and junction paths
            start = lane_offsets(m, lane, float(proj.s[0]), distance)
            on = np.flatnonzero(np.isin(scene.lane[rows], list(start)))
            if len(on):
                s, _ = m.index.project(scene.xy[rows[on]], scene.lane[rows[on]])
                ahead = np.array([start[int(ln)] for ln in scene.lane[rows[on]].tolist()]) + s
                hit[on] |= (ahead > 0.0) & (ahead - half_len[on] <= distance)
        return self._remove(world, scene, rows[hit], "removed_command")

    def remove_lane(self: _Keeper, lanes: Iterable[int]) -> int:
        """Bench2Drive ``RemoveLane``: delete background vehicles on these map lanes, stop spawning there."""
        world, scene, _ = self._command_scene()
        lanes = [int(ln) for ln in lanes]
        self._lane_removed[lanes] = True
        rows = live_vehicles(scene)
        return self._remove(world, scene, rows[np.isin(scene.lane[rows], lanes)], "removed_command")

    def readd_lane(self: _Keeper, lanes: Iterable[int]) -> None:
        """Bench2Drive ``ReAddLane``: spawning on these lanes is allowed again."""
        self._need_world()
        self._lane_removed[[int(ln) for ln in lanes]] = False

    def stop_lane(self: _Keeper, lanes: Iterable[int], before: float = np.inf) -> int:
        """Bench2Drive ``StopFront``/``StopBack``: background vehicles on these lanes (now, and any that
        drive onto them later) brake to a halt (``setSpeed(0)``) until :meth:`release_lane`; with
        ``before`` [m of lane arc length] only those whose centre is behind it (StopBack: the vehicles
        behind the ego; those ahead of it drive on). A vehicle once halted stays halted."""
        _, scene, _ = self._command_scene()
        count = len(self._halted)
        for ln in lanes:
            self._stopped_lanes[int(ln)] = float(before)
        self._halt_on_stopped_lanes(scene)
        return len(self._halted) - count

    def release_lane(self: _Keeper, lanes: Iterable[int]) -> int:
        """Bench2Drive ``StartFront``/``StartBack``: vehicles halted on these lanes drive on again."""
        import libsumo

        world = self._need_world()
        released = {int(ln) for ln in lanes}
        for ln in released:
            self._stopped_lanes.pop(ln, None)
        go = [a for a, ln in self._halted.items() if ln in released]
        for actor_id in go:
            del self._halted[actor_id]
            if actor_id in world.sumo.actors:
                libsumo.vehicle.setSpeed(actor_id, -1.0)  # back to SUMO's own car-following
        return len(go)

    def opposite_traffic(self: _Keeper, enabled: bool) -> int:
        """Bench2Drive ``OppOn``/``OppOff``. Off: no spawns on lanes running opposite (> 120 degrees) to the
        nearest CAV, and background vehicles heading against their nearest CAV, ahead of it within the
        radius, are removed (now; later only those out of sight). Returns the number removed now."""
        world, scene, cavs = self._command_scene()
        self._opposite = bool(enabled)
        if self._opposite or len(cavs.xy) == 0:
            return 0
        return self._remove_opposite(world, scene, cavs, 0.0)

    def clear_junction(self: _Keeper, junction_index: int, approach: float = 30.0) -> int:
        """Bench2Drive ``Junction`` clear: remove background vehicles inside the junction (on its internal
        lanes) and on its incoming lanes within ``approach`` [m] of it. Returns the count."""
        world, scene, _ = self._command_scene()
        m = world.map
        rows = live_vehicles(scene)
        lane = scene.lane[rows]
        known = lane >= 0
        hit = known & (m.lane_junction[np.where(known, lane, 0)] == junction_index)
        incoming = known & ~m.lane_internal[np.where(known, lane, 0)]
        incoming &= m.edge_to_junction[m.lane_edge[np.where(known, lane, 0)]] == junction_index
        if incoming.any():
            s, _ = m.index.project(scene.xy[rows[incoming]], lane[incoming])
            hit[incoming] = m.lane_length[lane[incoming]] - s <= approach
        return self._remove(world, scene, rows[hit], "removed_command")

    def max_speed(self: _Keeper, v_mps: float | None) -> None:
        """Bench2Drive ``MaxSpeed``: cap every background vehicle (and new spawns) at ``v_mps`` [m/s];
        ``None`` restores each vehicle type's own maximum."""
        import libsumo

        _, scene, _ = self._command_scene()
        if v_mps is not None and v_mps < 0.0:
            raise ValueError(f"max_speed needs v_mps >= 0 or None, got {v_mps}")
        self._speed_cap = v_mps
        for r in live_vehicles(scene).tolist():
            actor_id = scene.ids[r]
            if actor_id in self._pending:  # not inserted yet: capped when it appears (_settle_spawns)
                continue
            if v_mps is None:
                type_name = self._type_of.get(actor_id) or libsumo.vehicle.getTypeID(actor_id).split("@")[0]
                cap = ACTOR_TYPES[type_name].max_speed if type_name in ACTOR_TYPES else 1e3
            else:
                cap = v_mps
            libsumo.vehicle.setMaxSpeed(actor_id, max(cap, 0.0))
