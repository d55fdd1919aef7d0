"""Numbers of a comparison of runs: per run the scores overall and per category (ability, scenario type,
CAV count, weather), per group of seeds their mean and sample standard deviation.

Pure functions over the records (``records.RouteResult``) of :mod:`cmudrive.bench.runs`; the page and the
charts that show them are :mod:`cmudrive.viz.compare_report`.

- **Overall** numbers are ``metrics.summarize`` with the run's expected route count (missing routes count
  0, as in ``results.json``): DS, SR, RC, IS, efficiency, comfortness, the multi-ability mean.
- **Per category**, over the routes of that category in the run: DS, SR (the paper's SS^j), RC and IS
  (means over the routes), and for abilities also Bench2Drive's success (``metrics.multi_ability``).
- **Empty categories**: a category is listed when some run has a route in it, and left out everywhere
  otherwise (scenario types, weathers, abilities and CAV counts alike). A group none of whose runs has it
  gets no number (shown "-"); a group where only some seeds have it averages those, and says how many.
- **Mean and spread** over a group's runs: the mean and the sample standard deviation (n - 1 in the
  denominator); none for a single run.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from cmudrive.bench.metrics import ABILITIES, abilities_of, multi_ability, summarize
from cmudrive.bench.records import STATUS_INVALID_ROUTE, RouteResult
from cmudrive.bench.runs import Run, RunError, RunGroup
from cmudrive.bench.scenario_types import SCENARIO_TYPES

METRICS: dict[str, str] = {
    "driving_score": "DS",
    "success_rate": "SR (%)",
    "route_completion": "RC (%)",
    "infraction_score": "IS",
}  # per-category numbers, with their column heading
OVERALL: dict[str, str] = {
    "driving_score": "Driving score DS (0-100)",
    "success_rate": "Success rate SR (%)",
    "route_completion": "Route completion RC (%)",
    "infraction_score": "Infraction score IS (0-1)",
    "efficiency": "Efficiency (%)",
    "comfortness": "Comfortness (%)",
    "ability_mean": "Multi-ability mean (Bench2Drive success, %)",
    "num_routes": "Routes evaluated",
    "num_crashed": "Routes crashed",
}
B2D_SUCCESS = "b2d_success"  # per ability: Bench2Drive's success rate [%] (``metrics.multi_ability``)


def _weathers() -> tuple[str, ...]:
    from cmudrive.sim.weather import WEATHERS  # local: keeps this module free of libsumo at import

    return tuple(WEATHERS)


@dataclass(frozen=True)
class Breakdown:
    """One way to split routes: the groups a route is in, and the order groups are listed in."""

    name: str  # key in the comparison, and the charts' file stem
    title: str  # heading in the page
    keys: Callable[[RouteResult], Iterable[Hashable]]
    order: Callable[[], Sequence[Hashable]]


BREAKDOWNS: tuple[Breakdown, ...] = (
    Breakdown("ability", "ability", lambda r: abilities_of(r.scenario_type), lambda: tuple(ABILITIES)),
    Breakdown("scenario_type", "scenario type", lambda r: [r.scenario_type], lambda: SCENARIO_TYPES),
    Breakdown("num_cavs", "number of CAVs", lambda r: [r.num_cavs], lambda: tuple(range(1, 65))),
    Breakdown("weather", "weather", lambda r: [r.weather], _weathers),
)


@dataclass(frozen=True)
class Stat:
    """A number over a group's runs: mean, sample standard deviation (None for one value), count."""

    mean: float
    std: float | None
    n: int

    def text(self, digits: int = 2) -> str:
        if self.std is None:
            return f"{self.mean:.{digits}f}"
        return f"{self.mean:.{digits}f} ± {self.std:.{digits}f}"


def mean_std(values: Sequence[float]) -> Stat | None:
    """Mean and sample standard deviation of ``values``; None for none."""
    if not values:
        return None
    n = len(values)
    mean = math.fsum(values) / n
    std = math.sqrt(math.fsum((v - mean) ** 2 for v in values) / (n - 1)) if n > 1 else None
    return Stat(mean, std, n)


def category_scores(
    routes: Sequence[RouteResult], breakdown: Breakdown
) -> dict[str, dict[str, float | int | None]]:
    """Per category of ``breakdown`` with routes: DS, SR [%], RC [%], IS (means over its routes), the
    number of routes, and for abilities Bench2Drive's success [%]. Categories in the breakdown's order,
    then the others by their text; keys are text ("3" CAVs, "" for routes without a scenario)."""
    members: dict[Hashable, list[RouteResult]] = {}
    for r in routes:
        for k in breakdown.keys(r):
            members.setdefault(k, []).append(r)
    order = breakdown.order()
    keys = [k for k in order if k in members] + sorted((k for k in members if k not in set(order)), key=str)
    out: dict[str, dict[str, float | int | None]] = {}
    for k in keys:
        rs = members[k]
        n = len(rs)
        scores: dict[str, float | int | None] = {
            "driving_score": math.fsum(r.driving_score for r in rs) / n,
            "success_rate": 100.0 * sum(r.success for r in rs) / n,
            "route_completion": math.fsum(r.route_completion for r in rs) / n,
            "infraction_score": math.fsum(r.infraction_score for r in rs) / n,
            "num_routes": n,
        }
        if breakdown.name == "ability":
            scores[B2D_SUCCESS] = multi_ability(rs)[str(k)]
        out[str(k)] = scores
    return out


def run_overall(run: Run) -> dict[str, float | int | None]:
    """The overall numbers of ``OVERALL`` for one run (``metrics.summarize``)."""
    try:
        s = summarize(run.routes, run.num_expected)
    except ValueError as e:
        raise RunError(f"{run.results_file}: {e}") from None
    values = {k: s[k] for k in OVERALL if k in s}
    values["ability_mean"] = s["multi_ability"]["mean"]
    return values


@dataclass
class Comparison:
    """The numbers of a report: ``groups`` of runs; per group the overall ``Stat`` s and per breakdown,
    category and group the per-category ``Stat`` s (a group none of whose runs has the category has none)."""

    groups: list[RunGroup]
    overall: list[dict[str, Stat | None]]  # [group] -> metric -> Stat
    per_run_overall: list[list[dict[str, float | int | None]]]  # [group][run] -> metric -> value
    categories: dict[str, list[str]]  # breakdown name -> categories some run has, in order
    scores: dict[str, dict[str, list[dict[str, Stat | None] | None]]]  # breakdown -> category -> [group]


def _stat(values: Iterable[float | int | None]) -> Stat | None:
    return mean_std([float(v) for v in values if v is not None])


def compare(groups: Sequence[RunGroup]) -> Comparison:
    """Mean and spread of every number over each group's runs (see the module docstring)."""
    per_run = [[run_overall(r) for r in g.runs] for g in groups]
    overall = [{k: _stat(v.get(k) for v in runs) for k in OVERALL} for runs in per_run]
    categories: dict[str, list[str]] = {}
    scores: dict[str, dict[str, list[dict[str, Stat | None] | None]]] = {}
    for b in BREAKDOWNS:
        run_cats = [
            [
                category_scores([r for r in run.routes if r.status != STATUS_INVALID_ROUTE], b)
                for run in g.runs
            ]
            for g in groups
        ]
        seen: list[str] = []
        for cats in (c for runs in run_cats for c in runs):
            seen += [k for k in cats if k not in seen]
        order = [str(k) for k in b.order()]
        seen.sort(key=lambda k: (order.index(k), "") if k in order else (len(order), k))
        categories[b.name] = seen
        metrics = [*METRICS, "num_routes", *([B2D_SUCCESS] if b.name == "ability" else [])]
        scores[b.name] = {
            cat: [
                {m: _stat(c[cat].get(m) for c in runs if cat in c) for m in metrics}
                if any(cat in c for c in runs)
                else None
                for runs in run_cats
            ]
            for cat in seen
        }
    return Comparison(list(groups), overall, per_run, categories, scores)


def runs_with(comparison: Comparison, breakdown: str, category: str, group: int) -> int:
    """How many of group ``group``'s runs have a route in ``category`` of ``breakdown``."""
    cell = comparison.scores[breakdown][category][group]
    stat = cell.get("num_routes") if cell else None
    return stat.n if stat else 0


def as_rows(comparison: Comparison) -> list[dict[str, Any]]:
    """The comparison as flat rows (breakdown, category, group, metric, mean, std, runs) for a CSV file."""
    rows: list[dict[str, Any]] = []
    for g, group in enumerate(comparison.groups):
        for metric, stat in comparison.overall[g].items():
            if stat is not None:
                rows.append(_row("overall", "all", group.label, metric, stat))
    for name, cats in comparison.scores.items():
        for cat, cells in cats.items():
            for group, cell in zip(comparison.groups, cells, strict=True):
                for metric, stat in (cell or {}).items():
                    if stat is not None:
                        rows.append(_row(name, cat, group.label, metric, stat))
    return rows


def _row(breakdown: str, category: str, group: str, metric: str, stat: Stat) -> dict[str, Any]:
    return {
        "breakdown": breakdown,
        "category": category,
        "group": group,
        "metric": metric,
        "mean": stat.mean,
        "std": "" if stat.std is None else stat.std,
        "runs": stat.n,
    }
