"""How far a run of routes is: routes done, wall time, an estimate of the time left and the simulated-time
ratio, for the progress display of ``cmudrive eval`` and ``cmudrive data collect``.

The ETA assumes the routes still to run take as long, on average, as the finished ones (with the same
workers): elapsed x remaining / finished; there is none before the first route finishes. The simulated-time
ratio is simulated seconds (ticks of finished routes plus the ticks reached by running ones, ``DT`` each)
per wall second since the run started, over all workers together: above 1 the run is faster than real
time. Time is passed in (``now``, seconds on the ``time.monotonic`` clock), so this is a pure record.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from cmudrive.bench.evaluator import DT


def clock(seconds: float) -> str:
    """``h:mm:ss`` (or ``m:ss`` under an hour) of a non-negative duration [s]."""
    minutes, secs = divmod(round(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


@dataclass
class RunProgress:
    """Routes of one run: ``tick`` as running routes advance, ``finish`` as each ends."""

    total: int  # [-] routes in the run
    start: float = field(default_factory=time.monotonic)  # [s] monotonic clock at the start
    dt: float = DT  # [s] simulated time per tick
    finished: int = 0  # [-] routes ended
    finished_ticks: int = 0  # [-] ticks simulated by the ended routes
    running: dict[str, int] = field(default_factory=dict)  # route id -> ticks reached so far

    def tick(self, route_id: str, tick: int) -> None:
        self.running[route_id] = tick

    def finish(self, route_id: str, ticks: int) -> None:
        self.running.pop(route_id, None)
        self.finished += 1
        self.finished_ticks += ticks

    def simulated(self) -> float:
        """[s] simulated time so far, all routes together."""
        return (self.finished_ticks + sum(self.running.values())) * self.dt

    def ratio(self, now: float) -> float:
        """[s/s] simulated seconds per wall second since the start."""
        return self.simulated() / max(now - self.start, 1e-9)

    def eta(self, now: float) -> float | None:
        """[s] estimated wall time left, None before a route has finished."""
        if self.finished == 0:
            return None
        return (now - self.start) * (self.total - self.finished) / self.finished

    def describe(self, now: float) -> str:
        """``2/4 routes, 0:35 elapsed, ETA 0:35, 3.1 simulated s per wall s``."""
        eta = self.eta(now)
        return (
            f"{self.finished}/{self.total} routes, {clock(now - self.start)} elapsed, "
            f"ETA {'-' if eta is None else clock(eta)}, {self.ratio(now):.2f} simulated s per wall s"
        )


__all__ = ["RunProgress", "clock"]
