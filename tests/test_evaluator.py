"""The evaluation loop end to end: a PID agent completes an empty route perfectly, a standing agent is
blocked after 60 s, crashing / NaN / hanging agents are isolated, results are resumable."""

from __future__ import annotations

import json
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from cmudrive.agents import Agent, AutopilotAgent, Observation, Observations, PidAgent, RouteSetup
from cmudrive.bench import CavSpec, EvalConfig, LocalExecutor, RouteSpec, evaluate_route, run_evaluation
from cmudrive.bench.callbacks import RouteCallback, RouteStart, Step
from cmudrive.bench.records import (
    STATUS_AGENT_CRASHED,
    STATUS_BLOCKED,
    STATUS_PERFECT,
    STATUS_SIM_CRASHED,
    RouteResult,
)
from cmudrive.maps import load_map
from cmudrive.maps.coords import map_to_carla
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.dynamics import Controls

EMPTY = BackgroundConfig(vehicles=0, pedestrians=0)  # "an empty town": no background actors


def ring_route(route_id: str = "ring", seed: int = 0) -> RouteSpec:
    """Two CAVs on the two lanes of a 488 m stretch of interurban's ring road, no junction on the way."""
    m = load_map("interurban")
    cavs = []
    for cav, (lane, s0, s1) in enumerate((("R1a-R2a_0", 20.0, 230.0), ("R1a-R2a_1", 60.0, 280.0))):
        i = m.lane(lane)
        s = np.linspace(s0, s1, 5)
        xy = m.index.frenet_to_xy(np.full(5, i), s)
        cavs.append(CavSpec(cav, np.column_stack([map_to_carla(xy), np.zeros(5)])))
    return RouteSpec(route_id, "interurban", "ClearNoon", seed, tuple(cavs))


class StandStill(Agent):
    observations: ClassVar[frozenset[Observation]] = frozenset({Observation.EGO_STATE})

    def setup(self, route: RouteSetup) -> None:
        pass

    def run_step(self, obs: Observations) -> Controls:
        return Controls(
            np.zeros(len(obs.cav_index)), np.zeros(len(obs.cav_index)), np.ones(len(obs.cav_index))
        )


class RaisesAtTick10(PidAgent):
    def run_step(self, obs: Observations) -> Controls:
        if obs.tick == 10:
            raise RuntimeError("boom at tick 10")
        return super().run_step(obs)


class RaisesOnRouteBad(PidAgent):
    """Drives like the PID agent, but raises at tick 10 of the route with id "bad"."""

    def setup(self, route: RouteSetup) -> None:
        super().setup(route)
        self.route_id = route.route_id

    def run_step(self, obs: Observations) -> Controls:
        if obs.tick == 10 and self.route_id == "bad":
            raise RuntimeError("boom at tick 10")
        return super().run_step(obs)


class ReturnsNaN(PidAgent):
    def run_step(self, obs: Observations) -> Controls:
        c = super().run_step(obs)
        return Controls(c.steer, np.full_like(c.throttle, np.nan), c.brake) if obs.tick == 5 else c


class Hangs(PidAgent):
    def run_step(self, obs: Observations) -> Controls:
        if obs.tick == 3:
            import time

            time.sleep(5.0)
        return super().run_step(obs)


def test_pid_agent_completes_an_empty_route_perfectly() -> None:
    result = evaluate_route(ring_route(), PidAgent, EvalConfig(background=EMPTY))
    assert result.status == STATUS_PERFECT and result.success
    for cav in result.cavs:
        assert cav.status == STATUS_PERFECT
        assert cav.route_completion == 100.0 and cav.infraction_score == 1.0
        assert cav.comfort is not None and 0.3 < cav.comfort <= 1.0  # full-throttle starts exceed 2.4 m/s^2
    assert result.driving_score == 100.0
    assert result.ticks < 1000  # ~210-220 m at ~20 m/s (0.8 x 90 km/h) with acceleration: about 15-25 s


def test_never_moving_agent_is_blocked_after_60_seconds() -> None:
    result = evaluate_route(ring_route(), StandStill, EvalConfig(background=EMPTY))
    assert [c.status for c in result.cavs] == [STATUS_BLOCKED] * 2
    assert result.ticks == pytest.approx(60.0 / 0.05, abs=3)  # blocked once 60 s have passed standing
    assert result.route_completion < 5.0 and not result.success


@pytest.mark.parametrize(
    ("agent", "message"),
    [(RaisesAtTick10, "boom at tick 10"), (ReturnsNaN, "throttle is nan"), (Hangs, "longer than 0.5 s")],
)
def test_crashing_agents_end_the_route_as_agent_crashed(agent: type[Agent], message: str) -> None:
    result = evaluate_route(ring_route(), agent, EvalConfig(background=EMPTY, step_timeout=0.5))
    assert result.status == STATUS_AGENT_CRASHED
    assert all(c.status == STATUS_AGENT_CRASHED for c in result.cavs)
    assert result.error is not None and message in result.error
    assert result.ticks < 20


def test_crash_isolation_and_resume(tmp_path: Path) -> None:
    """A crashing route does not stop the others; resume re-runs only the crashed one."""
    routes = [ring_route("good", seed=1), ring_route("bad", seed=2)]
    config = EvalConfig(background=EMPTY, tick_cap=300)
    ran: list[str] = []

    agent = f"{__name__}:RaisesOnRouteBad"
    merged = run_evaluation(
        routes[:1], agent, tmp_path, LocalExecutor(2), config, on_result=lambda r: ran.append(r.route_id)
    )
    merged = run_evaluation(
        routes,
        agent,
        tmp_path,
        LocalExecutor(2),
        config,
        resume=True,
        on_result=lambda r: ran.append(r.route_id),
    )
    assert ran == ["good", "bad"]  # "good" finished in the first run: resume skipped it
    by_id = {r["route_id"]: r for r in merged["routes"]}
    assert by_id["bad"]["status"] == STATUS_AGENT_CRASHED and by_id["good"]["status"] != STATUS_AGENT_CRASHED
    assert [r["route_id"] for r in merged["routes"]] == ["good", "bad"]  # route-file order
    assert merged["summary"]["num_routes"] == 2 and merged["summary"]["num_crashed"] == 1
    on_disk = json.loads((tmp_path / "results.json").read_text())
    assert on_disk["summary"] == merged["summary"]
    ran.clear()
    run_evaluation(
        routes,
        agent,
        tmp_path,
        LocalExecutor(1),
        config,
        resume=True,
        on_result=lambda r: ran.append(r.route_id),
    )
    assert ran == ["bad"]  # crashed routes run again on resume


def test_autopilot_drives_to_the_end_of_its_route() -> None:
    """The privileged autopilot reaches its destination: it slows for the route's end, it does not stand
    a look-ahead horizon short of it (which ended every CAV "Agent got blocked" at 60-80 % completion)."""
    result = evaluate_route(ring_route(), AutopilotAgent, EvalConfig(background=EMPTY))
    assert [c.status for c in result.cavs] == [STATUS_PERFECT] * 2
    assert [c.route_completion for c in result.cavs] == [100.0, 100.0]
    assert result.ticks < 1000  # 210-220 m at 0.9 x 90 km/h with a 3 m/s^2 arrival profile: 15-25 s


def test_route_actors_stand_in_the_world_and_are_hit_as_their_blueprint_says() -> None:
    """A route's own parked car and cone (as imported from an MDrive-style folder) stand in the two CAVs'
    lanes; the blind PID agent runs into both: a vehicle collision for CAV 0, a layout one for CAV 1 (the
    route asks for no background, so nothing else is on the road)."""
    from dataclasses import replace

    from cmudrive.bench.routes import ActorSpec, BackgroundSpec

    m = load_map("interurban")

    def at(lane: str, s: float) -> np.ndarray:
        xy = m.index.frenet_to_xy(np.array([m.lane(lane)]), np.array([s]))
        return np.column_stack([map_to_carla(xy), np.zeros(1)])

    actors = (
        ActorSpec("parked", "car", at("R1a-R2a_0", 120.0), static=True, model="vehicle.audi.a2"),
        ActorSpec("cone", "cone", at("R1a-R2a_1", 160.0), static=True, model="static.prop.trafficcone01"),
    )
    spec = replace(ring_route(), actors=actors, background=BackgroundSpec(0, 0))
    result = evaluate_route(spec, PidAgent, EvalConfig())
    hits = [{k: len(v) for k, v in cav.infractions.items() if v} for cav in result.cavs]
    assert hits[0].get("collisions_vehicle", 0) >= 1 and "collisions_layout" not in hits[0]
    assert hits[1].get("collisions_layout", 0) >= 1 and "collisions_vehicle" not in hits[1]


class _LightWatcher(PidAgent):
    """The blind PID driver, noting every signal character the world shows (privileged snapshot)."""

    observations: ClassVar[frozenset[Observation]] = frozenset(
        {Observation.EGO_STATE, Observation.PRIVILEGED}
    )
    seen: ClassVar[set[str]] = set()

    def run_step(self, obs: Observations) -> Controls:
        assert obs.snapshot is not None
        for state in obs.snapshot.tls_state.tolist():
            type(self).seen.update(state)
        return super().run_step(obs)


def test_a_route_with_its_lights_off_shows_no_signal_and_charges_no_red_light() -> None:
    """smoke_00 crosses downtown's signalised junctions: with the lights running, red signals show within
    20 s; with ``lights="off"`` (InterDrive's routes) every light is off from the first tick (SUMO's 'o'
    minor / 'O' major), so the blind PID driver, which ignores lights, runs no red light."""
    from dataclasses import replace

    from cmudrive.bench.routes import BackgroundSpec, read_routes

    smoke = Path(__file__).parents[1] / "cmudrive" / "assets" / "routes" / "smoke.xml"
    spec = replace(read_routes(smoke)[0], background=BackgroundSpec(0, 0))
    seen, reds = {}, {}
    for lights in ("on", "off"):
        _LightWatcher.seen = set()
        result = evaluate_route(replace(spec, lights=lights), _LightWatcher, EvalConfig(tick_cap=400))
        seen[lights] = _LightWatcher.seen
        reds[lights] = sum(len(c.infractions.get("red_light", [])) for c in result.cavs)
    assert "r" in seen["on"]
    assert seen["off"] <= {"o", "O"} and reds["off"] == 0


class Watch(RouteCallback):
    """Counts what it hears; raises in on_step at ``fail_at`` when given."""

    def __init__(self, fail_at: int | None = None) -> None:
        self.fail_at = fail_at
        self.started: RouteStart | None = None
        self.steps: list[tuple[int, int, float]] = []  # tick, active CAVs, CAV 0's throttle
        self.ended: RouteResult | None = None

    def on_route_start(self, start: RouteStart) -> None:
        self.started = start

    def on_step(self, step: Step) -> None:
        if step.tick == self.fail_at:
            raise RuntimeError(f"callback failure at tick {step.tick}")
        assert step.snapshot.time == pytest.approx(step.tick * 0.05)
        assert step.after.time == pytest.approx((step.tick + 1) * 0.05)
        self.steps.append((step.tick, len(step.cav_index), float(step.controls.throttle[0])))

    def on_route_end(self, result: RouteResult) -> None:
        self.ended = result


def test_callbacks_hear_every_tick_and_change_nothing() -> None:
    """A callback hears the start (the privileged set-up, whatever the agent declared), every tick with
    the agent's controls and the world before and after it, and the final record; the route scores as it
    does without it."""
    config = EvalConfig(background=EMPTY)
    plain = evaluate_route(ring_route(), PidAgent, config)
    watch = Watch()
    watched = evaluate_route(ring_route(), PidAgent, config, callbacks=[watch])
    assert watched.to_json() | {"wall_time": 0} == plain.to_json() | {"wall_time": 0}
    assert watch.started is not None and watch.started.setup.road_map is not None
    assert all(c.dense_route is not None for c in watch.started.setup.cavs)  # the PID agent gets none
    assert [t for t, _, _ in watch.steps] == list(range(plain.ticks))
    assert watch.steps[0][1] == 2 and watch.steps[0][2] > 0.0  # both CAVs, pulling away
    assert watch.ended is watched


def test_a_failing_callback_is_a_simulation_crash_not_the_agents() -> None:
    watch = Watch(fail_at=7)
    result = evaluate_route(ring_route(), PidAgent, EvalConfig(background=EMPTY), callbacks=[watch])
    assert result.status == STATUS_SIM_CRASHED
    assert all(c.status == STATUS_SIM_CRASHED for c in result.cavs)
    assert result.error is not None and "callback failure at tick 7" in result.error
    assert watch.ended is result and result.ticks == 8  # it failed once the world had run tick 7
