"""Language labels (``cmudrive.data.language``) on hand-built scenes of real towns and one closed loop of
the expert before a red light."""

from __future__ import annotations

import time
import zlib
from collections.abc import Sequence

import numpy as np
import pytest

from cmudrive.agents import Observations
from cmudrive.agents.expert import ExpertDecision, Reason
from cmudrive.agents.expert.detour import DetourReason
from cmudrive.data import Language, LanguageInputs, describe
from cmudrive.data.language import colour_names, direction, route_actions, speed_actions
from cmudrive.maps import RoadMap, Route, densify, load_map
from cmudrive.maps.model import StopKind, TurnDir
from cmudrive.sensors._mesh import VEHICLE_PAINTS
from cmudrive.sensors.visibility import Visibility, compute_visibility
from cmudrive.sim.snapshot import ActorKind, Role, Snapshot
from tests.test_expert import expert_for, lights_all, route_through, scene
from tests.test_expert_detour import CAV_S, ONE_WAY, TWO_WAY, Actor, Scene

NO_FUTURE = np.full((1, 5), np.nan)


@pytest.fixture(scope="module")
def downtown() -> RoadMap:
    return load_map("downtown")


def decision(
    snap: Snapshot,
    cav_rows: np.ndarray,
    paths: np.ndarray,
    reason: Sequence[int] | None = None,
    object_row: Sequence[int] | None = None,
    distance: Sequence[float] | None = None,
    target_speed: Sequence[float] | None = None,
    detour: tuple[Sequence[int], Sequence[int]] | None = None,
) -> ExpertDecision:
    """A hand-made decision for the CAVs at ``cav_rows`` (CAV index = position) with planned ``paths``."""
    n = len(cav_rows)
    rows = np.array(object_row if object_row is not None else [-1] * n, np.int64)
    kind = np.where(rows >= 0, snap.kind[np.maximum(rows, 0)], -1).astype(np.int8)
    return ExpertDecision(
        tick=0,
        cav_index=np.arange(n),
        target_speed=np.array(target_speed if target_speed is not None else snap.speed[cav_rows], float),
        desired_speed=np.array(target_speed if target_speed is not None else snap.speed[cav_rows], float),
        accel=np.zeros(n),
        reason=np.array(reason if reason is not None else [Reason.NONE] * n, np.int8),
        object_row=rows,
        object_id=np.where(rows >= 0, snap.ids[np.maximum(rows, 0)], "").astype(str),
        object_kind=kind,
        distance=np.array(distance if distance is not None else [np.inf] * n, float),
        path=paths,
        route_index=np.zeros(n, np.int64),
        detour_reason=np.array(detour[0] if detour else [DetourReason.NONE] * n, np.int8),
        detour_row=np.array(detour[1] if detour else [-1] * n, np.int64),
    )


def labels(
    snap: Snapshot, d: ExpertDecision, road_map: RoadMap, future: np.ndarray | None = None
) -> list[Language]:
    rows = np.flatnonzero(snap.role == Role.CAV)
    vis = compute_visibility(snap, rows, 120.0)
    n = len(rows)
    future = future if future is not None else np.tile(d.target_speed[:, None], (1, 5))
    return describe(LanguageInputs(snap, d, rows, vis, future, n, road_map))


def lane_path(sc: Scene, s: float, d: float = 0.0, sign: float = 1.0) -> np.ndarray:
    """(40, 2) points 1 m apart along the scene's lane from arc length ``s`` (backwards when sign < 0)."""
    along = s + sign * np.arange(40.0)
    lane = np.full(40, sc.lane)
    return sc.map.index.frenet_to_xy(lane, along, np.full(40, d))


def id_with_paint(colour: int, prefix: str) -> str:
    """An actor id that the camera paints ``VEHICLE_PAINTS[colour]``."""
    return next(
        f"{prefix}{k}"
        for k in range(1000)
        if zlib.crc32(f"{prefix}{k}".encode()) % len(VEHICLE_PAINTS) == colour
    )


# ------------------------------------------------------------------ (1) red light, closed loop
def test_closed_loop_red_light_stop_is_said(downtown: RoadMap) -> None:
    """The expert drives CAV 0 (point-mass kinematics with its own commanded acceleration) toward a red
    light 30 m ahead at 8 m/s, labelled every 5th tick with its own future target speeds: it slows down,
    then comes to a stop, then stays stopped, each time 'for the red light'."""
    m = downtown
    lane = str(m.lane_ids[m.stop_lane[np.flatnonzero(m.stop_kind == StopKind.TRAFFIC_LIGHT)[0]]])
    route, line = route_through(m, lane)
    agent = expert_for(m, [route])
    at, v = line - 30.0, 8.0
    ticks = []
    for t in range(130):
        snap, obs = scene(route, at, v, tls=lights_all(m, "r"), tick=t)
        agent.run_step(obs)
        assert agent.decision is not None
        ticks.append((snap, agent.decision))
        v_next = max(v + float(agent.decision.accel[0]) * 0.05, 0.0)
        at += 0.5 * (v + v_next) * 0.05
        v = v_next
    target = np.array([d.target_speed[0] for _, d in ticks])
    said = []
    for t in range(0, 100, 5):
        snap, d = ticks[t]
        rows = np.array([0])
        vis = compute_visibility(snap, rows, 120.0)
        lang = describe(LanguageInputs(snap, d, rows, vis, target[None, t + 5 : t + 30 : 5], 1, m))[0]
        assert lang.reason == "red_light" and lang.commentary.endswith(" for the red light.")
        assert lang.communication == "" and lang.partner_label == -1
        said.append(lang.speed_action)
    assert said[0] == "decelerate" and "stop" in said and said[-1] == "stopped"
    assert said.index("decelerate") < said.index("stop") < said.index("stopped")
    snap, d = ticks[-1]
    lang = labels(snap, d, m, target[None, -5:])[0]
    assert "Stay stopped for the red light." in lang.commentary


# ------------------------------------------------------------------ (2) communication
def occluded_walker_scene(van: bool, far_cav: bool = False) -> tuple[Scene, Snapshot, ExpertDecision]:
    """Downtown's two-way street: CAV 0 at 5 m/s, a van parked on the right 8 m ahead, a pedestrian just
    past it (hidden from CAV 0 by the van when ``van``), CAV 1 coming the other way 30 m ahead (and CAV 2
    50 m ahead when ``far_cav``). CAV 0's expert slows down for the pedestrian."""
    sc = Scene(*TWO_WAY)
    w = sc.width
    actors = [
        Actor(CAV_S + 30.0, w, 5.0, ActorKind.CAR, Role.CAV, 4.89, 2.10, yaw=np.pi, name="cav1"),
        Actor(CAV_S + 13.0, -0.5 * w - 0.75, 0.0, ActorKind.PEDESTRIAN, length=0.5, width=0.6, name="walker"),
    ]
    if far_cav:
        actors.insert(
            1, Actor(CAV_S + 50.0, w, 5.0, ActorKind.CAR, Role.CAV, 4.89, 2.10, yaw=np.pi, name="cav2")
        )
    if van:
        actors.append(
            Actor(CAV_S + 8.0, -0.5 * w - 0.9, 0.0, ActorKind.VAN, length=5.4, width=2.05, name="van")
        )
    snap = sc.snapshot(0.0, actors)
    cavs = np.flatnonzero(snap.role == Role.CAV)
    paths = np.stack(
        [lane_path(sc, CAV_S)] + [lane_path(sc, float(snap_s), w, -1.0) for snap_s in (50.0, 70.0)]
    )
    walker = snap.index_of("walker")
    n = len(cavs)
    d = decision(
        snap,
        cavs,
        paths[:n],
        reason=[Reason.PEDESTRIAN] + [Reason.NONE] * (n - 1),
        object_row=[walker] + [-1] * (n - 1),
        distance=[13.0 - 2.45 - 0.25] + [np.inf] * (n - 1),
        target_speed=[3.0] + [5.0] * (n - 1),
    )
    return sc, snap, d


def test_hidden_walker_is_named_with_the_cav_that_sees_it() -> None:
    sc, snap, d = occluded_walker_scene(van=True)
    walker = snap.index_of("walker")
    vis = compute_visibility(snap, np.flatnonzero(snap.role == Role.CAV), 120.0)
    assert not vis.actors[0, walker] and vis.actors[1, walker]  # the scene does what it says
    lang = labels(snap, d, sc.map)
    assert lang[0].partner_label == 1 and lang[0].critical_row == walker
    assert lang[0].communication.startswith("CAV 1 can see the pedestrian in ")
    assert "ahead on the right" in lang[0].communication or " ahead," in lang[0].communication
    assert lang[0].speed_action == "decelerate" and lang[0].reason == "pedestrian"
    assert "Slow down for the pedestrian in " in lang[0].commentary
    assert lang[1].communication == "" and lang[1].partner_label == -1


def test_no_communication_when_the_cav_sees_the_walker_itself() -> None:
    sc, snap, d = occluded_walker_scene(van=False)
    lang = labels(snap, d, sc.map)
    assert lang[0].critical_row == snap.index_of("walker")
    assert lang[0].communication == "" and lang[0].partner_label == -1


def test_the_partner_is_the_cav_nearest_to_the_hidden_object() -> None:
    sc, snap, d = occluded_walker_scene(van=True, far_cav=True)
    walker = snap.index_of("walker")
    vis = compute_visibility(snap, np.flatnonzero(snap.role == Role.CAV), 120.0)
    assert vis.actors[1, walker] and vis.actors[2, walker]
    lang = labels(snap, d, sc.map)
    assert lang[0].partner_label == 1 and lang[0].communication.startswith("CAV 1 ")


def test_without_an_object_reason_the_critical_object_is_the_first_in_the_path() -> None:
    """CAV 0 stops for a red light; a car stands 20 m ahead in its lane: that car is its critical object."""
    sc = Scene(*ONE_WAY)
    snap = sc.snapshot(0.0, [Actor(CAV_S + 20.0, 0.0, role=Role.BACKGROUND, name="car")], cav_speed=0.0)
    d = decision(
        snap, np.array([0]), lane_path(sc, CAV_S)[None], reason=[Reason.RED_LIGHT], target_speed=[0.0]
    )
    lang = labels(snap, d, sc.map)[0]
    assert lang.critical_row == 1 and lang.commentary == "Stay on the route. Stay stopped for the red light."


# ------------------------------------------------------------------ (3) speed bands
@pytest.mark.parametrize(
    ("speed", "future", "expected"),
    [
        (0.1, [0.0, 0.1, 0.0, 0.1, 0.0], "stopped"),
        (3.0, [0.1, 0.0, 0.0, 0.0, 0.0], "stop"),
        (5.0, [5.4, 5.4, 5.4, 5.4, 5.4], "keep"),
        (5.0, [4.6, 4.6, 4.6, 4.6, 4.6], "keep"),
        (5.0, [5.6, 5.6, 5.6, 5.6, 5.6], "accelerate"),
        (5.0, [4.4, 4.4, 4.4, 4.4, 4.4], "decelerate"),
        (0.0, [1.0, 2.0, 3.0, np.nan, np.nan], "accelerate"),  # the mean of the known samples: 2 m/s
        (0.1, [0.4, 0.4, 0.4, 0.4, 0.4], "accelerate"),  # standing, about to move
        (5.0, [np.nan] * 5, "decelerate"),  # the CAV ended: the current target speed (4 m/s)
    ],
)
def test_speed_action_bands(speed: float, future: list[float], expected: str) -> None:
    assert speed_actions(np.array([speed]), np.array([future]), np.array([4.0]))[0] == expected


# ------------------------------------------------------------------ (4) route actions
def turning_route(m: RoadMap, turn: TurnDir) -> tuple[Route, float]:
    """A dense route through the first signalised link of direction ``turn``; the route distance of the
    junction entry."""
    links = np.flatnonzero((m.link_dir == turn) & (m.link_tls >= 0) & (m.link_via >= 0))
    link = int(links[0])
    src, out = int(m.link_from[link]), int(m.link_to[link])
    length = float(m.lane_length[src])
    pts = [
        m.index.frenet_to_xy(np.array([src]), np.array([max(length - 60.0, 0.5)]))[0],
        m.index.frenet_to_xy(np.array([src]), np.array([length - 1.0]))[0],
        m.index.frenet_to_xy(np.array([out]), np.array([min(40.0, float(m.lane_length[out]) - 1.0)]))[0],
    ]
    route = densify(m, np.array(pts))
    on = np.flatnonzero(route.lane == src)
    return route, float(route.distance[on[-1]] + length - route.s[on[-1]])


@pytest.mark.parametrize(
    ("turn", "code"),
    [(TurnDir.LEFT, "turn_left"), (TurnDir.RIGHT, "turn_right"), (TurnDir.STRAIGHT, "follow")],
)
def test_turn_is_said_within_20m_of_the_junction_only(downtown: RoadMap, turn: TurnDir, code: str) -> None:
    """Within 20 m of the junction (and inside it, 5 m past its entry) the turn is said; 24 m and more
    before it the route is followed; straight across is followed."""
    route, entry = turning_route(downtown, turn)

    def path_from(gap: float) -> np.ndarray:
        k = int(np.searchsorted(route.distance, entry - gap))
        return route.xy[k : k + 40]

    near = np.stack([path_from(15.0), path_from(18.0), path_from(-5.0)])
    far = np.stack([path_from(24.0), path_from(35.0)])
    assert route_actions(downtown, near).tolist() == [code, code, code]
    assert route_actions(downtown, far).tolist() == ["follow", "follow"]


def test_lane_change_is_said() -> None:
    """Interurban's two-lane one-way road: a path that moves to the left lane within 20 m."""
    sc = Scene(*ONE_WAY)
    s = CAV_S + np.arange(40.0)
    d = np.clip((s - CAV_S - 5.0) / 10.0, 0.0, 1.0) * sc.width
    path = sc.map.index.frenet_to_xy(np.full(40, sc.lane), s, d)
    straight = lane_path(sc, CAV_S)
    assert route_actions(sc.map, np.stack([path, straight])).tolist() == ["lane_left", "follow"]


def expert_decision(
    sc: Scene, actors: list[Actor], times: tuple[float, ...], cav_s: float = CAV_S
) -> tuple[ExpertDecision | None, Snapshot]:
    """The expert's decision for the scene's CAV after one tick at each time, and the last snapshot."""
    agent = expert_for(sc.map, [sc.route])
    for tick, t in enumerate(times):
        snap = sc.snapshot(t, actors, cav_s)
        obs = Observations(
            tick=tick,
            time=t,
            cav_index=np.array([0]),
            x=snap.x[:1],
            y=snap.y[:1],
            yaw=snap.yaw[:1],
            speed=snap.speed[:1],
            accel=np.zeros(1),
            snapshot=snap,
        )
        agent.run_step(obs)
    return agent.decision, snap


def test_the_expert_names_what_it_goes_around() -> None:
    """ParkedObstacle 30 m ahead on the one-way road: the expert's decision records the shift and the car;
    the commentary says to go around the parked car ahead."""
    sc = Scene(*ONE_WAY)
    car = Actor(CAV_S + 30.0, -0.35 * sc.width, name=id_with_paint(4, "car"))  # a red car
    d, snap = expert_decision(sc, [car], (0.0, 1.5))
    assert d is not None and d.detour_reason[0] == DetourReason.OBSTACLE and d.detour_row[0] == 1
    lang = labels(snap, d, sc.map)[0]
    assert lang.route_action == "detour_parked"
    assert lang.commentary.startswith("Go around the red car parked ahead.")


def test_the_expert_names_the_emergency_vehicle_it_makes_way_for() -> None:
    """A siren 30 m behind in the CAV's lane: the expert's decision records the shift and the ambulance."""
    sc = Scene(*ONE_WAY)
    ev = Actor(CAV_S, 0.0, 25.0, ActorKind.EMERGENCY, length=6.2, width=2.3, siren=True)
    d, snap = expert_decision(sc, [ev], (0.0,), cav_s=CAV_S + 30.0)
    assert d is not None and d.detour_reason[0] == DetourReason.EMERGENCY and d.detour_row[0] == 1
    lang = labels(snap, d, sc.map)[0]
    assert lang.route_action == "detour_emergency" and lang.critical_row == 1
    assert lang.commentary.startswith("Make way for the white ambulance behind.")


def test_detour_templates() -> None:
    sc = Scene(*TWO_WAY)
    w = sc.width
    cases = [
        (
            Actor(CAV_S + 20.0, -0.4 * w, kind=ActorKind.PROP, role=Role.PROP, length=0.4, width=0.4),
            "construction",
        ),
        (Actor(CAV_S + 20.0, -0.4 * w, kind=ActorKind.EMERGENCY, length=5.0, width=2.0), "accident"),
        (Actor(CAV_S + 20.0, -0.4 * w, kind=ActorKind.CAR, role=Role.PROP, length=1.0, width=0.15), "door"),
        (Actor(CAV_S + 20.0, -0.4 * w, 3.0, kind=ActorKind.BICYCLE, length=1.8, width=0.65), "bicycles"),
        (
            Actor(CAV_S - 30.0, 0.0, 15.0, kind=ActorKind.EMERGENCY, length=6.2, width=2.3, siren=True),
            "emergency",
        ),
    ]
    for actor, code in cases:
        snap = sc.snapshot(0.0, [actor])
        why = DetourReason.EMERGENCY if code == "emergency" else DetourReason.ONCOMING_LANE
        d = decision(snap, np.array([0]), lane_path(sc, CAV_S)[None], detour=([why], [1]))
        lang = labels(snap, d, sc.map)[0]
        assert lang.route_action == f"detour_{code}", lang.commentary
    assert lang.commentary.startswith("Make way for the white ambulance behind.")
    assert lang.communication == ""  # no other CAV


def test_an_obstacle_passed_is_no_longer_gone_around() -> None:
    """The shift is held to ramp back after the parked car: with the car behind the CAV the route action
    is the plain one again, and the car is not the critical object."""
    sc = Scene(*ONE_WAY)
    snap = sc.snapshot(0.0, [Actor(CAV_S - 6.0, -0.35 * sc.width)])
    d = decision(snap, np.array([0]), lane_path(sc, CAV_S)[None], detour=([DetourReason.OBSTACLE], [1]))
    lang = labels(snap, d, sc.map)[0]
    assert lang.route_action == "follow" and lang.critical_row == -1


# ------------------------------------------------------------------ (5) walkers
@pytest.mark.parametrize(
    ("ahead", "speed", "caution"),
    [(10.0, 1.4, True), (10.0, 0.3, False), (20.0, 1.4, False), (-8.0, 1.4, False)],  # (behind: none)
)
def test_walker_caution(ahead: float, speed: float, caution: bool) -> None:
    sc = Scene(*TWO_WAY)
    walker = Actor(CAV_S + ahead, sc.width, speed, ActorKind.PEDESTRIAN, Role.BACKGROUND, 0.5, 0.6, name="w")
    snap = sc.snapshot(0.0, [walker])
    d = decision(snap, np.array([0]), lane_path(sc, CAV_S)[None])
    lang = labels(snap, d, sc.map)[0]
    assert lang.commentary.startswith("Stay on the route. Keep the current speed.")
    assert (" Watch out for the pedestrian in " in lang.commentary) == caution
    if caution:
        assert lang.commentary.endswith(" ahead on the left.") or lang.commentary.endswith(" ahead.")


# ------------------------------------------------------------------ (6) colours and directions
def test_colour_names() -> None:
    assert colour_names(VEHICLE_PAINTS) == [
        "white",
        "black",
        "silver",
        "grey",
        "red",
        "blue",
        "dark blue",
        "green",
        "yellow",
        "brown",
        "orange",
        "light blue",
    ]


def test_objects_are_named_by_colour_and_direction() -> None:
    """A red car ahead on the left, an orange cone on the right, a police car ahead: the follow reason,
    the colour the camera paints, and the direction in the CAV's frame."""
    sc = Scene(*ONE_WAY)
    red = id_with_paint(4, "car")
    actors = [
        Actor(CAV_S + 7.0, sc.width, role=Role.BACKGROUND, name=red),
        Actor(CAV_S + 0.5, -3.0, kind=ActorKind.PROP, role=Role.PROP, length=0.4, width=0.4, name="cone"),
        Actor(CAV_S + 15.0, 0.0, kind=ActorKind.EMERGENCY, length=5.0, width=2.0, name="police"),
    ]
    snap = sc.snapshot(0.0, actors, cav_speed=5.0)
    path = lane_path(sc, CAV_S)[None]
    for row, reason, text in [
        (1, Reason.LEADING_VEHICLE, "Slow down behind the red car ahead on the left."),
        (2, Reason.OBSTACLE, "Slow down for the orange traffic cone on the right."),
        (3, Reason.FORECAST, "Slow down to avoid a collision with the dark blue police car ahead."),
    ]:
        d = decision(snap, np.array([0]), path, [reason], [row], [10.0], target_speed=[3.0])
        assert labels(snap, d, sc.map)[0].commentary == f"Stay on the route. {text}"
    # beyond 40 m no object is given as the reason
    d = decision(snap, np.array([0]), path, [Reason.LEADING_VEHICLE], [1], [45.0], target_speed=[3.0])
    assert labels(snap, d, sc.map)[0].commentary == "Stay on the route. Slow down."


@pytest.mark.parametrize(
    ("dx", "dy", "expected"),
    [
        (10.0, 0.0, "ahead"),
        (10.0, 6.0, "ahead on the left"),
        (10.0, -6.0, "ahead on the right"),
        (1.0, 5.0, "on the left"),
        (-1.0, -5.0, "on the right"),
        (-10.0, 1.0, "behind"),
    ],
)
def test_direction_in_the_ego_frame(dx: float, dy: float, expected: str) -> None:
    yaw = 0.7  # the same offsets rotated by the heading
    c, s = np.cos(yaw), np.sin(yaw)
    assert direction(c * dx - s * dy, s * dx + c * dy, yaw) == expected


# ------------------------------------------------------------------ cost
def test_sixteen_cavs_are_labelled_well_under_a_millisecond_each() -> None:
    sc = Scene(*ONE_WAY)
    actors = [
        Actor(CAV_S + 12.0 * k, (k % 2) * sc.width, 8.0, ActorKind.CAR, Role.CAV, 4.89, 2.10, name=f"cav{k}")
        for k in range(1, 16)
    ]
    actors += [
        Actor(CAV_S + 5.0 + 7.0 * k, -0.5 * sc.width - 2.0, 1.2, ActorKind.PEDESTRIAN, length=0.5, width=0.6)
        for k in range(20)
    ]
    snap = sc.snapshot(0.0, actors)
    rows = np.flatnonzero(snap.role == Role.CAV)
    paths = np.stack([lane_path(sc, CAV_S + 12.0 * k, (k % 2) * sc.width) for k in range(16)])
    reasons = [Reason.LEADING_VEHICLE] * 16
    objects = [int(r) for r in rows[1:]] + [-1]
    d = decision(snap, rows, paths, reasons, objects, [8.0] * 16, target_speed=[6.0] * 16)
    vis: Visibility = compute_visibility(snap, rows, 120.0)
    inputs = LanguageInputs(snap, d, rows, vis, np.full((16, 5), 6.0), 16, sc.map)
    describe(inputs)  # warm up (lane index, numba)
    start = time.perf_counter()
    for _ in range(10):
        out = describe(inputs)
    per_cav = (time.perf_counter() - start) / 10 / 16
    assert len(out) == 16 and per_cav < 0.5e-3, per_cav
