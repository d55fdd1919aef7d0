"""Route criteria: every CAV of a route scored as ``reference/SCORING.md`` specifies (Leaderboard 2.0,
Bench2Drive variant).

:class:`RouteCriteria` (``engine``) is fed one snapshot and its collision events per tick and keeps, for
each CAV, its route completion RC_i, its infractions (``cmudrive.bench.records``: keys, penalty factors,
status strings) and whether its evaluation has ended; :class:`CriteriaConfig` (``config``) holds every
threshold with its unit. One module per criterion: ``progress`` (route index, completion, deviation,
timeout budget), ``collisions`` and ``layout`` (static scenery), ``red_lights`` and ``stop_signs`` (on
``stop_lines``), ``lanes`` (outside route lanes), ``min_speed``. All of them work on arrays over the
route's CAVs; nothing loops over background actors.

``docs/scoring.md`` states each rule as implemented and every place where it differs from CARLA's
scenario_runner / leaderboard criteria, and why.
"""

from cmudrive.bench.criteria.config import CriteriaConfig
from cmudrive.bench.criteria.engine import RouteCriteria

__all__ = ["CriteriaConfig", "RouteCriteria"]
