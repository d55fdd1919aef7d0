"""Running a stop sign: entering the junction from a stop-sign (or all-way-stop) lane without stopping.

The *stop area* of a sign's stop line is the last ``stop_area_length`` metres of its approach lane,
measured at the CAV's front bumper. A CAV is *at* a stop from the tick its centre lies on the approach
lane (heading-filtered, within half a lane width plus the margin: a CAV driving against the lane is never
at its stop) with its front bumper at most ``stop_area_length`` before the line, until its centre passes
the line. While at the stop, a speed below ``stop_speed`` satisfies it; the centre passing the line (the
CAV entering the junction) without that is one infraction. A CAV that leaves the lane sideways (more than
a lane width from the line's centre) before reaching the line is released without a verdict.
"""

from __future__ import annotations

import numpy as np

from cmudrive.bench.criteria.config import CriteriaConfig
from cmudrive.bench.criteria.stop_lines import StopLineTable
from cmudrive.maps.model import NO_INDEX


class StopSignCheck:
    def __init__(self, stops: StopLineTable, num_cavs: int, config: CriteriaConfig) -> None:
        self.stops = stops
        self.config = config
        self._stop = np.full(num_cavs, NO_INDEX, np.int64)  # the stop line each CAV is at, -1: none
        self._stopped = np.zeros(num_cavs, bool)  # it has stopped there

    def update(
        self, cav: np.ndarray, xy: np.ndarray, half_length: np.ndarray, speed: np.ndarray, lane: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """CAVs (of ``cav`` (m,)) that entered a junction past a stop sign without stopping this tick, and
        those stop lines. ``xy`` (m, 2) [m] centres, ``half_length`` (m,) [m], ``speed`` (m,) [m/s],
        ``lane`` (m,) the lane each centre is on (-1: none)."""
        cfg, stops = self.config, self.stops
        # 1. CAVs already at a stop: entered the junction, or left the lane sideways?
        k = self._stop[cav]
        at = np.flatnonzero(k >= 0)
        along, across = stops.frame(k[at], xy[at])
        entered = at[along > 0.0]
        ran = entered[~self._stopped[cav[entered]]]
        released = np.concatenate([entered, at[(along <= 0.0) & (np.abs(across) > stops.width[k[at]])]])
        self._stop[cav[released]] = NO_INDEX
        self._stopped[cav[released]] = False
        # 2. CAVs arriving in a stop area
        new = stops.at(lane, stops.is_sign)
        arrive = np.flatnonzero((new >= 0) & (new != self._stop[cav]))
        along, _ = stops.frame(new[arrive], xy[arrive])
        arrive = arrive[(along + half_length[arrive] >= -cfg.stop_area_length) & (along <= 0.0)]
        self._stop[cav[arrive]] = new[arrive]
        self._stopped[cav[arrive]] = False
        # 3. a stop inside the area satisfies it
        slow = (self._stop[cav] >= 0) & (np.abs(speed) < cfg.stop_speed)
        self._stopped[cav[slow]] = True
        return cav[ran], k[ran]
