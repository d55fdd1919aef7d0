"""Scenario parameters from a route file, with units, defaults and ranges, and the errors that name them.

Upstream mixes units (``reference/SCENARIOS.md``, "Conventions"): each :class:`Param` carries its unit
("m", "m/s", "km/h", "deg", or "" for a word), and values are stored in that unit; a scenario converts
km/h to m/s where it uses one. ``<frequency from="20" to="100"/>`` is a :class:`Range` param.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from cmudrive.bench.route_spec import ParamValue, ScenarioSpec

KMH = 1.0 / 3.6  # [m/s per km/h]


class ScenarioError(ValueError):
    """A scenario that cannot be set up; the message names the route, the scenario and what is wrong."""

    def __init__(self, route_id: str, scenario: str, problem: str) -> None:
        super().__init__(route_id, scenario, problem)
        self.route_id, self.scenario, self.problem = route_id, scenario, problem

    def __str__(self) -> str:
        return f"route {self.route_id!r}, scenario {self.scenario!r}: {self.problem}"


@dataclass(frozen=True)
class Param:
    """One parameter: name, unit, default and inclusive range (a word param lists its ``choices``)."""

    name: str
    unit: str
    default: float | str | tuple[float, ...] | None
    lo: float = -math.inf
    hi: float = math.inf
    choices: tuple[str, ...] = ()
    is_range: bool = False  # <name from="a" to="b"/>: a (from, to) pair, both in [lo, hi], from <= to
    is_location: bool = False  # <name x="..." y="..." z="..."/>: a CARLA-frame point [m], (x, y, z)
    required: bool = False  # no default: the route file must give it


DIRECTION = Param("direction", "", "right", choices=("right", "left"))


Value = float | str | tuple[float, ...] | None


def parse_params(spec: ScenarioSpec, route_id: str, params: tuple[Param, ...]) -> dict[str, Value]:
    """The scenario's parameter values (defaults filled in); ScenarioError for an unknown parameter, a
    value that is not a number, out of range, or not one of the choices."""
    known = {p.name: p for p in params}
    out: dict[str, Value] = {p.name: p.default for p in params}
    for name, raw in spec.params.items():
        if name not in known:
            allowed = ", ".join(sorted(known)) or "none"
            raise ScenarioError(
                route_id, spec.name, f"unknown parameter {name!r} for type {spec.type} (allowed: {allowed})"
            )
        out[name] = _value(known[name], raw, route_id, spec.name)
    for p in params:
        if p.required and p.name not in spec.params:
            raise ScenarioError(
                route_id, spec.name, f"missing required parameter {p.name!r} for type {spec.type}"
            )
    return out


def _value(p: Param, raw: ParamValue, route_id: str, scenario: str) -> Value:
    def fail(why: str) -> ScenarioError:
        unit = f" [{p.unit}]" if p.unit else ""
        return ScenarioError(route_id, scenario, f"parameter {p.name!r}{unit}: {why}")

    if p.is_location:
        if not isinstance(raw, dict) or not {"x", "y"} <= set(raw) <= {"x", "y", "z", "yaw", "pitch", "roll"}:
            raise fail(f"expected <{p.name} x=... y=... z=.../>, got {raw!r}")
        return tuple(_number(raw.get(k, "0"), fail) for k in ("x", "y", "z"))
    if p.is_range:
        if not isinstance(raw, dict) or set(raw) != {"from", "to"}:
            raise fail(f"expected <{p.name} from=... to=.../>, got {raw!r}")
        lo, hi = (_number(raw[k], fail) for k in ("from", "to"))
        for v in (lo, hi):
            _in_range(p, v, fail)
        if lo > hi:
            raise fail(f"'from' {lo} is larger than 'to' {hi}")
        return (lo, hi)
    if not isinstance(raw, str):
        raise fail(f"expected a single value, got {raw!r}")
    if p.choices:
        if raw not in p.choices:
            raise fail(f"{raw!r} is not one of {', '.join(p.choices)}")
        return raw
    v = _number(raw, fail)
    _in_range(p, v, fail)
    return v


def _number(raw: str, fail: Callable[[str], ScenarioError]) -> float:
    try:
        v = float(raw)
    except ValueError:
        raise fail(f"{raw!r} is not a number") from None
    if not math.isfinite(v):
        raise fail(f"{raw!r} is not a finite number")
    return v


def _in_range(p: Param, v: float, fail: Callable[[str], ScenarioError]) -> None:
    if not p.lo <= v <= p.hi:
        raise fail(f"{v:g} is outside [{p.lo:g}, {p.hi:g}]")
