"""What each rule of the expert asks for, and how :meth:`ExpertAgent.run_step` combines the rules.

Every rule (cruise, corridor, detour wait, junction, forecast) returns a :class:`Candidate` for the ``n``
active CAVs. A :class:`Verdict` starts from the cruise and takes the others in the rules' order: where a
candidate's acceleration term is *strictly* smaller than the verdict's so far, the candidate sets the
acceleration, the reason, the object row and the distance (on a tie the earlier rule keeps them); the
desired speed is the minimum of every rule's allowed speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Candidate:
    """One rule's ask, for the ``n`` active CAVs."""

    accel: np.ndarray  # (n,) [m/s^2] the rule's acceleration term, inf where it has nothing to say
    reason: int | np.ndarray  # Reason, one for all or (n,) int8
    row: np.ndarray | None  # (n,) int64 snapshot row of the object behind it, -1 none; None: no object
    distance: np.ndarray  # (n,) [m] bumper to the object or stop line, inf none
    allowed: np.ndarray  # (n,) [m/s] the speed the rule allows now, inf where it sets no limit


@dataclass
class Verdict:
    """The rules folded so far: the lowest acceleration and what set it, and the desired speed."""

    accel: np.ndarray  # (n,) [m/s^2]
    reason: np.ndarray  # (n,) int8 Reason
    row: np.ndarray  # (n,) int64 snapshot row of the object, -1 none
    distance: np.ndarray  # (n,) [m] inf none
    desired: np.ndarray  # (n,) [m/s] the minimum of the allowed speeds

    @classmethod
    def start(cls, first: Candidate) -> Verdict:
        """The verdict of the first rule (the cruise) alone."""
        n = len(first.accel)
        row = np.full(n, -1, np.int64) if first.row is None else first.row.copy()
        reason = np.broadcast_to(np.asarray(first.reason), (n,)).astype(np.int8)
        return cls(first.accel, reason, row, first.distance.copy(), first.allowed.copy())

    def take(self, c: Candidate | None) -> None:
        """Fold in a later rule's candidate (None: the rule had nothing to say this tick)."""
        if c is None:
            return
        np.minimum(self.desired, c.allowed, out=self.desired)
        better = c.accel < self.accel
        self.accel = np.where(better, c.accel, self.accel)
        self.reason = np.where(better, c.reason, self.reason).astype(np.int8)
        self.row[better] = -1 if c.row is None else c.row[better]
        self.distance[better] = c.distance[better]
