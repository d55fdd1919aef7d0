"""Benchmark metrics: pure functions from per-CAV results to route scores and route-set summaries.

Route level (the CMU-Drive paper's equations, ``reference/SCORING.md`` §4), for route j with N CAVs::

    RC^j = mean_i RC_i      IS^j = prod_i IS_i      DS^j = RC^j * IS^j      SS^j = [DS^j == 100]

Route-set level (Bench2Drive, §3): DS and SR are means of DS^j and SS^j over the routes (missing routes
count 0 when the expected number of routes is given, as Bench2Drive divides by 220); efficiency,
comfortness (smoothness) and the multi-ability success rates. Scales: DS in [0, 100]; SR, route
completion, efficiency, comfortness and ability success rates in percent.

Differences from the public Bench2Drive tools (``docs/scoring.md``, "Aggregation"): the comfort score is
computed in physical units with the real frame time (``comfort_score``), and the ability groups use the
correctly spelled scenario names and count each route once (``ABILITIES``, ``passes_traffic_signs``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Iterable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import savgol_filter

from cmudrive.bench.records import (
    INFRACTION_KEYS,
    STATUS_AGENT_CRASHED,
    STATUS_COMPLETED,
    STATUS_INVALID_ROUTE,
    STATUS_PERFECT,
    STATUS_SIM_CRASHED,
    CavResult,
    RouteResult,
)
from cmudrive.bench.scenario_types import SCENARIO_TYPES

SUCCESS_TOLERANCE = 1e-9  # [score points] DS^j counts as 100 within this
UNPENALISED_KEYS = frozenset({"min_speed_infractions"})  # infractions a Bench2Drive success may have
MAX_EFFICIENCY = 1000.0  # [%] min-speed checkpoints above this are dropped (Bench2Drive)

# --- comfort (Bench2Drive "smoothness", thresholds from nuPlan's ego comfort metrics) ---
COMFORT_WINDOW = 20  # [frames] frames per judged window (1 s at 20 Hz)
SAVGOL_WINDOW = 7  # [frames] Savitzky-Golay window length
SAVGOL_POLYORDER = 2  # Savitzky-Golay polynomial order
MIN_LON_ACCEL = -4.05  # [m/s^2] exclusive lower bound of the longitudinal acceleration
MAX_LON_ACCEL = 2.40  # [m/s^2] exclusive upper bound of the longitudinal acceleration
MAX_ABS_LAT_ACCEL = 4.89  # [m/s^2]
MAX_ABS_JERK = 8.37  # [m/s^3] rate of change of the acceleration magnitude
MAX_ABS_LON_JERK = 4.13  # [m/s^3] rate of change of the longitudinal acceleration
MAX_ABS_YAW_ACCEL = 1.93  # [rad/s^2]
MAX_ABS_YAW_RATE = 0.95  # [rad/s]
FRAME_TIME_TOLERANCE = 0.01  # [-] relative spread of frame intervals accepted as uniform

# --- multi-ability groups (Bench2Drive), correctly spelled: every name is in SCENARIO_TYPES ---
ABILITIES: dict[str, frozenset[str]] = {
    "Overtaking": frozenset(
        {
            "Accident",
            "AccidentTwoWays",
            "ConstructionObstacle",
            "ConstructionObstacleTwoWays",
            "HazardAtSideLaneTwoWays",
            "HazardAtSideLane",
            "ParkedObstacleTwoWays",
            "ParkedObstacle",
            "VehicleOpensDoorTwoWays",
        }
    ),
    "Merging": frozenset(
        {
            "CrossingBicycleFlow",
            "EnterActorFlow",
            "HighwayExit",
            "InterurbanActorFlow",
            "HighwayCutIn",
            "InterurbanAdvancedActorFlow",
            "MergerIntoSlowTrafficV2",
            "MergerIntoSlowTraffic",
            "NonSignalizedJunctionLeftTurn",
            "NonSignalizedJunctionRightTurn",
            "NonSignalizedJunctionLeftTurnEnterFlow",
            "ParkingExit",
            "SequentialLaneChange",
            "SignalizedJunctionLeftTurn",
            "SignalizedJunctionRightTurn",
            "SignalizedJunctionLeftTurnEnterFlow",
        }
    ),
    "Emergency_Brake": frozenset(
        {
            "BlockedIntersection",
            "DynamicObjectCrossing",
            "HardBreakRoute",
            "OppositeVehicleTakingPriority",
            "OppositeVehicleRunningRedLight",
            "ParkingCutIn",
            "PedestrianCrossing",
            "ParkingCrossingPedestrian",
            "StaticCutIn",
            "VehicleTurningRoute",
            "VehicleTurningRoutePedestrian",
            "ControlLoss",
        }
    ),
    "Give_Way": frozenset({"InvadingTurn", "YieldToEmergencyVehicle"}),
    "Traffic_Signs": frozenset(
        {
            "BlockedIntersection",
            "OppositeVehicleTakingPriority",
            "OppositeVehicleRunningRedLight",
            "PedestrianCrossing",
            "VehicleTurningRoute",
            "VehicleTurningRoutePedestrian",
            "EnterActorFlow",
            "CrossingBicycleFlow",
            "NonSignalizedJunctionLeftTurn",
            "NonSignalizedJunctionRightTurn",
            "NonSignalizedJunctionLeftTurnEnterFlow",
            "SignalizedJunctionLeftTurn",
            "SignalizedJunctionRightTurn",
            "SignalizedJunctionLeftTurnEnterFlow",
            "T_Junction",
            "VanillaNonSignalizedTurn",
            "VanillaSignalizedTurnEncounterGreenLight",
            "VanillaSignalizedTurnEncounterRedLight",
            "VanillaNonSignalizedTurnEncounterStopsign",
        }
    ),
}
TRAFFIC_SIGN_KEYS = ("red_light", "stop_infraction")  # infractions that fail the Traffic_Signs ability


# ------------------------------------------------------------------------------------------------------
# route level


def route_scores(cavs: Sequence[CavResult]) -> tuple[float, float, float, bool]:
    """(RC^j [%], IS^j, DS^j, SS^j) of one route from its CAVs' RC_i and IS_i (the paper's equations)."""
    if not cavs:
        raise ValueError("route_scores: a route needs at least one CAV result")
    rc = math.fsum(c.route_completion for c in cavs) / len(cavs)
    is_ = math.prod(c.infraction_score for c in cavs)
    ds = max(rc * is_, 0.0)
    return rc, is_, ds, abs(ds - 100.0) <= SUCCESS_TOLERANCE


def route_status(cavs: Sequence[CavResult]) -> str:
    """Route status: "Perfect" if every CAV is perfect, "Completed" if every CAV finished, else the first
    CAV failure in CAV order; "Failed - Simulation crashed" when there are no CAV results."""
    if not cavs:
        return STATUS_SIM_CRASHED
    if all(c.status == STATUS_PERFECT for c in cavs):
        return STATUS_PERFECT
    if all(c.status in (STATUS_PERFECT, STATUS_COMPLETED) for c in cavs):
        return STATUS_COMPLETED
    return next(c.status for c in cavs if c.status not in (STATUS_PERFECT, STATUS_COMPLETED))


def route_result(
    route_id: str,
    town: str,
    weather: str,
    scenario_type: str,
    cavs: Sequence[CavResult],
    *,
    status: str | None = None,
    num_cavs: int | None = None,
    seed: int = 0,
    ticks: int = 0,
    wall_time: float = 0.0,
    error: str | None = None,
) -> RouteResult:
    """A ``RouteResult`` with the paper's route scores (``route_scores``) and status (``route_status``).

    ``status`` overrides the derived status (crashes); ``num_cavs`` defaults to ``len(cavs)`` and is given
    for a route that crashed before any CAV was scored: with no CAV results the route scores RC^j = 0,
    IS^j = 1 (the empty product), DS^j = 0 and no success."""
    if cavs:
        rc, is_, ds, ss = route_scores(cavs)
    else:
        rc, is_, ds, ss = 0.0, 1.0, 0.0, False
    return RouteResult(
        route_id=route_id,
        town=town,
        weather=weather,
        scenario_type=scenario_type,
        num_cavs=len(cavs) if num_cavs is None else num_cavs,
        status=status if status is not None else route_status(cavs),
        route_completion=rc,
        infraction_score=is_,
        driving_score=ds,
        success=ss,
        cavs=list(cavs),
        seed=seed,
        ticks=ticks,
        wall_time=wall_time,
        error=error,
    )


def is_success(result: CavResult | RouteResult) -> bool:
    """Bench2Drive success: finished ("Perfect"/"Completed"), completion 100 %, and every infraction list
    empty except ``min_speed_infractions``. A route succeeds when all its CAVs do (and it has some)."""
    if isinstance(result, RouteResult):
        return bool(result.cavs) and all(is_success(c) for c in result.cavs)
    return (
        result.status in (STATUS_PERFECT, STATUS_COMPLETED)
        and result.route_completion >= 100.0 - SUCCESS_TOLERANCE
        and not any(events for key, events in result.infractions.items() if key not in UNPENALISED_KEYS)
    )


def passes_traffic_signs(route: RouteResult) -> bool:
    """Traffic_Signs ability of one route: no red-light or stop infraction by any CAV, and either the route
    succeeded or CAV 0 got past its first junction (``route_completion > first_junction_completion``).
    Without the junction share (None) this is plain route success."""
    if not route.cavs:
        return False
    if any(c.infractions.get(k) for c in route.cavs for k in TRAFFIC_SIGN_KEYS):
        return False
    if is_success(route):
        return True
    lead = route.cavs[0]
    return lead.first_junction_completion is not None and (
        lead.route_completion > lead.first_junction_completion
    )


def efficiency(min_speed_checkpoints: Iterable[float]) -> float | None:
    """Driving efficiency [%]: mean of the min-speed checkpoint percentages (ego speed as a share of the
    surrounding traffic's), values above ``MAX_EFFICIENCY`` dropped; None when none is left."""
    kept = [v for v in min_speed_checkpoints if v <= MAX_EFFICIENCY]
    return math.fsum(kept) / len(kept) if kept else None


def _mean_or_none(values: Iterable[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return math.fsum(kept) / len(kept) if kept else None


def route_efficiency(route: RouteResult) -> float | None:
    """Mean over the route's CAVs of their efficiency [%] (CAVs without checkpoints skipped)."""
    return _mean_or_none(efficiency(c.min_speed_checkpoints) for c in route.cavs)


def route_comfort(route: RouteResult) -> float | None:
    """Mean over the route's CAVs of their comfort share [0..1] (CAVs without a score skipped)."""
    return _mean_or_none(c.comfort for c in route.cavs)


# ------------------------------------------------------------------------------------------------------
# comfort


def _frame_time(t: np.ndarray) -> float:
    dts = np.diff(t)
    if not np.all(dts > 0.0):
        raise ValueError("comfort_score: times must be strictly increasing")
    dt = float(np.median(dts))
    if np.max(np.abs(dts - dt)) > FRAME_TIME_TOLERANCE * dt:
        raise ValueError(f"comfort_score: frames must be evenly spaced (median frame time {dt:.4g} s)")
    return dt


def comfort_signals(
    t: ArrayLike, x: ArrayLike, y: ArrayLike, yaw: ArrayLike, speed: ArrayLike
) -> dict[str, np.ndarray]:
    """Smoothed comfort quantities per frame, each shape (n,), n >= ``SAVGOL_WINDOW``.

    Inputs, shape (n,): ``t`` time [s] (evenly spaced), ``x``/``y`` position [m], ``yaw`` heading [rad]
    (counter-clockwise from +x, any wrapping), ``speed`` [m/s]. Derivatives are Savitzky-Golay
    derivatives (window 7, order 2) with ``delta`` = the real frame time:

    - ``lon_accel`` [m/s^2] = d speed / dt;
    - ``lat_accel`` [m/s^2] = the position's second derivative projected on the body's left axis;
    - ``jerk`` [m/s^3] = d|a|/dt, |a| the magnitude of the position's second derivative (nuPlan's
      definition, for which the threshold was set);
    - ``lon_jerk`` [m/s^3] = d lon_accel / dt;
    - ``yaw_rate`` [rad/s] and ``yaw_accel`` [rad/s^2] = first and second derivatives of the unwrapped yaw.
    """
    arrays = [np.asarray(a, dtype=np.float64) for a in (t, x, y, yaw, speed)]
    n = arrays[0].shape
    if any(a.ndim != 1 or a.shape != n for a in arrays):
        raise ValueError("comfort_score: t, x, y, yaw and speed must be 1-D arrays of one length")
    if n[0] < SAVGOL_WINDOW:
        raise ValueError(f"comfort_score: need at least {SAVGOL_WINDOW} frames, got {n[0]}")
    if not all(np.all(np.isfinite(a)) for a in arrays):
        raise ValueError("comfort_score: non-finite value in the trajectory")
    t_, x_, y_, yaw_, speed_ = arrays
    dt = _frame_time(t_)

    def sg(v: np.ndarray, deriv: int) -> np.ndarray:
        return np.asarray(savgol_filter(v, SAVGOL_WINDOW, SAVGOL_POLYORDER, deriv=deriv, delta=dt))

    heading = np.unwrap(yaw_)
    ax, ay = sg(x_, 2), sg(y_, 2)  # [m/s^2] world frame
    lon_accel = sg(speed_, 1)
    lat_accel = -np.sin(heading) * ax + np.cos(heading) * ay
    return {
        "lon_accel": lon_accel,
        "lat_accel": lat_accel,
        "jerk": sg(np.hypot(ax, ay), 1),
        "lon_jerk": sg(lon_accel, 1),
        "yaw_rate": sg(heading, 1),
        "yaw_accel": sg(heading, 2),
    }


def comfort_score(t: ArrayLike, x: ArrayLike, y: ArrayLike, yaw: ArrayLike, speed: ArrayLike) -> float | None:
    """Share [0..1] of comfortable 20-frame windows of one CAV's trajectory (Bench2Drive smoothness).

    The frames are cut into consecutive windows of ``COMFORT_WINDOW`` frames (a trailing partial window is
    dropped, as in Bench2Drive); a window is comfortable when every frame in it has, after smoothing
    (``comfort_signals``), longitudinal acceleration in (-4.05, 2.40) m/s^2, |lateral acceleration| <
    4.89 m/s^2, |jerk| < 8.37 m/s^3, |longitudinal jerk| < 4.13 m/s^3, |yaw acceleration| < 1.93 rad/s^2
    and |yaw rate| < 0.95 rad/s. None when there are fewer than 20 frames.

    Differences from the public Bench2Drive script (``tools/efficiency_smoothness_benchmark.py``), whose
    numbers are therefore not comparable with ours:

    1. it reads CARLA's angular velocity, which is in deg/s, as rad/s: its yaw-rate bound is effectively
       0.95 deg/s (any real turn fails it); we differentiate the yaw in rad;
    2. it differentiates with a 0.1 s frame time although frames come at 20 Hz (0.05 s), so its jerks are
       half the true value; we use the real frame time from ``t``;
    3. its "yaw acceleration" is the smoothed yaw rate itself, not its derivative; we take the second
       derivative of the yaw;
    4. it smooths each 20-frame window on its own; we smooth the whole trajectory once, so derivatives at a
       window's edge use the neighbouring frames rather than a one-sided fit (an event less than ~6 frames,
       0.3 s, from a window's edge can therefore also mark the neighbouring window);
    5. it evaluates a trajectory of at most 20 frames as one window; we return None below 20 frames.

    It reads CARLA's acceleration vector; we have positions and speed, so the longitudinal acceleration
    is d speed / dt and the lateral one comes from the positions' second derivative.
    """
    if np.ndim(t) != 1:
        raise ValueError("comfort_score: t, x, y, yaw and speed must be 1-D arrays of one length")
    n = len(np.asarray(t))
    if n < COMFORT_WINDOW:
        return None
    s = comfort_signals(t, x, y, yaw, speed)
    ok = (
        (s["lon_accel"] > MIN_LON_ACCEL)
        & (s["lon_accel"] < MAX_LON_ACCEL)
        & (np.abs(s["lat_accel"]) < MAX_ABS_LAT_ACCEL)
        & (np.abs(s["jerk"]) < MAX_ABS_JERK)
        & (np.abs(s["lon_jerk"]) < MAX_ABS_LON_JERK)
        & (np.abs(s["yaw_accel"]) < MAX_ABS_YAW_ACCEL)
        & (np.abs(s["yaw_rate"]) < MAX_ABS_YAW_RATE)
    )
    windows = n // COMFORT_WINDOW
    return float(ok[: windows * COMFORT_WINDOW].reshape(windows, COMFORT_WINDOW).all(axis=1).mean())


# ------------------------------------------------------------------------------------------------------
# route-set summary


def abilities_of(scenario_type: str) -> list[str]:
    """The ability groups a scenario type belongs to, in ``ABILITIES`` order."""
    return [name for name, types in ABILITIES.items() if scenario_type in types]


def multi_ability(routes: Sequence[RouteResult]) -> dict[str, float | None]:
    """Success rate [%] per ability group over the routes present (``is_success``; ``passes_traffic_signs``
    for Traffic_Signs), None for a group without routes, and ``"mean"`` over the groups with routes."""
    rates: dict[str, float | None] = {}
    for name, types in ABILITIES.items():
        members = [r for r in routes if r.scenario_type in types]
        passed = passes_traffic_signs if name == "Traffic_Signs" else is_success
        rates[name] = 100.0 * sum(passed(r) for r in members) / len(members) if members else None
    rates["mean"] = _mean_or_none(list(rates.values()))
    return rates


def _group_scores(routes: Sequence[RouteResult]) -> dict[str, float | int]:
    n = len(routes)
    return {
        "driving_score": math.fsum(r.driving_score for r in routes) / n,
        "success_rate": 100.0 * sum(r.success for r in routes) / n,
        "num_routes": n,
    }


def breakdown(
    routes: Sequence[RouteResult],
    keys: Callable[[RouteResult], Iterable[Hashable]],
    order: Sequence[Hashable] = (),
) -> dict[str, dict[str, float | int]]:
    """DS / SR [%] / number of routes per group; ``keys(route)`` names the groups a route is in. Groups
    come in ``order`` first, then the others sorted by their text; only groups with routes appear."""
    groups: dict[Hashable, list[RouteResult]] = {}
    for r in routes:
        for k in keys(r):
            groups.setdefault(k, []).append(r)
    known = [k for k in order if k in groups]
    rest = sorted((k for k in groups if k not in set(order)), key=str)
    return {str(k): _group_scores(groups[k]) for k in (*known, *rest)}  # str keys: as JSON writes them


OUTSIDE_KEY = "outside_route_lanes"


def infractions_per_km(routes: Sequence[RouteResult]) -> dict[str, float] | None:
    """Infraction events per key, over all CAVs, per km driven (route length x completion); None if no
    distance was driven. For ``outside_route_lanes`` the value is, as upstream, the kilometres driven
    outside the route's lanes per km driven (its record's factor is 1 - the share outside)."""
    driven = [(c, c.route_length * c.route_completion / 100.0) for r in routes for c in r.cavs]
    km = math.fsum(m for _, m in driven) / 1000.0
    if km <= 0.0:
        return None
    out = {k: sum(len(c.infractions.get(k, [])) for c, _ in driven) / km for k in INFRACTION_KEYS}
    outside = math.fsum(
        (1.0 - inf.factor) * metres for c, metres in driven for inf in c.infractions.get(OUTSIDE_KEY, [])
    )
    out[OUTSIDE_KEY] = outside / 1000.0 / km
    return out


def is_crashed(route: RouteResult) -> bool:
    """True when the agent or the simulation crashed during the route."""
    return route.error is not None or route.status in (STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED)


def v2v_totals(routes: Sequence[RouteResult]) -> dict[str, float | None] | None:
    """The V2V link counters summed over the routes that have them (``RouteResult.v2v``), with
    ``bytes_per_message`` recomputed from the sums and ``named_share``: the share of partner choices
    (``cav_ticks``) in which the agent named a partner itself (None without choices); None when no route
    has counters (an agent without V2V). Counters a route's record lacks (older records) count 0."""
    counters = [r.v2v for r in routes if r.v2v is not None]
    if not counters:
        return None
    keys = sorted({k for c in counters for k in c} - {"bytes_per_message", "named_share"})
    sums = {k: sum(c.get(k, 0) for c in counters) for k in keys}
    messages, ticks = sums.get("messages", 0), sums.get("cav_ticks", 0)
    return {
        **sums,
        "bytes_per_message": sums.get("bytes", 0) / messages if messages else 0.0,
        "named_share": sums.get("named", 0) / ticks if ticks else None,
    }


def summarize(routes: Sequence[RouteResult], expected_routes: int | None = None) -> dict[str, Any]:
    """Route-set summary (Bench2Drive style with the paper's route scores).

    - ``driving_score`` (DS, 0..100), ``success_rate`` (SR, % of routes with SS^j) and
      ``route_completion`` (%): sums over the routes divided by R = ``expected_routes`` when given
      (missing routes count 0, as Bench2Drive divides by 220), else by the number of routes present;
    - ``infraction_score``: mean IS^j of the routes present that have CAV results;
    - ``efficiency`` [%] and ``comfortness`` [%]: means over the routes that have a value (a route's
      value is the mean over its CAVs);
    - ``multi_ability``: see ``multi_ability``; ``num_routes``, ``num_expected``, ``num_missing``,
      ``num_crashed`` (``is_crashed``); ``infractions_per_km``: see ``infractions_per_km``; ``v2v``: the
      link counters over all routes (``v2v_totals``), None for an agent without V2V;
    - breakdowns over the routes present, ``{group: {"driving_score", "success_rate", "num_routes"}}``:
      ``by_scenario_type``, ``by_ability``, ``by_weather``, ``by_num_cavs`` (keys are strings, as in
      the JSON file: "2", "16").

    Routes recorded "Failed - Invalid route" (``eval --skip-invalid``: they could not run at all) are
    counted in ``num_invalid`` and left out of everything else: they neither count 0 in DS / SR / RC
    (R shrinks by them) nor appear in ``num_routes`` or the breakdowns; the agent was never tested there.
    """
    num_invalid = sum(r.status == STATUS_INVALID_ROUTE for r in routes)
    if num_invalid:
        routes = [r for r in routes if r.status != STATUS_INVALID_ROUTE]
        expected_routes = expected_routes - num_invalid if expected_routes is not None else None
    ids = [r.route_id for r in routes]
    if len(set(ids)) != len(ids):
        dup = sorted({i for i in ids if ids.count(i) > 1})
        raise ValueError(f"summarize: duplicate route ids {dup}")
    if expected_routes is not None and expected_routes < len(routes):
        raise ValueError(f"summarize: {len(routes)} routes but expected_routes={expected_routes}")
    denom = expected_routes if expected_routes is not None else len(routes)
    comfort = _mean_or_none(route_comfort(r) for r in routes)

    def over_r(values: Iterable[float]) -> float:
        return math.fsum(values) / denom if denom else 0.0

    return {
        "driving_score": over_r(r.driving_score for r in routes),
        "success_rate": 100.0 * over_r(float(r.success) for r in routes),
        "route_completion": over_r(r.route_completion for r in routes),
        "infraction_score": _mean_or_none(r.infraction_score for r in routes if r.cavs),
        "num_routes": len(routes),
        "num_expected": expected_routes,
        "num_missing": (expected_routes - len(routes)) if expected_routes is not None else 0,
        "num_crashed": sum(is_crashed(r) for r in routes),
        "num_invalid": num_invalid,
        "efficiency": _mean_or_none(route_efficiency(r) for r in routes),
        "comfortness": 100.0 * comfort if comfort is not None else None,
        "multi_ability": multi_ability(routes),
        "by_scenario_type": breakdown(routes, lambda r: [r.scenario_type], SCENARIO_TYPES),
        "by_ability": breakdown(routes, lambda r: abilities_of(r.scenario_type), tuple(ABILITIES)),
        "by_weather": breakdown(routes, lambda r: [r.weather], _weather_order()),
        "by_num_cavs": breakdown(routes, lambda r: [r.num_cavs], tuple(range(1, 65))),
        "infractions_per_km": infractions_per_km(routes),
        "v2v": v2v_totals(routes),
    }


def _weather_order() -> tuple[str, ...]:
    """The weather presets in their defined order (unknown names sort after them)."""
    from cmudrive.sim.weather import WEATHERS  # local: keeps importing the metrics free of libsumo

    return tuple(WEATHERS)
