"""The row collector: while an agent drives a route, every ``sample_every``-th tick each active CAV
becomes one dataset row (inputs, expert labels, language), written to the route's shard.

It is a step callback of the ordinary evaluation loop (``cmudrive.bench.evaluator.evaluate_route``,
:mod:`cmudrive.bench.callbacks`), not an agent: any agent drives. Where the privileged expert drives (the
default dataset), its own decisions are the labels. Where another agent drives (closed-loop data, DAgger:
``cmudrive data collect --driver v2v-vla``), a second :class:`~cmudrive.agents.expert.ExpertAgent`, the
labeller, decides every tick beside it on the state the driver reached, and labels the rows: what the
expert would do there, never what the driver did. The ``driver`` column says who drove.

The collector computes the rows' sensors itself, through the evaluator's own
:class:`~cmudrive.bench.observe.ObservationBuilder`, on sample ticks only: the camera, visibility,
occupancy and V2V merge cost nothing on the other four ticks of five. V2V uses the ideal link (no
latency, loss or pose noise) and the default partners (the closest CAV in front), whatever the driver's
link does.

The model's input columns (camera, merged BEV, speed, target points, other CAVs) come from
:class:`cmudrive.model.row.RowBuilder`, the row contract the closed-loop agent builds its rows with too;
its target points follow each CAV's progress along the sparse plan, advanced every tick. This is why
``data`` imports ``cmudrive.model.row``, one of the few imports that run up a layer
(``docs/architecture.md``): the rows collected must be the very rows the model is fed in closed loop, and
the contract lives beside the model; ``model.row`` needs only ``data.schema`` below it: no circle.

With ``recovery`` (``--recovery-views P``), a share of the sampled rows gets a second row of the same CAV
sensed from a pose beside it, labelled back toward its path (``cmudrive.data.recovery``).

Labels need the future (the path the CAV drives next, its positions 2.5 s on, the expert's target speed
over the next 1.25 s for the language), so a sample tick is kept in memory, its images already encoded,
until every CAV of it has driven ``PATH_REACH`` metres and ``LABEL_TICKS`` ticks further or left the world;
then its rows are computed and written as a row group. Rows of another driver take their path and speed
waypoints from the labeller's plan at the sample tick instead (:func:`cmudrive.data.labels.plan_labels`:
the driver's future is not the expert's); their language still reads the labeller's future target speeds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from cmudrive.agents.base import Observation, Observations
from cmudrive.agents.expert import ExpertAgent, Reason
from cmudrive.agents.expert.agent import ExpertDecision
from cmudrive.bench.callbacks import RouteCallback, RouteStart, Step
from cmudrive.bench.observe import ObservationBuilder, SensorConfig, relative_poses
from cmudrive.bench.records import STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED, RouteResult
from cmudrive.data.labels import (
    PATH_POINTS,
    PATH_SPACING,
    SPEED_POINTS,
    SPEED_STEP_TICKS,
    plan_labels,
    waypoint_labels,
)
from cmudrive.data.language import Language, LanguageInputs, describe
from cmudrive.data.recovery import RecoveryViews, moved, to_view, view_poses
from cmudrive.data.schema import COLUMNS, EXPERT_DRIVER, pack_occupancy
from cmudrive.data.shards import ROW_GROUP, ShardWriter
from cmudrive.maps import RoadMap, load_scenery
from cmudrive.model import row  # the module, not its names: cmudrive.model.row imports cmudrive.data
from cmudrive.sim.dynamics import Controls
from cmudrive.sim.snapshot import ActorKind, Snapshot
from cmudrive.sim.weather import get_weather
from cmudrive.v2v.warp import warp_and_merge

SAMPLE_EVERY = 5  # [ticks] 4 Hz at 20 Hz
LANGUAGE_TICKS = 25  # [ticks] the expert's target speed is looked up at t+5 .. t+25 for the language
LABEL_TICKS = max(SPEED_POINTS * SPEED_STEP_TICKS, LANGUAGE_TICKS)  # [ticks] of future a sample needs
PATH_REACH = (PATH_POINTS - 1) * PATH_SPACING  # [m] of future path a sample needs
SENSORS = frozenset(
    {
        Observation.PRIVILEGED,
        Observation.VISIBILITY,
        Observation.CAMERA,
        Observation.OCCUPANCY,
        Observation.MERGED_OCCUPANCY,
    }
)


@dataclass(frozen=True)
class RouteInfo:
    """What a row says about its route (the agent's ``RouteSetup`` has no scenario type)."""

    route_id: str
    scenario_type: str
    weather: str
    town: str
    num_cavs: int


@dataclass
class _SampleTick:
    """One sample tick, its rows' inputs already encoded, waiting for its labels."""

    tick: int
    time: float
    snap: Snapshot
    decision: ExpertDecision
    rows: np.ndarray  # (n,) snapshot rows of the CAVs, decision.cav_index order
    visibility: Any  # cmudrive.sensors.Visibility
    columns: dict[str, list[Any]] = field(default_factory=dict)  # inputs and controls, one entry per CAV
    views: list[_View] = field(default_factory=list)  # recovery views (cmudrive.data.recovery)


@dataclass
class _View:
    """A recovery view of the CAV at ``slot`` of its sample tick: its inputs and its offset."""

    slot: int  # index into the tick's decision.cav_index
    offset: np.ndarray  # (3,) x, y [m], yaw [rad]
    columns: dict[str, Any]  # one value per input column


class _Trace:
    """Per tick and CAV: position, heading, speed, odometer and the expert's target speed (NaN when not in
    the world), grown as the route runs; and each CAV's last planned path."""

    def __init__(self, num_cavs: int, capacity: int = 1024) -> None:
        self.data = np.full((capacity, num_cavs, 6), np.nan)  # x, y, yaw, speed, odometer, target speed
        self.last_tick = np.full(num_cavs, -1, np.int64)
        self.plan: list[np.ndarray] = [np.zeros((0, 2)) for _ in range(num_cavs)]

    def add(self, tick: int, obs: Observations, decision: ExpertDecision) -> None:
        while tick >= len(self.data):
            self.data = np.concatenate([self.data, np.full_like(self.data, np.nan)])
        i = obs.cav_index
        odo = np.zeros(len(i))
        seen = self.last_tick[i] >= 0
        if seen.any():
            prev = self.data[self.last_tick[i[seen]], i[seen]]
            step = np.hypot(obs.x[seen] - prev[:, 0], obs.y[seen] - prev[:, 1])
            odo[seen] = prev[:, 4] + step
        self.data[tick, i] = np.stack([obs.x, obs.y, obs.yaw, obs.speed, odo, decision.target_speed], axis=1)
        self.last_tick[i] = tick
        for a, k in enumerate(i):
            self.plan[int(k)] = decision.path[a]


class RowCollector(RouteCallback):
    """Records rows of the route it watches (module docstring); a step callback of the evaluation loop."""

    def __init__(
        self,
        info: RouteInfo,
        writer: ShardWriter,
        sample_every: int = SAMPLE_EVERY,
        sensors: SensorConfig | None = None,
        seed: int = 0,
        recovery: RecoveryViews | None = None,
        labeller: ExpertAgent | None = None,
        driver: str = EXPERT_DRIVER,
    ) -> None:
        """``labeller``: the expert that labels the rows while another agent drives (closed-loop data);
        None: the driving agent is the expert and its own decisions are the labels. ``driver``: the
        name stored in the rows' ``driver`` column."""
        if sample_every < 1:
            raise ValueError(f"sample_every must be >= 1 tick, got {sample_every}")
        self.info, self.writer = info, writer
        self.sample_every = sample_every
        self.sensor_config = sensors or SensorConfig()
        self.seed = seed
        self.recovery = recovery or RecoveryViews()
        self.labeller, self.driver = labeller, driver
        self.view_rng = np.random.default_rng([seed, 3])
        self.pending: list[_SampleTick] = []
        self.buffer: dict[str, list[Any]] = {k: [] for k in COLUMNS}
        self.active = np.zeros(info.num_cavs, bool)
        self.samples = 0

    # ------------------------------------------------------------------ callback interface
    def on_route_start(self, start: RouteStart) -> None:
        route = start.setup
        assert route.road_map is not None  # callbacks get the privileged set-up
        if self.labeller is None and not isinstance(start.agent, ExpertAgent):
            raise TypeError(
                f"route {self.info.route_id}: {type(start.agent).__name__} drives and no expert labels: "
                "give the collector a labeller"
            )
        if self.labeller is not None:
            self.labeller.setup(route)
            self.labeller_observer = ObservationBuilder(
                frozenset({Observation.PRIVILEGED}),
                len(route.cavs),
                get_weather(route.weather),
                load_scenery(route.road_map),
                config=self.sensor_config,
                road_map=route.road_map,
            )
        self.road_map: RoadMap = route.road_map
        self.observer = ObservationBuilder(
            SENSORS,
            len(route.cavs),
            get_weather(route.weather),
            load_scenery(self.road_map),
            config=self.sensor_config,
            rng=np.random.default_rng([self.seed, 1]),
            road_map=self.road_map,
        )
        self.row_builder = row.RowBuilder(route.cavs, self.sensor_config.occupancy)
        self.viewer: ObservationBuilder | None = None
        if self.recovery.prob > 0.0:  # own and partner occupancy of the views, its own noise generator
            self.viewer = ObservationBuilder(
                frozenset({Observation.OCCUPANCY}),
                len(route.cavs),
                self.observer.weather,
                self.observer.scenery,
                config=self.sensor_config,
                rng=np.random.default_rng([self.seed, 4]),
                road_map=self.road_map,
            )
        self.trace = _Trace(len(route.cavs))

    def on_step(self, step: Step) -> None:
        if self.labeller is None:  # the expert drives: its decision of this tick labels the rows
            obs, controls = step.observations, step.controls
            decision = cast(ExpertAgent, step.agent).decision
        else:  # another agent drives: the expert decides beside it, on the state it reached
            obs = self.labeller_observer.build(step.snapshot, step.tick, step.rows, step.cav_index, True)
            controls = self.labeller.run_step(obs)
            decision = self.labeller.decision
        assert decision is not None and decision.tick == step.tick
        self.trace.add(step.tick, obs, decision)
        self.row_builder.advance(obs)  # progress and standing clocks advance every tick, as in closed loop
        self.active[:] = False
        self.active[step.cav_index] = True
        if step.tick % self.sample_every == 0 and len(step.cav_index):
            self.pending.append(self._sample(step, obs, decision, controls))
        self._flush(step.tick)

    def on_route_end(self, result: RouteResult) -> None:
        """Rows of a route that ran to its end are written (what is pending labelled with the future
        there is) and the shard closed; a crashed route's shard is dropped."""
        if result.status in (STATUS_AGENT_CRASHED, STATUS_SIM_CRASHED):
            self.writer.abort()
            return
        self.active[:] = False
        self._flush(None)
        self._write(force=True)
        self.writer.close()

    # ------------------------------------------------------------------ sampling
    def _sample(
        self, step: Step, obs: Observations, decision: ExpertDecision, controls: Controls
    ) -> _SampleTick:
        snap, rows = step.snapshot, step.rows
        sensed = self.observer.build(snap, obs.tick, rows, obs.cav_index, privileged=True)
        assert sensed.camera is not None and sensed.occupancy is not None
        assert sensed.merged_occupancy is not None and sensed.partner is not None
        inputs = self.row_builder.inputs(sensed, sensed.merged_occupancy)  # the model's input columns
        assert inputs.bev is not None
        cols: dict[str, list[Any]] = {
            **self.row_builder.stored(inputs),
            "occupancy": list(pack_occupancy(sensed.occupancy)),
            "merged_occupancy": list(inputs.bev),
            "partner": [int(p) for p in sensed.partner],
            "throttle": [float(v) for v in controls.throttle],
            "steer": [float(v) for v in controls.steer],
            "brake": [float(v) for v in controls.brake],
        }
        assert self.observer.last_visibility is not None
        sample = _SampleTick(obs.tick, obs.time, snap, decision, rows, self.observer.last_visibility, cols)
        if self.viewer is not None:
            sample.views = self._views(obs, rows, inputs, sensed.partner)
        return sample

    def _views(
        self, obs: Observations, rows: np.ndarray, inputs: row.RowInputs, partner: np.ndarray
    ) -> list[_View]:
        """Recovery views of a share of this tick's rows (``cmudrive.data.recovery``): sensed in a copy of
        the snapshot where the chosen CAVs stand at their views, merged with the tick's partners' grids
        sensed in that copy too."""
        assert self.viewer is not None and self.observer.camera is not None and obs.snapshot is not None
        sel, offset = self.recovery.draw(self.view_rng, len(rows))
        if len(sel) == 0:
            return []
        snap = obs.snapshot
        there = moved(
            snap, rows[sel], view_poses(snap.x[rows[sel]], snap.y[rows[sel]], snap.yaw[rows[sel]], offset)
        )
        pose = np.stack([there.x[rows], there.y[rows], there.yaw[rows]], axis=1)  # (n, 3) every active CAV
        slot = {int(c): j for j, c in enumerate(obs.cav_index)}
        mate = np.array([slot.get(int(p), -1) for p in partner[sel]], np.int64)  # -1: no partner
        has = mate >= 0
        sensed = np.unique(np.concatenate([sel, mate[has]]))  # the views and their partners
        grids = self.viewer.build(
            there, obs.tick, rows[sensed], obs.cav_index[sensed], privileged=True
        ).occupancy
        assert grids is not None
        own = grids[np.searchsorted(sensed, sel)]
        mate = np.where(has, mate, sel)  # rows without a partner merge nothing (has is False)
        merged = warp_and_merge(
            own,
            grids[np.searchsorted(sensed, mate)],
            pose[mate],
            pose[sel],
            has,
            self.sensor_config.occupancy,
        )
        camera = self.observer.camera.render(there, rows[sel], self.observer.weather)
        relative = relative_poses(pose[:, 0], pose[:, 1], pose[:, 2], obs.cav_index, self.info.num_cavs)[sel]
        views = self.row_builder.view(inputs, sel, offset, camera, merged, relative)
        assert views.bev is not None
        stored = self.row_builder.stored(views)
        packed_own = pack_occupancy(own)
        return [
            _View(
                int(a),
                offset[i],
                {
                    **{name: values[i] for name, values in stored.items()},
                    "occupancy": packed_own[i],
                    "merged_occupancy": views.bev[i],
                },
            )
            for i, a in enumerate(sel)
        ]

    def _ready(self, sample: _SampleTick, now: int | None) -> bool:
        """Every CAV of the sample has its future: left the world, or LABEL_TICKS and PATH_REACH ahead."""
        if now is None:
            return True
        if now < sample.tick + LABEL_TICKS:
            return False
        if self.labeller is not None:  # labels from the plan: only the language's future is needed
            return True
        i = sample.decision.cav_index
        gone = ~self.active[i]
        odo_then = self.trace.data[sample.tick, i, 4]
        odo_now = self.trace.data[now, i, 4]
        return bool(np.all(gone | (odo_now - odo_then >= PATH_REACH)))

    def _flush(self, now: int | None) -> None:
        while self.pending and self._ready(self.pending[0], now):
            self._label(self.pending.pop(0))
        self._write(force=False)

    # ------------------------------------------------------------------ labels and rows
    def _label(self, s: _SampleTick) -> None:
        d, data = s.decision, self.trace.data
        i = d.cav_index
        n = len(i)
        future_ts = np.full((n, LANGUAGE_TICKS // SAMPLE_EVERY), np.nan)
        for j, dt in enumerate(range(SAMPLE_EVERY, LANGUAGE_TICKS + 1, SAMPLE_EVERY)):
            if s.tick + dt < len(data):
                future_ts[:, j] = data[s.tick + dt, i, 5]
        language = describe(
            LanguageInputs(
                snap=s.snap,
                decision=d,
                cav_rows=s.rows,
                visibility=s.visibility,
                future_target_speed=future_ts,
                num_cavs=self.info.num_cavs,
                road_map=self.road_map,
            )
        )
        labels = [self._waypoints(s, a) for a in range(n)]
        for a in range(n):
            self._row(s, a, {name: values[a] for name, values in s.columns.items()}, *labels[a], language[a])
        for v in s.views:  # from the view's frame the CAV's own path leads back (cmudrive.data.recovery)
            path, speed_wp = (to_view(p, v.offset) for p in labels[v.slot])
            inputs = {name: values[v.slot] for name, values in s.columns.items()}  # partner, controls
            self._row(s, v.slot, {**inputs, **v.columns}, path, speed_wp, language[v.slot], v.offset)
        self.samples += n + len(s.views)
        # a labelled tick's snapshot and visibility are no longer needed
        s.columns.clear()
        s.views.clear()

    def _waypoints(self, s: _SampleTick, a: int) -> tuple[np.ndarray, np.ndarray]:
        """(path, speed waypoints) labels of the CAV at slot ``a``: its future as driven by the expert,
        or, where another agent drove, what the labeller planned at the sample tick."""
        d = s.decision
        if self.labeller is not None:
            r = int(s.rows[a])
            pose = (float(s.snap.x[r]), float(s.snap.y[r]), float(s.snap.yaw[r]), float(s.snap.speed[r]))
            return plan_labels(d.path[a], *pose, float(d.accel[a]), float(d.desired_speed[a]))
        k = int(d.cav_index[a])
        traj = self.trace.data[s.tick : int(self.trace.last_tick[k]) + 1, k]
        traj = traj[~np.isnan(traj[:, 0])]
        return waypoint_labels(traj[:, :2], float(traj[0, 2]), self.trace.plan[k], float(traj[-1, 3]))

    def _row(
        self,
        s: _SampleTick,
        a: int,
        inputs: dict[str, Any],
        path: np.ndarray,
        speed_wp: np.ndarray,
        lang: Language,
        view: np.ndarray | None = None,
    ) -> None:
        """Append the row of the CAV at slot ``a`` of sample ``s`` (its own, or a view's ``inputs``)."""
        d, b = s.decision, self.buffer
        b["route_id"].append(self.info.route_id)
        b["scenario_type"].append(self.info.scenario_type)
        b["weather"].append(self.info.weather)
        b["town"].append(self.info.town)
        b["num_cavs"].append(self.info.num_cavs)
        b["cav"].append(int(d.cav_index[a]))
        b["tick"].append(s.tick)
        b["time"].append(s.time)
        b["view"].append([0.0, 0.0, 0.0] if view is None else [float(v) for v in view])
        b["driver"].append(self.driver)
        for name, value in inputs.items():
            b[name].append(value)
        b["path"].append(path)
        b["speed_waypoints"].append(speed_wp)
        b["reason"].append(Reason(int(d.reason[a])).name)
        b["object_id"].append(str(d.object_id[a]))
        kind = int(d.object_kind[a])
        b["object_kind"].append(ActorKind(kind).name if kind >= 0 else "")
        dist = float(d.distance[a])
        b["object_distance"].append(dist if np.isfinite(dist) else float("nan"))
        b["target_speed"].append(float(d.target_speed[a]))
        b["desired_speed"].append(float(d.desired_speed[a]))
        b["commentary"].append(lang.commentary)
        b["communication"].append(lang.communication)
        b["partner_label"].append(int(lang.partner_label))
        b["route_action"].append(lang.route_action)
        b["speed_action"].append(lang.speed_action)

    def _write(self, force: bool) -> None:
        if len(self.buffer["route_id"]) >= ROW_GROUP or (force and self.buffer["route_id"]):
            self.writer.write(self.buffer)
            self.buffer = {k: [] for k in COLUMNS}
