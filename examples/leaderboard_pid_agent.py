"""A small agent written for the CARLA Leaderboard 2.0, run on cmudrive with only its imports changed.

It follows its global plan's world coordinates: it finds itself with GNSS (position) and the IMU's
compass (heading), steers toward the plan point ``lookahead`` metres ahead with a PD controller and holds
``target_speed`` with a PI controller on the speedometer; it brakes for nothing (it ignores every other
road user and every light), and stops at the end of its plan. It asks for a front camera too, to show
the camera's format, and does not look at it. The configuration file (``--agent-option conf=...``) is
JSON: ``{"target_speed": m/s, "lookahead": m}``.

For the leaderboard, the three cmudrive imports below read:

    import carla
    from agents.navigation.local_planner import RoadOption
    from leaderboard.autoagents.autonomous_agent import AutonomousAgent, Track

Run it on cmudrive (from the repository root):

    cmudrive eval --routes smoke --agent leaderboard:examples/leaderboard_pid_agent.py \\
        --agent-option conf=examples/leaderboard_pid_agent.json --out out/lb-pid --workers 1
"""

import json
import math

import numpy as np

from cmudrive.leaderboard import RoadOption, carla
from cmudrive.leaderboard.autonomous_agent import AutonomousAgent, Track

EARTH_RADIUS = 6378137.0  # [m] the Mercator radius of CARLA's GNSS
STEER_GAIN, STEER_DAMPING = 1.2, 0.2  # [1/rad], [s/rad]
SPEED_GAIN, SPEED_INTEGRAL = 0.5, 0.05  # [1/(m/s)], [1/m]
STOP_DECEL = 2.0  # [m/s^2] comfortable braking toward the plan's last point
TURN_SPEED = 4.0  # [m/s] through turns at junctions


def get_entry_point():
    return "PidLeaderboardAgent"


class PidLeaderboardAgent(AutonomousAgent):
    def setup(self, path_to_conf_file):
        self.track = Track.SENSORS
        conf = {}
        if path_to_conf_file:
            with open(path_to_conf_file) as f:
                conf = json.load(f)
        self.target_speed = float(conf.get("target_speed", 6.0))
        self.lookahead = float(conf.get("lookahead", 6.0))
        self.progress = 0
        self.last_angle = 0.0
        self.speed_error_sum = 0.0
        self.last_time = None

    def sensors(self):
        return [
            {"type": "sensor.camera.rgb", "id": "rgb_front", "x": 1.3, "y": 0.0, "z": 2.3,
             "roll": 0.0, "pitch": 0.0, "yaw": 0.0, "width": 128, "height": 64, "fov": 100},
            {"type": "sensor.speedometer", "id": "speed", "reading_frequency": 20},
            {"type": "sensor.other.gnss", "id": "gps", "x": 0.0, "y": 0.0, "z": 0.0},
            {"type": "sensor.other.imu", "id": "imu", "x": 0.0, "y": 0.0, "z": 0.0,
             "roll": 0.0, "pitch": 0.0, "yaw": 0.0},
        ]  # fmt: skip

    def set_global_plan(self, global_plan_gps, global_plan_world_coord):
        super().set_global_plan(global_plan_gps, global_plan_world_coord)
        # keep the dense plan too: (x east, y north) metres from the first plan point
        self.origin_gps = global_plan_gps[0][0] if global_plan_gps else None
        first = global_plan_world_coord[0][0].location if global_plan_world_coord else None
        self.plan = np.array(
            [(t.location.x - first.x, -(t.location.y - first.y)) for t, _ in global_plan_world_coord]
        ).reshape(-1, 2)
        self.turns = [o in (RoadOption.LEFT, RoadOption.RIGHT) for _, o in global_plan_world_coord]

    def _local(self, lat, lon):
        """GNSS (deg) -> (east, north) metres from the first plan point (Mercator at its latitude)."""
        lat0, lon0 = self.origin_gps["lat"], self.origin_gps["lon"]
        k = EARTH_RADIUS * math.cos(math.radians(lat0))
        east = k * math.radians(lon - lon0)
        north = k * math.log(math.tan(math.radians(45 + lat / 2)) / math.tan(math.radians(45 + lat0 / 2)))
        return np.array([east, north])

    def run_step(self, input_data, timestamp):
        lat, lon, _ = input_data["gps"][1]
        speed = input_data["speed"][1]["speed"]
        compass = input_data["imu"][1][6]  # [rad] clockwise from north
        heading = math.pi / 2 - compass  # [rad] counter-clockwise from east
        position = self._local(lat, lon)
        dt = 0.05 if self.last_time is None else max(timestamp - self.last_time, 1e-3)
        self.last_time = timestamp

        # progress: the nearest plan point among the next 50
        window = self.plan[self.progress : self.progress + 50]
        self.progress += int(np.argmin(np.linalg.norm(window - position, axis=1)))
        ahead = min(self.progress + int(self.lookahead), len(self.plan) - 1)
        dx, dy = self.plan[ahead] - position
        angle = math.atan2(dy, dx) - heading
        angle = (angle + math.pi) % (2 * math.pi) - math.pi  # to the target, + = left

        control = carla.VehicleControl()
        turn = STEER_GAIN * angle + STEER_DAMPING * (angle - self.last_angle) / dt
        control.steer = float(np.clip(-turn, -1.0, 1.0))  # CARLA's steer: + = right
        self.last_angle = angle
        remaining = np.linalg.norm(self.plan[-1] - position)
        turning = any(self.turns[self.progress : self.progress + 15])
        wanted = min(self.target_speed, math.sqrt(2.0 * STOP_DECEL * remaining))
        if turning:
            wanted = min(wanted, TURN_SPEED)
        error = wanted - speed
        self.speed_error_sum = float(np.clip(self.speed_error_sum + error * dt, -10.0, 10.0))
        if wanted < 0.3 or speed > 1.2 * wanted + 0.5:
            control.throttle, control.brake = 0.0, 0.5 if wanted >= 0.3 else 1.0
        else:
            push = SPEED_GAIN * error + SPEED_INTEGRAL * self.speed_error_sum
            control.throttle = float(np.clip(push, 0.0, 0.8))
            control.brake = 0.0
        return control
