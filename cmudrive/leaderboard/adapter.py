"""Runs an agent written for the CARLA Leaderboard 2.0 / Bench2Drive on every CAV of a route.

``cmudrive eval --agent leaderboard:my_agent.py --agent-option conf=my_conf`` makes one
:class:`LeaderboardAgent` per route (the bundled agent ``leaderboard`` with the options ``agent=FILE``
and ``conf=...``). It imports the agent file (``get_entry_point()`` names its class) and, per route,
makes one instance of that class per CAV, in the leaderboard evaluator's order: ``cls(host, port,
debug)``, ``set_global_plan`` (the CAV's dense route in GPS and in CARLA world coordinates),
``setup(conf)``, ``sensors()``. Every tick, each active CAV's instance gets ``run_step(input_data,
timestamp)`` with its own sensors' readings in the leaderboard's shape (``{id: (frame, data)}``, frame =
the tick, timestamp = simulated seconds) and returns a ``VehicleControl``; the controls of all CAVs go
back to the world as one batch.

Why it declares the privileged observation: the sensors a leaderboard agent asks for (cameras at its
own poses and sizes, GNSS, IMU) are computed here from the snapshot, as the data collector computes its
sensors; the user's agent never sees the snapshot or the map, only its sensors' readings and the
global plan the leaderboard gives too. Its sensor suite is checked once before the run starts
(:meth:`LeaderboardAgent.check_options`: one instance is made and set up in the main process, with an
empty global plan, to call ``sensors()``), so that a LiDAR or any sensor we do not simulate stops the
run naming its id, before any route starts.

The agent file may import the modules beside it (its folder goes first on the import path), as under the
leaderboard's ``--agent``; it is imported once per process.
"""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Mapping
from pathlib import Path
from types import ModuleType
from typing import Any, ClassVar

import numpy as np

from cmudrive.agents.base import Agent, AgentSetupError, Observation, Observations, RouteSetup
from cmudrive.leaderboard.carla import Location, Rotation, Transform
from cmudrive.leaderboard.geo import GeoReference, geo_reference, map_to_gnss
from cmudrive.leaderboard.sensors import CAMERA, IMU, ImuTracker, SensorRig, SensorSpec, parse_sensors
from cmudrive.maps import RoadMap, RoadOption, Route, actor_elevation, load_scenery
from cmudrive.maps.coords import map_to_carla
from cmudrive.sensors.camera import CameraConfig, FrontCamera
from cmudrive.sim.dynamics import Controls
from cmudrive.sim.snapshot import Snapshot
from cmudrive.sim.weather import get_weather

CARLA_HOST, CARLA_PORT = "localhost", 2000  # handed to the agent's constructor; no server is behind them
# modules a leaderboard agent imports and what to import instead (the README's "Bring a leaderboard agent")
REPLACEMENTS = {
    "carla": "from cmudrive.leaderboard import carla",
    "leaderboard": "from cmudrive.leaderboard.autonomous_agent import AutonomousAgent, Track",
    "agents": "from cmudrive.leaderboard import RoadOption",
}
_MODULES: dict[Path, ModuleType] = {}  # agent files imported in this process, by resolved path


class LeaderboardAgent(Agent):
    """A leaderboard agent class run on every CAV (module docstring). Options: ``agent``, the agent
    file (.py); ``conf``, the string handed to ``setup`` (a file or folder, as the leaderboard's
    ``--agent-config``); ``debug``, handed to the constructor."""

    observations: ClassVar[frozenset[Observation]] = frozenset({Observation.PRIVILEGED})

    def __init__(self, agent: str = "", conf: str = "", debug: bool = False) -> None:
        if not agent:
            raise AgentSetupError(
                "the leaderboard adapter needs the agent file: --agent leaderboard:FILE.py "
                "(or --agent leaderboard --agent-option agent=FILE.py)"
            )
        self.agent_file = Path(agent)
        self.conf = str(conf)
        self.debug = bool(debug)
        self.agent_class = load_leaderboard_class(self.agent_file)
        self.where = f"{self.agent_file.name} ({self.agent_class.__name__})"
        self.instances: list[Any] = []

    # ------------------------------------------------------------------ run checks (main process)
    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """The agent file imports, its class sets up with ``conf``, and ``sensors()`` asks only for what
        we provide (SensorError naming the sensor otherwise)."""
        agent = cls(**options)
        probe = agent._instance()
        try:
            probe.set_global_plan([], [])
            probe.setup(agent.conf)
            parse_sensors(probe.sensors(), agent.where)
        finally:
            probe.destroy()

    @classmethod
    def input_files(cls, options: Mapping[str, Any]) -> dict[str, Path]:
        """The agent file, and ``conf`` when it names a file or folder: ``--resume`` compares their
        content."""
        files = {}
        for key in ("agent", "conf"):
            value = options.get(key)
            if isinstance(value, str) and value and Path(value).exists():
                files[key] = Path(value).resolve()
        return files

    # ------------------------------------------------------------------ route
    def setup(self, route: RouteSetup) -> None:
        road_map = route.road_map
        if road_map is None or any(c.dense_route is None for c in route.cavs):
            raise AgentSetupError("LeaderboardAgent needs the privileged set-up (map and dense routes)")
        geo = geo_reference(route.town)
        self.instances, self.rigs = [], []
        base_camera: FrontCamera | None = None
        weather = get_weather(route.weather)
        for plan in route.cavs:
            assert plan.dense_route is not None
            instance = self._instance()
            gps, world = global_plan(plan.dense_route, road_map, geo)
            instance.set_global_plan(gps, world)
            instance.setup(self.conf)
            specs = parse_sensors(instance.sensors(), f"{self.where} on CAV {plan.cav_id}")
            if base_camera is None and any(s.type == CAMERA for s in specs):
                base_camera = FrontCamera(CameraConfig(), road_map, load_scenery(road_map))
            self.instances.append(instance)
            self.rigs.append(SensorRig(specs, base_camera, weather, geo))
        self.cav_ids = [c.cav_id for c in route.cavs]
        self.imu = ImuTracker(len(route.cavs))

    def _instance(self) -> Any:
        try:
            return self.agent_class(CARLA_HOST, CARLA_PORT, self.debug)
        except TypeError as exc:
            raise AgentSetupError(
                f"{self.where}: the constructor must take (carla_host, carla_port, debug) as the "
                f"leaderboard's AutonomousAgent does: {exc}"
            ) from exc

    def run_step(self, obs: Observations) -> Controls:
        snap = obs.snapshot
        assert snap is not None
        rows = _rows_of(snap, obs.cav_index)
        self.imu.update(obs.cav_index, obs.time, snap.yaw[rows])
        controls = np.zeros((3, len(rows)))  # steer, throttle, brake
        for rig, members in self._groups(obs.cav_index):
            imu = (self.imu.rate[obs.cav_index[members]], self.imu.rate_change[obs.cav_index[members]])
            readings = rig.read(snap, rows[members], imu if any(s.type == IMU for s in rig.specs) else None)
            for k, a in enumerate(members):
                cav = int(obs.cav_index[a])
                input_data = {sid: (obs.tick, values[k]) for sid, values in readings.items()}
                try:
                    control = self.instances[cav].run_step(input_data, obs.time)
                except Exception as exc:
                    raise RuntimeError(
                        f"{self.where} on CAV {self.cav_ids[cav]}: run_step raised {exc!r}"
                    ) from exc
                controls[:, a] = self._control_values(control, cav)
        return Controls(steer=controls[0], throttle=controls[1], brake=controls[2])

    def _groups(self, cav_index: np.ndarray) -> list[tuple[SensorRig, np.ndarray]]:
        """Active CAVs grouped by sensor suite (positions in ``cav_index``), so each camera renders once
        for all CAVs that carry it."""
        groups: dict[tuple[SensorSpec, ...], list[int]] = {}
        rig_of: dict[tuple[SensorSpec, ...], SensorRig] = {}
        for a, cav in enumerate(cav_index):
            rig = self.rigs[int(cav)]
            groups.setdefault(rig.specs, []).append(a)
            rig_of.setdefault(rig.specs, rig)
        return [(rig_of[key], np.array(members, np.int64)) for key, members in groups.items()]

    def _control_values(self, control: Any, cav: int) -> tuple[float, float, float]:
        """(steer, throttle, brake) of a ``VehicleControl``-like object; an error naming the CAV when it
        is not one or asks for reverse."""
        who = f"{self.where} on CAV {self.cav_ids[cav]}"
        try:
            steer, throttle, brake = (float(getattr(control, k)) for k in ("steer", "throttle", "brake"))
        except (AttributeError, TypeError, ValueError) as exc:
            raise RuntimeError(
                f"{who}: run_step must return a VehicleControl with numeric steer, throttle and brake, "
                f"got {control!r} ({exc})"
            ) from exc
        if getattr(control, "reverse", False):
            raise RuntimeError(f"{who}: run_step asked for reverse gear, which cmudrive's CAVs do not have")
        if getattr(control, "hand_brake", False):
            brake = 1.0
        return steer, throttle, brake

    def destroy(self) -> None:
        """Every CAV's instance's ``destroy()``; the first error is raised after all have run."""
        problems = []
        for cav, instance in enumerate(self.instances):
            try:
                instance.destroy()
            except Exception as exc:
                problems.append(f"{self.where} on CAV {self.cav_ids[cav]}: destroy raised {exc!r}")
        self.instances = []
        if problems:
            raise RuntimeError("; ".join(problems))


def global_plan(
    route: Route, road_map: RoadMap, geo: GeoReference
) -> tuple[list[tuple[dict[str, float], RoadOption]], list[tuple[Transform, RoadOption]]]:
    """A dense route as the leaderboard's two global plans: GPS points ``{"lat", "lon", "z"}`` and CARLA
    world transforms (y mirrored from our map frame, yaw clockwise in degrees), each with its RoadOption."""
    z = np.nan_to_num(actor_elevation(road_map, route.lane, route.xy[:, 0], route.xy[:, 1]), nan=0.0)
    carla_xy, carla_yaw = map_to_carla(route.xy, route.heading)
    gnss = map_to_gnss(route.xy, z, geo)
    options = [RoadOption(int(o)) for o in route.option]
    world = [
        (Transform(Location(float(p[0]), float(p[1]), float(h)), Rotation(yaw=float(y))), o)
        for p, h, y, o in zip(carla_xy, z, carla_yaw, options, strict=True)
    ]
    gps = [
        ({"lat": float(g[0]), "lon": float(g[1]), "z": float(g[2])}, o)
        for g, o in zip(gnss, options, strict=True)
    ]
    return gps, world


def load_leaderboard_class(path: Path) -> type:
    """The class a leaderboard agent file names with ``get_entry_point()``, the file imported once per
    process; AgentSetupError naming the file for each way this fails (and, for a ``carla`` or
    ``leaderboard`` import, the line to write instead)."""
    path = Path(path)
    if path.suffix != ".py" or not path.is_file():
        raise AgentSetupError(f"leaderboard agent file {str(path)!r} is not a .py file that exists")
    module = _import_file(path.resolve())
    entry = getattr(module, "get_entry_point", None)
    if not callable(entry):
        raise AgentSetupError(
            f"{path}: no get_entry_point() function (a leaderboard agent file returns its class name from it)"
        )
    name = entry()
    cls = getattr(module, str(name), None)
    if not isinstance(cls, type):
        raise AgentSetupError(f"{path}: get_entry_point() returned {name!r}, which is no class in the file")
    missing = [
        m for m in ("setup", "sensors", "run_step", "set_global_plan", "destroy") if not hasattr(cls, m)
    ]
    if missing:
        raise AgentSetupError(
            f"{path}: class {cls.__name__} lacks {', '.join(missing)}: subclass "
            "cmudrive.leaderboard.AutonomousAgent, as for the leaderboard"
        )
    return cls


def _import_file(path: Path) -> ModuleType:
    if path in _MODULES:
        return _MODULES[path]
    folder = str(path.parent)
    if folder not in sys.path:
        sys.path.insert(0, folder)  # the agent's own helper modules, as the leaderboard's import allows
    name = f"cmudrive_leaderboard_agent_{len(_MODULES)}_{path.stem}"
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except ImportError as exc:
        del sys.modules[name]
        top = (exc.name or "").split(".")[0]
        hint = (
            f"; write `{REPLACEMENTS[top]}` instead (README: Bring a leaderboard agent)"
            if top in REPLACEMENTS
            else ""
        )
        raise AgentSetupError(f"{path}: cannot import it: {exc}{hint}") from exc
    except Exception as exc:
        del sys.modules[name]
        raise AgentSetupError(f"{path}: importing it raised {exc!r}") from exc
    _MODULES[path] = module
    return module


def _rows_of(snap: Snapshot, cav_index: np.ndarray) -> np.ndarray:
    """Snapshot rows of the CAVs ``cav_index`` (n,), in that order."""
    rows, index = snap.cav_rows()
    row_of = dict(zip(index.tolist(), rows.tolist(), strict=True))
    return np.array([row_of[int(i)] for i in cav_index], np.int64)


__all__ = ["LeaderboardAgent", "global_plan", "load_leaderboard_class"]
