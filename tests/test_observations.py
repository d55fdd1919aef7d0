"""Sensors and V2V through the agent interface: provided batched, only when declared, on a real route."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from cmudrive.agents import Observation, Observations, PidAgent
from cmudrive.bench import EvalConfig, evaluate_route
from cmudrive.bench.routes import CavSpec, RouteSpec
from cmudrive.maps import load_map
from cmudrive.maps.coords import map_to_carla
from cmudrive.sim.background import BackgroundConfig
from cmudrive.sim.dynamics import Controls
from tests.test_evaluator import ring_route

TRAFFIC = BackgroundConfig(vehicles=20, pedestrians=0)
TICKS = 60


def three_cavs() -> RouteSpec:
    """Three CAVs on interurban's ring road, one after the other: CAV 0 at s = 20 m (right lane), CAV 1 at
    60 m (left lane), CAV 2 at 85 m (right lane), all driving the same way."""
    m = load_map("interurban")
    cavs = []
    for cav, (lane, s0) in enumerate((("R1a-R2a_0", 20.0), ("R1a-R2a_1", 60.0), ("R1a-R2a_0", 85.0))):
        s = np.linspace(s0, s0 + 200.0, 5)
        xy = m.index.frenet_to_xy(np.full(5, m.lane(lane)), s)
        cavs.append(CavSpec(cav, np.column_stack([map_to_carla(xy), np.zeros(5)])))
    return RouteSpec("three", "interurban", "ClearNoon", 0, tuple(cavs))


class Cooperative(PidAgent):
    """Follows its route like the PID agent, keeps what it observed, and from tick 20 on names CAV 2 as
    CAV 0's partner."""

    observations: ClassVar[frozenset[Observation]] = frozenset(
        {Observation.EGO_STATE, Observation.PRIVILEGED, Observation.MERGED_OCCUPANCY, Observation.VISIBILITY}
    )
    seen: ClassVar[list[Observations]] = []

    def run_step(self, obs: Observations) -> Controls:
        Cooperative.seen.append(obs)
        self._n = len(obs.cav_index)
        self._tick = obs.tick
        return super().run_step(obs)

    def next_partners(self) -> np.ndarray | None:
        return np.array([2] + [-1] * (self._n - 1)) if self._tick >= 20 and self._n == 3 else None


class EgoOnly(PidAgent):
    seen: ClassVar[list[Observations]] = []

    def run_step(self, obs: Observations) -> Controls:
        EgoOnly.seen.append(obs)
        return super().run_step(obs)


def test_declared_sensors_and_v2v_arrive_batched() -> None:
    Cooperative.seen.clear()
    result = evaluate_route(ring_route(), Cooperative, EvalConfig(tick_cap=TICKS, background=TRAFFIC))
    assert len(Cooperative.seen) == TICKS
    first = Cooperative.seen[0]
    n = len(first.cav_index)
    assert n == 2
    assert first.occupancy is not None and first.occupancy.shape == (2, 4, 192, 128)
    assert first.merged_occupancy is not None and first.merged_occupancy.dtype == bool
    assert (first.merged_occupancy >= first.occupancy).all()  # merged = own OR partner
    assert first.visible is not None and first.visible.shape == (2, first.snapshot.num_actors)
    # the two CAVs start 40 m apart on neighbouring lanes, CAV 1 ahead: CAV 0 talks to CAV 1 (in front),
    # CAV 1 has nobody in front and takes the closest CAV in range, CAV 0
    assert first.partner.tolist() == [1, 0]
    assert first.partner_received.all()
    # other CAVs in each CAV's frame: CAV 1 is ~40 m ahead of CAV 0 and to its left (one lane over, on a
    # curve of the ring), CAV 0 as far behind CAV 1
    rel = first.other_cavs
    assert rel.shape == (2, 2, 3) and np.isnan(rel[0, 0]).all() and np.isnan(rel[1, 1]).all()
    assert 35.0 < rel[0, 1, 0] < 45.0 and 2.0 < rel[0, 1, 1] < 7.0
    assert -45.0 < rel[1, 0, 0] < -35.0
    # the link counts one 12,316-byte message per CAV and tick
    assert result.v2v is not None
    assert result.v2v["messages"] == 2 * TICKS and result.v2v["bytes"] == 2 * TICKS * 12316
    assert result.v2v["received"] == 2 * TICKS
    # two partner choices per tick, none named by this agent: the default partner every time
    assert result.v2v["cav_ticks"] == 2 * TICKS and result.v2v["named"] == result.v2v["named_taken"] == 0


def test_an_agent_names_the_partner_for_the_next_tick() -> None:
    Cooperative.seen.clear()
    result = evaluate_route(three_cavs(), Cooperative, EvalConfig(tick_cap=30, background=TRAFFIC))
    # by default CAV 0 talks to CAV 1 (40 m ahead; CAV 2 is 65 m ahead, within the 70 m range); the
    # agent names CAV 2 after tick 20, so from tick 21 on CAV 0 receives CAV 2's map
    assert Cooperative.seen[20].partner.tolist() == [1, 2, 1]
    assert Cooperative.seen[21].partner.tolist() == [2, 2, 1]
    assert Cooperative.seen[21].partner_received.all()
    # 3 CAVs x 30 ticks of partner choices; CAV 0's request counts from tick 21 to 29 (9 ticks), and CAV 2
    # is in range each time, so every named partner was the one used
    assert result.v2v is not None
    assert (result.v2v["cav_ticks"], result.v2v["named"], result.v2v["named_taken"]) == (90, 9, 9)


def test_nothing_is_computed_that_was_not_declared() -> None:
    EgoOnly.seen.clear()
    result = evaluate_route(ring_route(), EgoOnly, EvalConfig(tick_cap=5, background=TRAFFIC))
    obs = EgoOnly.seen[0]
    assert obs.occupancy is None and obs.merged_occupancy is None and obs.camera is None
    assert obs.partner is None and obs.visible is None and obs.snapshot is None
    assert obs.other_cavs is not None and obs.other_cavs.shape == (2, 2, 3)
    assert result.v2v is None


class Sees(PidAgent):
    observations: ClassVar[frozenset[Observation]] = frozenset({Observation.EGO_STATE, Observation.CAMERA})
    seen: ClassVar[list[Observations]] = []

    def run_step(self, obs: Observations) -> Controls:
        Sees.seen.append(obs)
        return super().run_step(obs)


def test_camera_images_come_batched_when_declared() -> None:
    Sees.seen.clear()
    evaluate_route(ring_route(), Sees, EvalConfig(tick_cap=3, background=TRAFFIC))
    images = Sees.seen[0].camera
    assert images is not None and images.shape == (2, 128, 256, 3) and images.dtype == np.uint8
    # the road ahead: the lower half of the image is mostly the grey road, the top row sky-blue
    bottom = images[:, 96:, 96:160].reshape(2, -1, 3).astype(int)
    assert (np.abs(bottom[..., 0] - bottom[..., 2]) < 25).mean() > 0.8
    top = images[:, 0].astype(int)
    assert (top[..., 2] > top[..., 0]).all()


def test_sensor_demo_video_shows_camera_occupancy_and_bev(tmp_path) -> None:
    import imageio.v3 as iio

    from cmudrive.viz.demo import run_demo

    out = tmp_path / "sensors.gif"
    stats = run_demo("downtown", cavs=3, seconds=0.3, output=out, sensors=True, follow=1, window=60.0)
    assert stats.ticks == 6
    frames = iio.imread(out)
    assert frames.shape[0] == 6
    height, width = frames.shape[1:3]
    # camera (2:1) + two occupancy panels (2:3) + the square BEV window, side by side
    assert width > 3.5 * height


class NamesNonsense(Cooperative):
    def next_partners(self) -> np.ndarray | None:
        return np.full(self._n, 0.5)  # not CAV indices


def test_partners_that_are_not_cav_indices_are_the_agents_crash() -> None:
    from cmudrive.bench.records import STATUS_AGENT_CRASHED

    result = evaluate_route(ring_route(), NamesNonsense, EvalConfig(tick_cap=10, background=TRAFFIC))
    assert result.status == STATUS_AGENT_CRASHED
    assert result.error is not None and "next_partners returned float64" in result.error


def test_camera_and_visibility_must_describe_the_same_camera() -> None:
    import pytest

    from cmudrive.bench.observe import SensorConfig
    from cmudrive.sensors import CameraConfig, VisibilityConfig

    SensorConfig(camera=CameraConfig(fov_deg=90.0), visibility=VisibilityConfig(fov_deg=90.0))
    with pytest.raises(ValueError, match="must describe the same camera"):
        SensorConfig(camera=CameraConfig(fov_deg=90.0))
