"""The pictures of the comparison page (:mod:`cmudrive.viz.compare_report`): bar charts of DS, SR, RC and IS
overall and per breakdown (mean and sample standard deviation per group of runs), and a map per town with a
marker per infraction record.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from cmudrive.bench.compare import B2D_SUCCESS, BREAKDOWNS, METRICS, OVERALL, Comparison, Stat
from cmudrive.bench.records import INFRACTION_KEYS, record_stem
from cmudrive.bench.report import EMPTY
from cmudrive.viz.infraction_map import InfractionPoint, group_colour, save_infraction_map

CHART_DPI = 110  # [dots/inch]
NO_SCENARIO = "(no scenario)"  # the scenario type "" of routes without one


def _bars(
    ax: Axes, categories: Sequence[str], values: list[list[Stat | None]], colours: Sequence[str]
) -> None:
    """Grouped bars: per category one bar per group (``values[group][category]``), error bars = std."""
    n = len(values)
    width = 0.8 / max(n, 1)
    x = np.arange(len(categories), dtype=np.float64)
    for g, stats in enumerate(values):
        means = np.array([s.mean if s else np.nan for s in stats])
        errs = np.array([s.std if s and s.std is not None else np.nan for s in stats])  # NaN: no whisker
        pos = x - 0.4 + width * (g + 0.5)
        ax.bar(pos, means, width, color=colours[g])
        for xi in pos[np.isnan(means)]:  # a category none of the group's runs has: "-", not an empty 0
            ax.text(
                xi, 0.01, EMPTY, transform=ax.get_xaxis_transform(), ha="center", va="bottom", color="0.45"
            )
        spread = np.isfinite(errs) & np.isfinite(means)
        if spread.any():
            ax.errorbar(
                pos[spread],
                means[spread],
                yerr=errs[spread],
                fmt="none",
                ecolor="black",
                elinewidth=0.8,
                capsize=2.5,
            )
    ax.set_xticks(x)
    ax.set_xticklabels(
        [c or NO_SCENARIO for c in categories], fontsize=8, rotation=90 if len(categories) > 8 else 0
    )
    for tick in ax.get_xticklabels():
        tick.set_parse_math(False)
    pad = max(0.0, 0.5 * (3 - len(categories)))  # few categories: bars no wider than with three
    ax.set_xlim(-0.6 - pad, len(categories) - 0.4 + pad)
    ax.grid(axis="y", color="0.9", linewidth=0.8)
    ax.set_axisbelow(True)


Cell = dict[str, Stat | None] | None  # a group's numbers in one category (None: none of its runs has it)


def _chart(
    path: Path,
    comparison: Comparison,
    categories: list[str],
    cells: Sequence[Sequence[Cell]],
    title: str,
    xlabel: str,
    metrics: Sequence[str],
) -> Path:
    """One panel per metric, bars per category and group (``cells[category][group]``), the groups'
    legend at the right."""
    groups = comparison.groups
    width = min(max(5.0, 0.22 * max(len(categories), 3) * len(groups) + 2.0), 20.0) + 2.8
    fig = Figure(figsize=(width, 2.3 * len(metrics) + 0.9), dpi=CHART_DPI, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(metrics), 1, sharex=True, squeeze=False)[:, 0]
    colours = [group_colour(g) for g in range(len(groups))]
    for ax, metric in zip(axes, metrics, strict=True):
        values = [[(c[g] or {}).get(metric) if c[g] else None for c in cells] for g in range(len(groups))]
        _bars(ax, categories, values, colours)
        ax.set_ylim(0.0, 1.05 if metric == "infraction_score" else 105.0)
        ax.set_ylabel(_metric_label(metric), fontsize=9)
    axes[-1].set_xlabel(xlabel)
    axes[0].set_title(title, fontsize=10)
    fig.legend(handles=_group_patches(comparison), loc="outside right upper", fontsize=8, frameon=False)
    fig.savefig(path, dpi=CHART_DPI)
    return path


def _group_patches(comparison: Comparison) -> list[Artist]:
    return [Patch(color=group_colour(g), label=grp.label) for g, grp in enumerate(comparison.groups)]


def _overall_chart(path: Path, comparison: Comparison) -> Path:
    """DS, SR, RC and IS x 100 side by side, a bar per group (whiskers: std over its runs)."""
    scale = {"infraction_score": 100.0}
    values = [
        [_scaled(comparison.overall[g].get(m), scale.get(m, 1.0)) for m in METRICS]
        for g in range(len(comparison.groups))
    ]
    labels = ["IS x 100" if m == "infraction_score" else METRICS[m] for m in METRICS]
    fig = Figure(figsize=(8.5, 3.4), dpi=CHART_DPI, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    _bars(ax, labels, values, [group_colour(g) for g in range(len(comparison.groups))])
    ax.set_ylim(0.0, 105.0)
    ax.set_ylabel("score / %")
    ax.set_title("Overall (bars: mean over seeds, whiskers: std)", fontsize=10)
    fig.legend(handles=_group_patches(comparison), loc="outside right upper", fontsize=8, frameon=False)
    fig.savefig(path, dpi=CHART_DPI)
    return path


def _scaled(stat: Stat | None, factor: float) -> Stat | None:
    if stat is None:
        return None
    return Stat(stat.mean * factor, None if stat.std is None else stat.std * factor, stat.n)


def _metric_label(metric: str) -> str:
    if metric == B2D_SUCCESS:
        return "B2D success (%)"
    return METRICS.get(metric, OVERALL.get(metric, metric))


def write_charts(comparison: Comparison, out: Path) -> dict[str, Path]:
    """The overall chart (DS, SR, RC, IS per group, error bars = std) and one per breakdown that has
    categories (DS and SR per category and group)."""
    charts: dict[str, Path] = {}
    charts["overall"] = _overall_chart(out / "compare_overall.png", comparison)
    for b in BREAKDOWNS:
        cats = comparison.categories[b.name]
        if not cats:
            continue
        cells = [comparison.scores[b.name][c] for c in cats]
        charts[b.name] = _chart(
            out / f"compare_by_{b.name}.png",
            comparison,
            cats,
            cells,
            f"DS and SR per {b.title} (bars: mean over seeds, whiskers: std)",
            b.title,
            ["driving_score", "success_rate"],
        )
    return charts


# ------------------------------------------------------------------------------------------------------
# maps


def infraction_points(comparison: Comparison) -> dict[str, list[InfractionPoint]]:
    """Every infraction record of every run, per town, with its group."""
    towns: dict[str, list[InfractionPoint]] = {}
    for g, group in enumerate(comparison.groups):
        for run in group.runs:
            for r in run.routes:
                points = towns.setdefault(r.town, [])
                for c in r.cavs:
                    for key in INFRACTION_KEYS:
                        points += [InfractionPoint(g, key, i.x, i.y) for i in c.infractions.get(key, [])]
    return towns


def _search_dirs(comparison: Comparison) -> list[Path]:
    """Folders of the runs' route files: a town given as a file beside its route file is found there."""
    dirs = []
    for group in comparison.groups:
        for run in group.runs:
            if run.route_file:
                dirs.append(Path(run.route_file).parent)
    return dirs


def write_maps(comparison: Comparison, out: Path) -> list[tuple[str, Path | None, str]]:
    """One PNG per town with infraction records; towns without any and towns whose map cannot be loaded get
    a note instead."""
    from cmudrive.maps import load_map

    labels = [g.label for g in comparison.groups]
    maps: list[tuple[str, Path | None, str]] = []
    for i, (town, points) in enumerate(sorted(infraction_points(comparison).items())):
        placed = [p for p in points if math.isfinite(p.x) and math.isfinite(p.y)]
        unplaced = len(points) - len(placed)
        name = Path(town).name.removesuffix(".net.xml")
        if not points:
            maps.append((name, None, "no infraction record"))
            continue
        try:
            road_map = load_map(town, search=_search_dirs(comparison))
        except Exception as e:  # any map failure: the page says why, the rest of it still works
            maps.append((name, None, f"map not drawn: {type(e).__name__}: {e}"))
            continue
        path = out / f"map_{i:02d}_{record_stem(name)}.png"
        counts = save_infraction_map(path, road_map, points, labels, f"Infractions in {name}")
        per_group = {g: sum(n for (h, _), n in counts.items() if h == g) for g, _ in counts}
        note = f"{sum(counts.values())} markers: " + ", ".join(
            f"{labels[g]} {n}" for g, n in sorted(per_group.items())
        )
        if unplaced:
            note += f"; {unplaced} records without a place not drawn"
        maps.append((name, path, note))
    return maps
