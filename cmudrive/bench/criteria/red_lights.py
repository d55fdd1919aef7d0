"""Running a red light: the CAV's rear segment crosses the stop line of its lane while the light is red.

Per tick and CAV: the *rear segment* runs from ``red_light_tail_near`` x half length behind the box centre
to ``red_light_tail_extra`` behind the rear bumper (CARLA's segment). The lane is the driving lane under
the segment's far end (heading-filtered, within half a lane width plus the margin), so the CAV must drive
along the lane; only that lane's light stop line is tested. When the segment crosses it, the light
state is read from the SUMO links leaving the lane: a lane whose links all show red (``r``/``u``) is
red, one with none red is not; when they differ (e.g. a red straight and a green right-turn arrow) the
link the CAV takes decides: the one its route takes from that lane, else the one whose first junction lane
lies nearest the CAV's front bumper. A light is charged once per passage: the same stop line counts again
only after the CAV has been ``red_light_rearm_distance`` away from it.
"""

from __future__ import annotations

import numpy as np

from cmudrive.bench.criteria.config import CriteriaConfig
from cmudrive.bench.criteria.stop_lines import StopLineTable, segments_cross
from cmudrive.maps.model import NO_INDEX, RoadMap
from cmudrive.maps.routing import Route
from cmudrive.sim.traffic_lights import RED_STATES, link_states

_EMPTY = np.zeros(0, np.int64)


class RedLightCheck:
    def __init__(
        self, road_map: RoadMap, stops: StopLineTable, routes: list[Route], config: CriteriaConfig
    ) -> None:
        self.map = road_map
        self.stops = stops
        self.routes = routes
        self.config = config
        self._charged = np.full(len(routes), NO_INDEX, np.int64)  # stop line charged in this passage

    def update(
        self,
        cav: np.ndarray,
        xy: np.ndarray,
        forward: np.ndarray,
        half_length: np.ndarray,
        tail_lane: np.ndarray,
        route_index: np.ndarray,
        tls_state: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """CAVs (of ``cav`` (m,)) that ran a red light this tick and the stop lines they crossed.

        ``xy`` (m, 2) [m] box centres, ``forward`` (m, 2) unit headings, ``half_length`` (m,) [m],
        ``tail_lane`` (m,) lane under the rear segment's far end (-1: none), ``route_index`` (m,) current
        route points, ``tls_state`` the snapshot's light strings."""
        cfg, stops = self.config, self.stops
        held = np.flatnonzero(self._charged[cav] >= 0)  # CAVs charged in their current passage
        if len(held):  # (a map without light stop lines never gets here: nothing is ever charged)
            gone = np.linalg.norm(xy[held] - stops.mid[self._charged[cav[held]]], axis=1)
            self._charged[cav[held[gone > cfg.red_light_rearm_distance]]] = NO_INDEX
        k = stops.at(tail_lane, stops.is_light)
        sel = np.flatnonzero((k >= 0) & (k != self._charged[cav]))
        if len(sel) == 0:
            return _EMPTY, _EMPTY
        ks, fwd = k[sel], forward[sel]
        near = xy[sel] - fwd * (cfg.red_light_tail_near * half_length[sel])[:, None]
        far = xy[sel] - fwd * (half_length[sel] + cfg.red_light_tail_extra)[:, None]
        crossing = segments_cross(near, far, stops.ends[ks, 0], stops.ends[ks, 1])
        crossing &= np.einsum("mc,mc->m", fwd, stops.forward[ks]) > 0.0
        sel = sel[crossing]
        if len(sel) == 0:
            return _EMPTY, _EMPTY
        signal = link_states(self.map, tls_state)
        ran = []
        for j in sel.tolist():  # CAVs crossing a light's line this very tick: rarely more than one
            front = xy[j] + forward[j] * half_length[j]
            if self._is_red(int(cav[j]), int(k[j]), front, int(route_index[j]), signal):
                ran.append(j)
                self._charged[cav[j]] = k[j]
        return cav[ran], k[ran]

    def _is_red(self, cav: int, stop: int, front: np.ndarray, route_index: int, signal: np.ndarray) -> bool:
        m = self.map
        lane = int(self.stops.lane[stop])
        links = np.flatnonzero((m.link_from == lane) & (m.link_tls >= 0))
        red = np.isin(signal[links], list(RED_STATES))
        if len(links) == 0 or not red.any():
            return False
        if red.all():
            return True
        return bool(red[links == self._link_taken(cav, lane, links, front, route_index)][0])

    def _link_taken(self, cav: int, lane: int, links: np.ndarray, front: np.ndarray, route_index: int) -> int:
        """The link of ``links`` (all leaving ``lane``) that the CAV takes: its route's, else the one whose
        first lane (junction-internal, or the outgoing lane) is nearest the front bumper."""
        m = self.map
        entry = np.where(m.link_via[links] >= 0, m.link_via[links], m.link_to[links])
        route_lane = self.routes[cav].lane
        leave = np.flatnonzero((route_lane[:-1] == lane) & (route_lane[1:] != lane))  # route exits of lane
        if len(leave):
            nxt = route_lane[leave[np.argmin(np.abs(leave - route_index))] + 1]
            hit = np.flatnonzero(entry == nxt)
            if len(hit):
                return int(links[hit[0]])
        _, d = m.index.project(np.repeat(front[None], len(entry), axis=0), entry)
        return int(links[np.argmin(np.abs(d))])
