"""Contacts of CAVs with the town's static scenery (buildings, poles, guardrails): layout collisions.

The scenery of a map never moves, so its boxes go into a :class:`SceneryIndex` once per route: a
``cKDTree`` over the box centres for the broad phase, and the box table that the separating-axis test of
:mod:`cmudrive.sim.collisions` reads. Each tick, :func:`scenery_contacts` tests the few CAV boxes against
the scenery boxes within reach: candidates whose bounding circles meet, then the same SAT penetration and
touch tolerance as actor-actor collisions (boxes that merely touch do not collide). A counted contact is
a ``collisions_layout`` infraction (factor 0.65), under the same once-per-contact rules as the other
collisions (:mod:`cmudrive.bench.criteria.collisions`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from cmudrive.maps.scenery import SceneryKind, StaticScenery
from cmudrive.sim.collisions import TOUCH_TOLERANCE, pair_penetration


def box_table(
    x: np.ndarray, y: np.ndarray, yaw: np.ndarray, length: np.ndarray, width: np.ndarray
) -> np.ndarray:
    """(n, 6) rows x, y [m], cos yaw, sin yaw, half length, half width [m]: the SAT's box table."""
    return np.column_stack([x, y, np.cos(yaw), np.sin(yaw), 0.5 * length, 0.5 * width]).astype(np.float64)


@dataclass(frozen=True, eq=False)
class SceneryIndex:
    """Static scenery boxes ready for contact queries."""

    scenery: StaticScenery
    table: np.ndarray  # (S, 6) box table of the scenery
    radius: np.ndarray  # (S,) half-diagonal of each box [m]
    tree: cKDTree | None  # over the box centres; None without scenery

    @staticmethod
    def build(scenery: StaticScenery) -> SceneryIndex:
        s = scenery
        table = box_table(s.x, s.y, s.yaw, s.length, s.width)
        radius = np.hypot(table[:, 4], table[:, 5])
        tree = cKDTree(table[:, :2]) if len(s) else None
        return SceneryIndex(scenery, table, radius, tree)

    @property
    def reach(self) -> float:
        """The largest half-diagonal of a scenery box [m]."""
        return float(self.radius.max()) if len(self.radius) else 0.0

    def name(self, j: int) -> str:
        """Id of scenery box ``j`` in infraction records: ``scenery:<kind>:<index>``."""
        return f"scenery:{SceneryKind(int(self.scenery.kind[j])).name.lower()}:{j}"


def scenery_contacts(boxes: np.ndarray, index: SceneryIndex) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping (box, scenery) pairs: the row in ``boxes`` (k,) and the scenery box (k,), sorted by
    row then scenery box. ``boxes`` (n, 6) is a :func:`box_table` (e.g. of a tick's CAVs)."""
    empty = np.zeros(0, np.int64)
    if index.tree is None or len(boxes) == 0:
        return empty, empty
    radius = np.hypot(boxes[:, 4], boxes[:, 5])
    found = index.tree.query_ball_point(boxes[:, :2], radius + index.reach)  # (n,) lists of box indices
    counts = np.fromiter((len(f) for f in found), np.int64, len(found))
    if counts.sum() == 0:
        return empty, empty
    row = np.repeat(np.arange(len(boxes)), counts)
    other = np.concatenate([np.asarray(f, np.int64) for f in found])
    gap = np.hypot(*(boxes[row, :2] - index.table[other, :2]).T)
    near = gap <= radius[row] + index.radius[other]
    row, other = row[near], other[near]
    hit = pair_penetration(boxes[row], index.table[other]) > TOUCH_TOLERANCE
    row, other = row[hit], other[hit]
    order = np.lexsort((other, row))
    return row[order], other[order]
