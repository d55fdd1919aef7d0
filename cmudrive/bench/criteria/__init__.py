"""Route criteria: every CAV of a route scored as SCORING.md specifies (Leaderboard 2.0, Bench2Drive variant).

:class:`RouteCriteria` (``engine``) is fed one snapshot and its collision events per tick and keeps, for
each CAV, its route completion RC_i, its infractions (``cmudrive.bench.records``: keys, penalty factors,
status strings) and whether its evaluation has ended; :class:`CriteriaConfig` (``config``) holds every
threshold with its unit. One module per criterion: ``progress`` (route index, completion, deviation,
timeout budget), ``collisions`` and ``layout`` (static scenery), ``red_lights`` and ``stop_signs`` (on
``stop_lines``), ``lanes`` (outside route lanes), ``min_speed``. All of them work on arrays over the
route's CAVs; nothing loops over background actors. ``docs/scoring.md`` carries the same table.

Defaults (Bench2Drive) and how each rule is implemented, with every place where it differs from CARLA's
scenario_runner / leaderboard criteria:

===================  ==============================================  =========================================
Criterion            Rule as implemented here                        Where it differs from CARLA (and why)
===================  ==============================================  =========================================
Route completion     RC_i [%]. Each tick the route index moves to    The box centre stands for CARLA's actor
                     the furthest of the current and the next 3      location. One route index also feeds
                     dense-route points (1 m apart) whose forward    deviation, outside-lanes, minimum speed
                     direction the CAV's box centre has passed       and the timeout budget (CARLA's tests
                     ((p-point).forward > 0). RC_i = route distance  each track their own).
                     at that index / route length x 100. Above 99 %
                     with the centre within 10 m of the last point,
                     RC_i = 100 and the CAV is finished as
                     completed.

Collisions           collisions_pedestrian 0.5, collisions_vehicle   2D oriented boxes without height, and a
                     0.6, collisions_layout 0.65. A CollisionEvents  contact is seen on every tick the boxes
                     pair with a running CAV on one side is a        overlap (CARLA's sensor reports physics
                     contact of that CAV (a CAV-CAV pair is a        contacts); the time and distance rules
                     contact of each). It counts unless the CAV is   turn it into one event. Parked cars are
                     slower than 0.1 m/s, the same other actor was   vehicles (kind CAR, static), as in CARLA;
                     counted for this CAV within 5 s, or the CAV's   cones and signs are props. The same-
                     centre is within 5 m of where it was at its     actor rule remembers every other actor
                     last counted collision. The key follows the     (CARLA: only the last one). Some
                     other actor's kind: PEDESTRIAN gives            scenario_runner versions use 3 m / 5 m
                     pedestrian, PROP layout, anything else (cars,   location rules; we use SCORING.md's 5 m.
                     trucks, bicycles, motorcycles, emergency
                     vehicles, other CAVs) vehicle.

Layout collisions    collisions_layout 0.65. A running CAV's box     CARLA: physics contacts with the town's
(static scenery)     against the map's static scenery boxes          meshes. Ours: boxes derived from the map
                     (``layout``: cKDTree broad phase, the SAT of    (``docs/scenery.md``), without height;
                     actor collisions), counted under the same       the CAV passes through instead of
                     rules; actor ``scenery:<kind>:<index>``.        stopping.

Red light            red_light 0.7. The rear segment runs from 0.8   SUMO link signals and the lanes' stop
                     x half length behind the centre to 1 m behind   lines replace light actors and their
                     the rear bumper. Its far end's driving lane     trigger volumes (SUMO networks have no
                     (within 90 deg of the heading and half a lane   trigger volumes). Signals are per link,
                     width + 0.5 m) selects the lane's stop line     so a lane can show a green arrow beside a
                     (the map's stop line at the lane end,           red (CARLA: one light per lane). One
                     stretched to 1.2 lane widths). Crossing it in   infraction per passage rather than per
                     the direction of travel while the lane's SUMO   light in a row.
                     link signal is r or u is one infraction; where
                     the lane's links differ, the link of the CAV's
                     route (else the one nearest its front bumper)
                     decides. The same line counts again only after
                     the CAV was 15 m away from it.

Stop sign            stop_infraction 0.8. For STOP_SIGN and          CARLA's area is the sign's trigger volume
                     ALLWAY_STOP lines. A CAV is at the stop from    (its size varies per map), entered when
                     the tick its centre is on the approach lane     the volume lies within 4 m ahead of the
                     (within 90 deg and half a lane width + 0.5 m,   vehicle's lane waypoint. We use the last
                     so never when driving against it) with its      4 m of the approach lane at the front
                     front bumper at most 4 m before the line,       bumper because SUMO networks only have
                     until its centre passes the line. A speed       the stop line.
                     below 0.1 m/s while at the stop satisfies it;
                     the centre passing the line without that is
                     one infraction. A CAV leaving the lane
                     sideways first is released without a verdict.

Outside route lanes  outside_route_lanes 1 - pct/100. Outside: the   Inside a junction's outline (SUMO's
                     centre is farther than lane width / 2 + 0.5 m   junction shape) a CAV is never outside:
                     from the nearest driving lane's centreline and  SUMO's internal lanes are thin paths over
                     from the nearest parking lane's, and not        the paved junction, and a CAV cutting a
                     inside a junction's outline. Wrong way: the     turn by 2-3 m would be charged (the lane-
                     nearest driving lane is a normal (not           following autopilot on downtown was, on
                     junction-internal) lane at 120 deg or more to   1-3 % of its routes), where CARLA's
                     the heading; per-CAV switch                     overlapping junction lanes cover the
                     (set_wrong_direction_check). The route          junction. Wrong way is judged each tick
                     distance advanced while outside or wrong-way    from the angle to the nearest lane; CARLA
                     is summed; when the CAV finishes, pct = that    tracks lane-id sign changes and junction
                     sum / completed route distance x 100 gives one  exits, with hysteresis.
                     infraction with factor 1 - pct/100.

Route deviation      route_dev; Failed - Agent deviated from the     The window starts at the route-completion
                     route. The nearest of 6 route points from the   index; CARLA's InRouteTest follows its
                     route index on is 30 m or more away, or the     own closest point.
                     route distance advanced while that nearest
                     point was more than 15 m away exceeds 30 % of
                     the route length. The CAV is finished.

Blocked              vehicle_blocked; Failed - Agent got blocked.    Time counted in ticks x dt rather than
                     Slower than 0.1 m/s for more than 60 s          the game clock (the same at a fixed
                     (consecutive ticks x dt). suspend_blocked       step).
                     pauses the test while a scenario's own timeout
                     runs; the clock restarts from zero.

Route timeout        route_timeout; Failed - Agent timed out. Route  The speed limit is the route lane's SUMO
                     time (ticks x dt since the route started)       speed, not the limit the vehicle last
                     exceeds 300 s plus, for every route point       read from a sign.
                     passed, the metres before it / (0.1 x the
                     speed limit there).

Tick cap             Failed - TickRuntime. The evaluator calls       None (Bench2Drive's cap).
                     end_route after EvalConfig.tick_cap (4000)
                     ticks; every running CAV gets the status.

Minimum speed        min_speed_infractions (factor 1, recorded       'Surrounding traffic' is background
                     only). The route is cut into 20 parts of equal  vehicles (not pedestrians, props or
                     length. Each tick with background vehicles      scenario actors) within 50 m; CARLA
                     within 50 m of the CAV adds the CAV's speed     averages all background-activity
                     and those vehicles' mean speed to the part's    vehicles, which it keeps around the ego.
                     two sums. A part's value is 100 x CAV sum /     Parts are cut by distance.
                     traffic sum, or 100 when it had no traffic.
                     Parts below 100 % are listed with factor 1.

Scenario timeout     scenario_timeouts 0.7.                          None.
                     record_scenario_timeout(cav, tick, message)
                     records one infraction; the scenario calls it
                     when its own timeout expires.

Yield to EV          yield_emergency_vehicle_infractions 0.7.        Evaluated once, when the scenario calls
                     record_yield_to_emergency_vehicle(cav, ev_xy,   it (CARLA takes the value at scenario
                     ev_heading) at the scenario's end: infraction   end).
                     when (cav-ev).forward_ev > 0 (CAV centre still
                     ahead of the EV's centre along its heading).

Status and IS_i      Perfect / Completed / Failed - <reason>. IS_i   Per CAV of a multi-CAV route; the route-
                     is the product of all infraction factors.       level aggregation is in
                     Perfect: RC_i = 100 and no infraction except    cmudrive/bench/metrics.py.
                     minimum-speed records. Completed: RC_i = 100
                     with infractions. Otherwise the failure that
                     ended the CAV, or Running.
===================  ==============================================  =========================================

Throughout: positions are the centres of the snapshot's 2D boxes in the map frame (CARLA: actor
locations in 3D); CAV i is scored by its own criteria, exactly like one ego in CARLA, and leaves the
world when it finishes; a route shorter than 100 m completes only once the CAV has passed its last point
(as in CARLA, whose routes are longer).
"""

from cmudrive.bench.criteria.config import CriteriaConfig
from cmudrive.bench.criteria.engine import RouteCriteria

__all__ = ["CriteriaConfig", "RouteCriteria"]
