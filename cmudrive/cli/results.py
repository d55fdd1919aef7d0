"""The results of a run on the console: a table in a terminal, plain lines in a log."""

from __future__ import annotations

from typing import Any

from rich.table import Table

from cmudrive.cli.common import (
    console,
)

PER_ROUTE_TABLE_MAX = 12  # routes; larger runs print one row per scenario type

# infraction keys a failure status already says (and minimum speed, which is recorded without penalty)
_IMPLIED_BY_STATUS = frozenset({"min_speed_infractions", "vehicle_blocked", "route_dev", "route_timeout"})


def failures(route: dict[str, Any]) -> str:
    """Why a route is not a success, per CAV: its status (when not completed) and its infractions."""
    parts = []
    for cav in route.get("cavs", []):
        status = str(cav["status"])
        why = [status.removeprefix("Failed - Agent ").removeprefix("Failed - ")] if "Failed" in status else []
        why += sorted(k for k, v in cav["infractions"].items() if v and k not in _IMPLIED_BY_STATUS)
        if why:
            parts.append(f"{cav['cav_id']}: {', '.join(why)}")
    if route.get("error") and not parts:
        parts.append(str(route["status"]))
    return "; ".join(parts)


def _route_line(r: dict[str, Any]) -> str:
    """One route's results on one line, every field, the whole failure reason (logs)."""
    why = failures(r)
    return (
        f"route {r['route_id']} ({r.get('scenario_type') or 'no scenario'}): {r['town']}, {r['weather']}, "
        f"{r['num_cavs']} CAVs, {r['status']}, RC {r['route_completion']:.1f}, "
        f"IS {r['infraction_score']:.3f}, DS {r['driving_score']:.1f}" + (f"; why: {why}" if why else "")
    )


def _results_table(merged: dict[str, Any]) -> Table:
    """A row per route (up to ``PER_ROUTE_TABLE_MAX`` routes) or per scenario type, with why routes failed."""
    routes = merged["routes"]
    if len(routes) <= PER_ROUTE_TABLE_MAX:
        table = Table(title="CMU-Drive results")
        for col in ("route", "town", "weather", "CAVs", "status", "RC", "IS", "DS", "why not a success"):
            table.add_column(col)
        for r in routes:
            table.add_row(
                str(r["route_id"]),
                r["town"],
                r["weather"],
                str(r["num_cavs"]),
                r["status"],
                f"{r['route_completion']:.1f}",
                f"{r['infraction_score']:.3f}",
                f"{r['driving_score']:.1f}",
                failures(r),
            )
    else:
        table = Table(title="CMU-Drive results by scenario type")
        for col in (
            "scenario type",
            "routes",
            "DS",
            "SR %",
            "why not a success (route: CAV: why)",
        ):
            table.add_column(col)
        by_type: dict[str, list[dict[str, Any]]] = {}
        for r in routes:
            by_type.setdefault(str(r.get("scenario_type") or "-"), []).append(r)
        for name, group in by_type.items():
            scores = merged["summary"]["by_scenario_type"].get(name)
            ds = f"{scores['driving_score']:.1f}" if scores else "-"
            sr = f"{scores['success_rate']:.0f}" if scores else "-"
            why = " | ".join(f"{r['route_id']}: {failures(r)}" for r in group if not r["success"])
            table.add_row(name, str(len(group)), ds, sr, why)
    return table


def print_results(merged: dict[str, Any]) -> None:
    """The results of a run: a table in a terminal; where stdout is not one (a log file), plain lines that
    no width cuts: one per route with every field and why it failed, then one per scenario type."""
    routes = merged["routes"]
    if console.is_terminal:
        console.print(_results_table(merged))
    else:
        for r in routes:
            console.print(_route_line(r), soft_wrap=True, highlight=False, markup=False)
        if len(routes) > PER_ROUTE_TABLE_MAX:
            by_type = merged["summary"]["by_scenario_type"]
            for name in dict.fromkeys(str(r.get("scenario_type") or "-") for r in routes):
                if name in by_type:
                    ds, sr = by_type[name]["driving_score"], by_type[name]["success_rate"]
                    console.print(f"scenario type {name}: DS {ds:.1f}, SR {sr:.0f} %", soft_wrap=True)
    s = merged["summary"]
    invalid = s.get("num_invalid", 0)
    console.print(
        f"driving score {s['driving_score']:.2f}, success rate {s['success_rate']:.2f} %, "
        f"{s['num_routes']} routes" + (f" ({invalid} invalid routes skipped, not scored)" if invalid else "")
    )
