"""Traffic lights: read every light's signal string each tick, expand it to per-link states, and force
states for scenarios (and release them back to the network's program).

SUMO runs each light's program from the network; a forced state (``force``) holds until ``release``,
which restores the program SUMO was running and its phase, so the normal cycle resumes.

A forced switch never turns a green signal red at once: the signal shows yellow for ``YELLOW_TIME`` first
(forcing and releasing alike), as a real controller and SUMO's own programs do. Without it a scenario
could switch a CAV's light from green to red while it was 2-3 m from the line at 8 m/s, a red-light
infraction no driver could avoid. ``update`` (called by the world every tick) ends the yellow intervals.
Signal characters are SUMO's: ``r`` red, ``y`` yellow, ``g`` green (minor: yield), ``G`` green
(priority), ``s`` green right-turn arrow after stopping, ``u`` red+yellow, ``o``/``O`` off.
"""

from __future__ import annotations

import numpy as np

from cmudrive.maps.model import RoadMap

NO_SIGNAL = "O"  # state reported for links without a traffic light
RED_STATES = frozenset("ru")  # a vehicle must not pass
GREEN_STATES = frozenset("gGs")
YELLOW_TIME = 3.0  # [s] yellow between a forced green and red (SUMO's default yellow duration)
# [s] longest green phase: CARLA's default light cycle (green 10 s, yellow 3 s, red 2 s per group) where
# netconvert's programs run 31-42 s greens in 90 s cycles (reds of 45-80 s, beyond the 60 s blocked test)
GREEN_TIME = 10.0


class TrafficLights:
    """The lights of one map inside a running SUMO simulation."""

    def __init__(self, road_map: RoadMap) -> None:
        self.map = road_map
        self.ids = [str(t) for t in road_map.tls_ids]
        # tls -> (program, phase, seconds the phase had left, simulation time) when it was first forced
        self._forced: dict[str, tuple[str, int, float, float]] = {}
        self._last_states: list[str] | None = None
        self._last_array = np.zeros(0, dtype=str)
        # tls -> (the state it goes to, per signal the time its yellow ends, inf: not yellow)
        self._target: dict[str, tuple[str, np.ndarray]] = {}
        self._release_at: dict[str, float] = {}  # tls -> when a release waiting for its yellow happens

    def cap_green(self, green: float = GREEN_TIME) -> None:
        """Shorten every green phase of every light's programs to at most ``green`` seconds (yellow and
        all-red phases, and greens already shorter, keep their duration), CARLA's cycle: a light whose
        approach waits through the other groups' greens shows red for about 15-40 s, not SUMO's 45-80 s.
        Each light restarts its current phase."""
        import libsumo

        tl = libsumo.trafficlight
        for tls in self.ids:
            current = tl.getProgram(tls)
            for logic in tl.getAllProgramLogics(tls):
                if logic.programID in ("off", "online"):
                    continue
                phases = []
                for ph in logic.phases:
                    greenish = "y" not in ph.state and any(c in GREEN_STATES for c in ph.state)
                    d = min(ph.duration, green) if greenish else ph.duration
                    phases.append(tl.Phase(d, ph.state, d, d, ph.next, ph.name))
                new = tl.Logic(
                    logic.programID, logic.type, logic.currentPhaseIndex, phases, logic.subParameter
                )
                tl.setProgramLogic(tls, new)
            phase = tl.getPhase(tls)
            tl.setProgram(tls, current)
            tl.setPhase(tls, phase)  # the running phase takes its new duration

    def read(self) -> np.ndarray:
        """(T,) current signal string of each light, in map order. Lights change every few seconds, so
        the array is rebuilt only when a string changed and shared (read-only) by the ticks between."""
        import libsumo

        raw = getattr(libsumo, "_libsumo", None)  # the C entry point: the public wrapper only forwards
        get_state = getattr(raw, "trafficlight_getRedYellowGreenState", None)
        states = list(map(get_state or libsumo.trafficlight.getRedYellowGreenState, self.ids))
        if states != self._last_states:
            self._last_states = states
            self._last_array = np.array(states, dtype=str)
            self._last_array.flags.writeable = False
        return self._last_array

    def link_states(self, tls_state: np.ndarray) -> np.ndarray:
        """(L,) one signal character per map link ('O' where the link has no light)."""
        return link_states(self.map, tls_state)

    def switch_off(self) -> None:
        """Switch every light off for good (SUMO's built-in ``off`` program): a junction then runs by its
        right of way, its minor links show ``o`` (yield) and its major ones ``O``; no signal is red, so no
        light can be run. For routes whose source runs without lights (``RouteSpec.lights``)."""
        import libsumo

        for tls in self.ids:
            libsumo.trafficlight.setProgram(tls, "off")

    def force(self, tls_id: str, state: str) -> None:
        """Hold ``tls_id`` at ``state`` (one character per signal index) until :meth:`release`; signals
        going from green to red show yellow for ``YELLOW_TIME`` first."""
        import libsumo

        current = libsumo.trafficlight.getRedYellowGreenState(tls_id)
        if len(state) != len(current):
            raise ValueError(
                f"traffic light {tls_id}: state {state!r} has {len(state)} signals, expected {len(current)}"
            )
        now = libsumo.simulation.getTime()
        if tls_id not in self._forced:
            self._forced[tls_id] = (
                libsumo.trafficlight.getProgram(tls_id),
                libsumo.trafficlight.getPhase(tls_id),
                libsumo.trafficlight.getNextSwitch(tls_id) - now,
                now,
            )
        self._release_at.pop(tls_id, None)  # forced again before a pending release happened
        self._switch(tls_id, current, state, now)

    def _switch(self, tls_id: str, current: str, state: str, now: float) -> None:
        """Show ``state``, with yellow first where a green signal turns red (or stays yellow where an
        earlier yellow has not ended and the signal still goes red)."""
        import libsumo

        _, due = self._target.get(tls_id, ("", np.full(len(state), np.inf)))
        due = due.copy()
        shown = list(state)
        for k, (cur, new) in enumerate(zip(current, state, strict=True)):
            if new not in RED_STATES:
                due[k] = np.inf
            elif cur in GREEN_STATES:
                due[k] = now + YELLOW_TIME
            if np.isfinite(due[k]):
                shown[k] = "y"
        if np.isfinite(due).any():
            self._target[tls_id] = (state, due)
        else:
            self._target.pop(tls_id, None)
        libsumo.trafficlight.setRedYellowGreenState(tls_id, "".join(shown))

    def update(self) -> None:
        """End the yellow intervals that are over (and the releases that waited for them); every tick."""
        if not self._target and not self._release_at:
            return
        import libsumo

        now = libsumo.simulation.getTime() + 1e-9
        for tls_id in [t for t, at in self._release_at.items() if at <= now]:
            del self._release_at[tls_id]
            self._target.pop(tls_id, None)
            self._restore(tls_id)
        for tls_id, (state, due) in list(self._target.items()):
            if tls_id in self._release_at or not (due <= now).any():
                continue
            current = libsumo.trafficlight.getRedYellowGreenState(tls_id)
            shown = "".join(state[k] if due[k] <= now else c for k, c in enumerate(current))
            left = np.where(due <= now, np.inf, due)
            if np.isfinite(left).any():
                self._target[tls_id] = (state, left)
            else:
                del self._target[tls_id]  # every yellow of this light is over
            libsumo.trafficlight.setRedYellowGreenState(tls_id, shown)

    def force_lanes(self, lanes: list[int] | np.ndarray, char: str, others: str | None = None) -> list[str]:
        """Set every signal of links leaving ``lanes`` (map lane indices) to ``char``; with ``others``, set
        all other signals of the same lights to that. Returns the lights touched."""
        import libsumo

        m = self.map
        links = np.flatnonzero(np.isin(m.link_from, np.asarray(lanes)) & (m.link_tls >= 0))
        touched = sorted({int(t) for t in m.link_tls[links]})
        for t in touched:
            tls_id = self.ids[t]
            state = list(libsumo.trafficlight.getRedYellowGreenState(tls_id))
            if others is not None:
                state = [others] * len(state)
            for k in links[m.link_tls[links] == t]:
                state[int(m.link_tls_index[k])] = char
            self.force(tls_id, "".join(state))
        return [self.ids[t] for t in touched]

    def release(self, tls_id: str | None = None) -> None:
        """Give ``tls_id`` (default: every forced light) back to its program, at the phase it was in; where
        that turns a green signal red, after ``YELLOW_TIME`` of yellow (a no-op while that runs)."""
        import libsumo

        now = libsumo.simulation.getTime()
        for tls in [tls_id] if tls_id else list(self._forced):
            if tls not in self._forced or tls in self._release_at:
                continue
            program, phase = self._forced[tls][:2]
            resumed = _phase_state(tls, program, phase)
            current = libsumo.trafficlight.getRedYellowGreenState(tls)
            if resumed is not None and len(resumed) == len(current):
                self._switch(tls, current, resumed, now)  # yellow where the program turns a green red
            pending = self._target.get(tls)
            yellow_ends = pending[1][np.isfinite(pending[1])] if pending else np.zeros(0)
            until = float(yellow_ends.max()) if yellow_ends.size else now
            if until > now:
                self._release_at[tls] = until
            else:
                self._target.pop(tls, None)
                self._restore(tls)

    def _restore(self, tls: str) -> None:
        import libsumo

        program, phase, left, since = self._forced.pop(tls)
        libsumo.trafficlight.setProgram(tls, program)
        libsumo.trafficlight.setPhase(tls, phase)
        # the phase goes on for what it had left minus the time it was overridden (at least 1 s):
        # restarting it in full kept the other approaches red ~40 s longer, long enough for a
        # CAV waiting there to count as blocked
        elapsed = libsumo.simulation.getTime() - since
        libsumo.trafficlight.setPhaseDuration(tls, max(left - elapsed, 1.0))


def _phase_state(tls: str, program: str, phase: int) -> str | None:
    """The signal string of ``phase`` of ``program`` of light ``tls`` (None when SUMO has no such phase)."""
    import libsumo

    for logic in libsumo.trafficlight.getAllProgramLogics(tls):
        if logic.programID == program and 0 <= phase < len(logic.phases):
            return str(logic.phases[phase].state)
    return None


def link_state(road_map: RoadMap, tls_state: np.ndarray, link: int) -> str:
    """The signal character of one map link (``NO_SIGNAL`` where it has no light): what
    :func:`link_states` gives for that link, without building the whole array."""
    m = road_map
    tls, index = int(m.link_tls[link]), int(m.link_tls_index[link])
    if tls < 0 or index < 0 or tls >= len(tls_state):
        return NO_SIGNAL
    state = str(tls_state[tls])
    return state[index] if index < len(state) else NO_SIGNAL


def link_states(road_map: RoadMap, tls_state: np.ndarray) -> np.ndarray:
    """(L,) signal character per link from the (T,) light strings of a snapshot."""
    m = road_map
    out = np.full(len(m.link_from), NO_SIGNAL, dtype="<U1")
    if len(tls_state) == 0:
        return out
    width = max(len(s) for s in tls_state)
    if width == 0:
        return out
    chars = np.array([list(str(s).ljust(width, NO_SIGNAL)) for s in tls_state], dtype="<U1")
    signalled = (m.link_tls >= 0) & (m.link_tls_index >= 0)
    out[signalled] = chars[m.link_tls[signalled], np.minimum(m.link_tls_index[signalled], width - 1)]
    return out
