"""Results I/O and the benchmark report: markdown and CSV tables plus charts from route result records.

The evaluator writes each finished route to ``DIR/routes/<route_id>.json`` (one ``RouteResult.to_json()``
object) and the merged set to ``DIR/results.json``; ``load_results`` reads either. ``write_report``
summarises them (``metrics.summarize``) into::

    summary.md               overall metrics and breakdowns by scenario type, ability, weather, CAV count
    summary.csv              the same numbers, one row per (breakdown, group)
    routes.csv               one row per route
    by_scenario_type.png     DS and SR per scenario type with routes (the paper's Figure 3 on cmudrive220)
    by_num_cavs.png          DS and SR per number of CAVs on the route
    by_weather.png           DS and SR per weather preset

Charts are drawn with matplotlib's Agg canvas (no pyplot state), 150 dpi. A group without routes (a scenario
type, ability or weather no route has) is left out of every table and chart alike; routes without a scenario
are the type "(none)". ``cmudrive report`` writes these for one run beside its comparison page
(:mod:`cmudrive.viz.compare_report`).

Records are validated when read (``RouteResult.from_json``: ranges, statuses, consistency); a bad one is
a ``ResultsError`` naming the file and the record. Text from the records is written inertly: markdown
cells are HTML-escaped (``<``, ``>``, ``&``; ``|`` and line breaks too, which would break the table), and
CSV text cells that a spreadsheet would run as a formula (starting with ``= + - @``, tab or carriage
return) get a leading ``'`` (OWASP's advice for CSV injection). Numbers are written as they are.
"""

from __future__ import annotations

import csv
import html
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.artist import Artist
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from cmudrive.bench.metrics import (
    is_crashed,
    is_success,
    route_comfort,
    route_efficiency,
    summarize,
)
from cmudrive.bench.records import INFRACTION_KEYS, RouteResult

DPI = 150  # [dots/inch] of the PNG charts
DS_COLOR = "#1f5fa8"  # driving score bars
SR_COLOR = "#f28e2b"  # success rate bars
EMPTY = "–"  # table cell of a group without routes


class ResultsError(ValueError):
    """A results file or folder that cannot be read; the message names the file."""


# ------------------------------------------------------------------------------------------------------
# loading


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise ResultsError(f"{path}: malformed JSON (line {e.lineno}, column {e.colno}: {e.msg})") from e
    except RecursionError:  # json's decoder recurses per level: 100k nested brackets exhaust the stack
        raise ResultsError(f"{path}: JSON nested too deeply to be a results file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ResultsError(f"{path}: cannot read ({e})") from e


def _records(path: Path, data: Any) -> list[RouteResult]:
    """Route records of one JSON document: a list of routes, ``{"routes": [...]}``, or one route."""
    if isinstance(data, dict) and "routes" in data:
        data = data["routes"]
    items = data if isinstance(data, list) else [data]
    out = []
    for i, item in enumerate(items):
        try:
            if not isinstance(item, dict):
                raise TypeError(f"expected an object, got {type(item).__name__}")
            out.append(RouteResult.from_json(item))
        except (TypeError, KeyError, AttributeError, ValueError) as e:
            where = f"record {i}" if isinstance(data, list) else "record"
            raise ResultsError(f"{path}: {where} is not a route result ({e})") from None
    return out


def load_results(path: str | Path) -> list[RouteResult]:
    """Route results from a results file, or a results folder: ``DIR/results.json`` when it exists, else
    every ``DIR/routes/*.json`` (sorted by name), else every ``DIR/*.json`` (``DIR`` is the routes folder
    itself). Raises ``ResultsError`` naming the offending file."""
    path = Path(path)
    if path.is_file():
        return _records(path, _read_json(path))
    if not path.is_dir():
        raise ResultsError(f"{path}: no such results file or folder")
    merged = path / "results.json"
    if merged.is_file():
        return _records(merged, _read_json(merged))
    folder = path / "routes" if (path / "routes").is_dir() else path
    files = sorted(folder.glob("*.json"))
    if not files:
        raise ResultsError(f"{path}: no results.json, no routes/ folder and no route records (*.json)")
    return [r for f in files for r in _records(f, _read_json(f))]


# ------------------------------------------------------------------------------------------------------
# tables


def _fmt(value: Any, digits: int = 2) -> str:
    """A markdown table cell: numbers to ``digits`` places, text HTML-escaped with ``|`` and line breaks
    made harmless."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return EMPTY
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    text = html.escape(str(value), quote=False).replace("|", "\\|")
    return " ".join(text.splitlines())


FORMULA_START = ("=", "+", "-", "@", "\t", "\r")  # a spreadsheet runs a cell starting so as a formula


def _csv_cell(value: Any) -> Any:
    """A CSV cell: text a spreadsheet would run as a formula gets a leading ``'``; numbers unchanged."""
    if isinstance(value, str) and value.startswith(FORMULA_START):
        return "'" + value
    return value


def _csv_row(writer: Any, row: Sequence[Any]) -> None:
    writer.writerow([_csv_cell(v) for v in row])


def _md_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + ["---:"] * (len(header) - 1)) + "|"]
    lines += ["| " + " | ".join(_fmt(v) for v in row) + " |" for row in rows]
    return [*lines, ""]


def _group_rows(groups: dict[Any, dict[str, Any]]) -> list[list[Any]]:
    """One row per group with routes (``metrics.breakdown`` lists only those, in order): name, routes, DS,
    SR."""
    return [
        [k or "(none)", g["num_routes"], g["driving_score"], g["success_rate"]] for k, g in groups.items()
    ]


def _overall_rows(s: dict[str, Any]) -> list[list[Any]]:
    expected = s["num_expected"] if s["num_expected"] is not None else s["num_routes"]
    ability = s["multi_ability"]
    return [
        ["Driving score DS (0-100)", s["driving_score"]],
        ["Success rate SR (%)", s["success_rate"]],
        ["Route completion (%)", s["route_completion"]],
        ["Infraction score (0-1, routes present)", s["infraction_score"]],
        ["Efficiency (%)", s["efficiency"]],
        ["Comfortness (%)", s["comfortness"]],
        ["Multi-ability mean (%)", ability["mean"]],
        ["Routes evaluated / expected", f"{s['num_routes']} / {expected}"],
        ["Routes missing", s["num_missing"]],
        ["Routes crashed", s["num_crashed"]],
    ]


def summary_markdown(s: dict[str, Any], title: str = "cmudrive benchmark report") -> str:
    """The summary as markdown: overall metrics, then one table per breakdown."""
    head = ["group", "routes", "DS (0-100)", "SR (%)"]
    lines = [f"# {title}", "", "## Overall", ""]
    lines += _md_table(["metric", "value"], _overall_rows(s))
    lines += [
        "DS and SR are sums over routes divided by the expected number of routes (missing routes count 0)",
        "when it is given, else by the routes evaluated; breakdowns are over the routes evaluated.",
        "",
        "## Multi-ability (Bench2Drive success, %)",
        "",
    ]
    abilities = [[k, v] for k, v in s["multi_ability"].items() if v is not None]  # groups with routes
    lines += _md_table(["ability", "success rate (%)"], abilities)
    lines += ["## By ability", ""]
    lines += _md_table(["ability", *head[1:]], _group_rows(s["by_ability"]))
    lines += ["## By number of CAVs", ""]
    lines += _md_table(["CAVs", *head[1:]], _group_rows(s["by_num_cavs"]))
    lines += ["## By weather", ""]
    lines += _md_table(["weather", *head[1:]], _group_rows(s["by_weather"]))
    lines += ["## By scenario type", "", "![DS and SR by scenario type](by_scenario_type.png)", ""]
    lines += _md_table(["scenario type", *head[1:]], _group_rows(s["by_scenario_type"]))
    per_km = s["infractions_per_km"]
    if per_km is not None:
        lines += ["## Infractions per km driven (all CAVs)", ""]
        lines += _md_table(["infraction", "per km"], [[k, v] for k, v in per_km.items()])
    link = s.get("v2v")
    if link is not None:
        lines += ["## V2V link (all routes)", ""]
        lines += _md_table(["counter", "value"], [[k, v] for k, v in link.items()])
    lines += ["![by number of CAVs](by_num_cavs.png) ![by weather](by_weather.png)", ""]
    return "\n".join(lines)


def _write_summary_csv(path: Path, s: dict[str, Any]) -> None:
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["breakdown", "group", "num_routes", "driving_score", "success_rate"])
        w.writerow(["overall", "all", s["num_routes"], s["driving_score"], s["success_rate"]])
        for name in ("by_scenario_type", "by_ability", "by_weather", "by_num_cavs"):
            for k, g in s[name].items():
                _csv_row(w, [name, k, g["num_routes"], g["driving_score"], g["success_rate"]])
        for k, v in s["multi_ability"].items():
            w.writerow(["multi_ability", k, "", "", "" if v is None else v])
        for key in ("route_completion", "infraction_score", "efficiency", "comfortness"):
            w.writerow(["overall", key, "", "", "" if s[key] is None else s[key]])


ROUTE_COLUMNS = (
    "route_id", "town", "weather", "scenario_type", "num_cavs", "status", "route_completion",
    "infraction_score", "driving_score", "success", "b2d_success", "efficiency", "comfort", "ticks",
    "wall_time", "crashed", *INFRACTION_KEYS,
)  # fmt: skip


def _write_routes_csv(path: Path, routes: Sequence[RouteResult]) -> None:
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(ROUTE_COLUMNS)
        for r in routes:
            eff, comfort = route_efficiency(r), route_comfort(r)
            counts = [sum(len(c.infractions.get(k, [])) for c in r.cavs) for k in INFRACTION_KEYS]
            _csv_row(w, [
                r.route_id, r.town, r.weather, r.scenario_type, r.num_cavs, r.status, r.route_completion,
                r.infraction_score, r.driving_score, int(r.success), int(is_success(r)),
                "" if eff is None else eff, "" if comfort is None else comfort, r.ticks, r.wall_time,
                int(is_crashed(r)), *counts,
            ])  # fmt: skip


# ------------------------------------------------------------------------------------------------------
# charts


def _bar_chart(
    path: Path,
    groups: dict[Any, dict[str, Any]],
    labels: Sequence[Any],
    *,
    xlabel: str,
    title: str,
    mean_ds: float | None,
    size: tuple[float, float],
    rotate: bool,
) -> None:
    """Grouped bars of DS and SR per label (empty for labels without routes, whose tick label is grey),
    the number of routes above each group, bar values when there are few groups."""
    fig = Figure(figsize=size, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    x = np.arange(len(labels), dtype=np.float64)
    width = 0.4
    ds = np.array([groups[k]["driving_score"] if k in groups else np.nan for k in labels])
    sr = np.array([groups[k]["success_rate"] if k in groups else np.nan for k in labels])
    ds_bars = ax.bar(x - width / 2, ds, width, color=DS_COLOR)
    sr_bars = ax.bar(x + width / 2, sr, width, color=SR_COLOR)
    handles: list[Artist] = [
        Patch(color=DS_COLOR, label="driving score DS (0-100)"),
        Patch(color=SR_COLOR, label="success rate SR (%)"),
    ]
    if mean_ds is not None:
        handles.append(ax.axhline(mean_ds, color=DS_COLOR, linestyle="--", linewidth=1.0))
        handles[-1].set_label(f"mean DS of the routes run: {mean_ds:.1f}")
    handles.append(Patch(color="none", label="numbers on top: routes"))
    if not groups:
        ax.text(0.5, 0.5, "no routes", transform=ax.transAxes, ha="center", va="center", color="0.5")
    if len(labels) <= 16:
        for bars, values in ((ds_bars, ds), (sr_bars, sr)):
            text = ["" if np.isnan(v) else f"{v:.0f}" for v in values]
            ax.bar_label(bars, text, padding=1.5, fontsize=7, color="0.25")
    for xi, k in zip(x, labels, strict=True):
        n = groups[k]["num_routes"] if k in groups else 0
        ax.text(xi, 107.0, f"{n}", ha="center", va="bottom", fontsize=7, color="0.3" if n else "0.65")
    ax.set_xticks(x)
    ax.set_xticklabels([str(k) or "(none)" for k in labels], rotation=90 if rotate else 0, fontsize=8)
    for tick, k in zip(ax.get_xticklabels(), labels, strict=True):
        tick.set_parse_math(False)  # a group name from a record is text, not mathtext ("$\\frac{$" raised)
        if k not in groups:
            tick.set_color("0.6")
    pad = max(0.0, 0.5 * (4 - len(labels)))  # few groups: bars no wider than with four
    ax.set_xlim(-0.7 - pad, len(labels) - 0.3 + pad)
    ax.set_ylim(0.0, 113.0)
    ax.set_yticks(np.arange(0, 101, 20))
    ax.set_ylabel("DS (points, 0-100) / SR (%)")
    ax.set_xlabel(xlabel)
    ax.set_title(title)
    ax.grid(axis="y", color="0.9", linewidth=0.8)
    ax.set_axisbelow(True)
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    fig.savefig(path, dpi=DPI)


def write_charts(s: dict[str, Any], out_dir: Path, mean_ds: float | None = None) -> list[Path]:
    """The three PNG charts of a summary (``mean_ds``: reference line, the mean DS of the routes evaluated);
    returns their paths."""
    types = list(s["by_scenario_type"])  # those with routes, in SCENARIO_TYPES order (metrics.breakdown)
    paths = [out_dir / "by_scenario_type.png", out_dir / "by_num_cavs.png", out_dir / "by_weather.png"]
    many = len(types) > 8  # rotated labels on a chart as wide as they need (15 in for all 44 types)
    size = (min(15.0, 2.5 + 0.3 * len(types)), 6.0) if many else (8.0, 4.5)  # [in], the others' size
    _bar_chart(paths[0], s["by_scenario_type"], types, xlabel="scenario type", size=size, rotate=many,
               title="Driving score and success rate per scenario type", mean_ds=mean_ds)  # fmt: skip
    _bar_chart(paths[1], s["by_num_cavs"], list(s["by_num_cavs"]), xlabel="number of CAVs on the route",
               size=(8.0, 4.5), rotate=False, title="Driving score and success rate by number of CAVs",
               mean_ds=mean_ds)  # fmt: skip
    _bar_chart(paths[2], s["by_weather"], list(s["by_weather"]), xlabel="weather preset", size=(8.0, 4.5),
               rotate=False, title="Driving score and success rate by weather", mean_ds=mean_ds)  # fmt: skip
    return paths


# ------------------------------------------------------------------------------------------------------
# report


def write_report(
    results: str | Path | Sequence[RouteResult],
    out_dir: str | Path,
    *,
    expected_routes: int | None = None,
    title: str = "cmudrive benchmark report",
) -> list[Path]:
    """Write ``summary.md``, ``summary.csv``, ``routes.csv`` and the three charts into ``out_dir`` (created)
    from a results file or folder (``load_results``) or route records; returns the paths written.
    ``expected_routes``: the benchmark's route count (220), so that missing routes count 0."""
    routes = load_results(results) if isinstance(results, (str, Path)) else list(results)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    s = summarize(routes, expected_routes)
    md, summary_csv, routes_csv = out / "summary.md", out / "summary.csv", out / "routes.csv"
    md.write_text(summary_markdown(s, title), encoding="utf-8")
    _write_summary_csv(summary_csv, s)
    _write_routes_csv(routes_csv, routes)
    mean_ds = sum(r.driving_score for r in routes) / len(routes) if routes else None
    return [md, summary_csv, routes_csv, *write_charts(s, out, mean_ds)]
