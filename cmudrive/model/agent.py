"""V2V-VLA in closed loop: one model drives every CAV of a route, all CAVs of a tick in one batch.

Per tick, for the ``n`` active CAVs:

1. each CAV's row, as the dataset has it (:class:`cmudrive.model.row.RowBuilder`, the row contract the
   collector stores rows with): the front camera after the dataset's JPEG round trip, the merged
   occupancy drawn with the dataset's palette, its speed, how long it has stood (counted every tick),
   the next two sparse route target points in its frame (progress along the leaderboard-style sparse plan
   that every agent gets, no privileged map) and the other CAVs' poses; the model's configuration says
   which of them its prompt states;
2. one :meth:`~cmudrive.model.V2VVLA.predict` for all of them: the waypoints from one pass over
   prompt + queries every tick, and language (greedy decoding on the same KV cache) every
   ``language_every`` ticks (default 5: the dataset's 4 Hz, the rate its commentary labels change at;
   decoding some 50 tokens at 20 Hz would cost several times the driving pass). The waypoints do not
   depend on the language (the model's layout puts the queries before the answer), so the silent ticks
   drive exactly as the talking ones;
3. SimLingo's controller (:class:`~cmudrive.agents.control.WaypointController`) turns the waypoints into
   steer, throttle and brake; a model with a speed query (``speed_query``) predicts the speed to drive
   at, and the CAV brakes where SimLingo's brake rule says so for it (above it by 10 %, or it below 0.4
   m/s) and, for a model that reads its speed, where its stop probability exceeds 0.5 (the stop label is
   a function of the speed: a model that never sees it cannot know it); the path still steers;
4. the CAV named in each communication sentence becomes that CAV's partner from the next tick
   (:meth:`next_partners`; -1, the default closest CAV in front, when it names none);
5. with ``safety_brake=True`` (off by default: the paper's agent has no such layer), a CAV whose own
   predicted path runs into an occupied cell of the occupancy its model sees (the baseline: the CAV's
   own occupancy), within its stopping distance, brakes fully
   (:class:`~cmudrive.agents.shield.SafetyBrake`; it overrides the creep).

The checkpoint: ``V2VVLAAgent(checkpoint=PATH)`` (``cmudrive eval --agent v2v-vla --checkpoint PATH``
passes it through ``EvalConfig.agent_options``), else the committed one under
``cmudrive/assets/models/v2v-vla-tiny-no-speed/`` (``v2v-vla-baseline-tiny-no-speed/`` for
:class:`V2VVLABaselineAgent`): the pair trained without the speed in the prompt, which drives better in
closed loop than the pair that reads it (``v2v-vla-tiny/``, ``v2v-vla-baseline-tiny/``; README).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from cmudrive.agents.base import Agent, Observation, Observations, RouteSetup
from cmudrive.agents.control import WaypointController
from cmudrive.agents.shield import SafetyBrake
from cmudrive.model.row import RowBuilder
from cmudrive.sim.dynamics import Controls

MODELS = Path(__file__).resolve().parents[1] / "assets" / "models"
DEFAULT_CHECKPOINT = MODELS / "v2v-vla-tiny-no-speed"
DEFAULT_BASELINE_CHECKPOINT = MODELS / "v2v-vla-baseline-tiny-no-speed"
LANGUAGE_EVERY = 5  # [ticks] generate language at 4 Hz (the dataset's sample rate)
STOP_PROBABILITY = 0.5  # [-] a model with a speed query brakes where its stop probability exceeds this


def resolve_checkpoint(checkpoint: str | Path | None, cooperative: bool) -> Path:
    """The checkpoint directory to load, or a FileNotFoundError that says what to do."""
    default = DEFAULT_CHECKPOINT if cooperative else DEFAULT_BASELINE_CHECKPOINT
    path = Path(checkpoint) if checkpoint is not None else default
    if not (path / "vla_config.json").is_file():
        flag = "" if cooperative else " --baseline"
        hint = (
            "no trained checkpoint is committed there yet"
            if checkpoint is None
            else "not a V2VVLA.save_pretrained directory"
        )
        raise FileNotFoundError(
            f"V2V-VLA checkpoint {path}: {hint}. Train one (cmudrive train --data DIR --out runs/NAME"
            f"{flag}) and pass --checkpoint runs/NAME/model"
        )
    return path


def load_checkpoint(path: Path, device: str, cooperative: bool) -> Any:
    """The V2VVLA model saved in ``path`` on ``device``; ValueError when it is the other kind of model
    (cooperative or baseline) than the agent's."""
    from cmudrive.model.modeling import V2VVLA

    model = V2VVLA.from_pretrained(path, device=device).eval()
    if model.config.cooperative != cooperative:
        kind = "cooperative" if model.config.cooperative else "baseline"
        raise ValueError(
            f"{path} holds a {kind} model; use the "
            f"{'v2v-vla' if model.config.cooperative else 'v2v-vla-baseline'} agent"
        )
    return model


class V2VVLAAgent(Agent):
    """The cooperative V2V-VLA: camera + merged occupancy + other CAVs in, waypoints + language out."""

    observations: ClassVar[frozenset[Observation]] = frozenset(
        {Observation.EGO_STATE, Observation.CAMERA, Observation.MERGED_OCCUPANCY}
    )
    cooperative: ClassVar[bool] = True

    def __init__(
        self,
        checkpoint: str | Path | None = None,
        language_every: int = LANGUAGE_EVERY,
        max_new_tokens: int | None = None,
        device: str | None = None,
        partner_requests: bool = True,
        bev: str = "merged",
        other_cavs: bool = True,
        camera_jpeg: bool = True,
        desired_speed: str = "query",
        safety_brake: bool = False,
    ) -> None:
        """``checkpoint``: a ``V2VVLA.save_pretrained`` directory (default: the committed one);
        ``max_new_tokens``: cap on generated answer tokens (default: the model's ``max_answer_tokens``).
        Ablations of the cooperative model: ``partner_requests=False`` ignores the partner its sentences
        name (every CAV keeps the default partner, the closest CAV in front); ``bev="own"`` gives it the
        CAV's own occupancy instead of the merged one (no partner information in the image),
        ``bev="empty"`` an image of no occupancy at all (what does the model take from the image?);
        ``other_cavs=False`` lists no other CAV in the prompt (so the model has none to name either).
        ``camera_jpeg=False`` feeds the raw camera render instead of the dataset's JPEG round trip
        (which training saw; ~0.3 ms per CAV and tick, docs/model.md, "Row contract").
        ``desired_speed``, for a model with a speed query: ``"query"`` drives toward its predicted speed
        (go/stop as in the module docstring), ``"waypoints"`` toward the speed SimLingo's controller
        reads from its speed waypoints, braking where the stop probability exceeds 0.5 (docs/model.md,
        "Go/stop").
        ``safety_brake=True`` adds the occupancy safety brake (step 5 of the module docstring) on the
        grid the model sees (the own grid for ``bev="own"`` and ``bev="empty"``; the baseline, whose
        model sees no grid, asks for the CAV's own occupancy for the brake alone)."""
        if language_every < 1:
            raise ValueError(f"language_every must be >= 1 tick, got {language_every}")
        if bev not in ("merged", "own", "empty"):
            raise ValueError(f"bev must be 'merged', 'own' or 'empty', got {bev!r}")
        if desired_speed not in ("query", "waypoints"):
            raise ValueError(f"desired_speed must be 'query' or 'waypoints', got {desired_speed!r}")
        self.desired_speed = desired_speed
        self.safety_brake = SafetyBrake() if safety_brake else None
        self.partner_requests = partner_requests
        self.bev = bev
        self.other_cavs = other_cavs
        self.camera_jpeg = camera_jpeg
        self.checkpoint = resolve_checkpoint(checkpoint, self.cooperative)
        self.language_every = language_every
        self.max_new_tokens = max_new_tokens
        self.device = device
        self.model: Any = None
        self.last_text: list[str] = []

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """Before the first route: the options are valid and the checkpoint loads (on the CPU, once; a
        missing, broken or inconsistent checkpoint stops the run with the reason instead of crashing
        every route). The tiny checkpoints load in about a second after torch's import."""
        agent = cls(**options)
        load_checkpoint(agent.checkpoint, "cpu", cls.cooperative)

    @classmethod
    def input_files(cls, options: Mapping[str, Any]) -> dict[str, Path]:
        """The checkpoint it loads: ``checkpoint`` or the committed default."""
        files = super().input_files(options)
        try:
            files["checkpoint"] = resolve_checkpoint(options.get("checkpoint"), cls.cooperative).resolve()
        except FileNotFoundError:  # the agent's constructor says so, in every route
            pass
        return files

    def setup(self, route: RouteSetup) -> None:
        if self.model is None:
            import torch

            device = self.device or ("cuda" if torch.cuda.is_available() else "cpu")
            self.model = load_checkpoint(self.checkpoint, device, self.cooperative)
        k = len(route.cavs)
        self.row_builder = RowBuilder(route.cavs)
        self.controller = WaypointController(k)
        self.talked = np.zeros(k, bool)  # has generated language at least once
        self.last_text = [""] * k
        self.requested = np.full(k, -1, np.int64)  # partner named by each CAV's last sentence
        self.cav_index = np.zeros(0, np.int64)

    def needed_observations(self) -> frozenset[Observation]:
        """The class's observations; the baseline's safety brake adds the CAV's own occupancy."""
        if self.safety_brake is not None and not self.cooperative:
            return self.observations | {Observation.OCCUPANCY}
        return self.observations

    def rows(self, obs: Observations) -> list[dict[str, Any]]:
        """The model's input rows of the active CAVs, as the dataset has them (the row contract,
        :class:`~cmudrive.model.row.RowBuilder`). Advances the CAVs' progress along their plans: once a
        tick."""
        grid = None
        if self.cooperative:
            grid = obs.merged_occupancy if self.bev == "merged" else obs.occupancy
            assert grid is not None
            if self.bev == "empty":
                grid = np.zeros_like(grid)
        rows = self.row_builder.model_rows(self.row_builder.inputs(obs, grid), jpeg=self.camera_jpeg)
        if not self.other_cavs:
            for row in rows:
                row["other_cavs"] = []
        return rows

    def run_step(self, obs: Observations) -> Controls:
        idx = np.asarray(obs.cav_index, np.int64)
        self.cav_index = idx
        if len(idx) == 0:
            return Controls(steer=np.zeros(0), throttle=np.zeros(0), brake=np.zeros(0))
        talk = obs.tick % self.language_every == 0 or not self.talked[idx].all()
        pred = self.model.predict(self.rows(obs), max_new_tokens=self.max_new_tokens if talk else 0)
        if talk:
            self.talked[idx] = True
            for a, k in enumerate(idx):
                self.last_text[int(k)] = pred.text[a]
                self.requested[int(k)] = pred.partner[a] if self.cooperative and self.partner_requests else -1
        path = pred.path.float().cpu().numpy().astype(np.float64)  # (n, 20, 2) ego frame [m]
        speed_wp = pred.speed_waypoints.float().cpu().numpy().astype(np.float64)  # (n, 10, 2)
        target_speed = stop = None
        if pred.target_speed is not None and pred.stop_prob is not None:  # go/stop from the speed query
            stop = pred.stop_prob.float().cpu().numpy() > STOP_PROBABILITY
            if self.desired_speed == "query":
                target_speed = pred.target_speed.float().cpu().numpy().astype(np.float64)
                if not self.model.config.speed_in_prompt:  # the brake rule on its speed alone
                    stop = np.zeros(len(idx), bool)
        speed = np.asarray(obs.speed, np.float64)
        steer, throttle, brake = self.controller(idx, speed, path, speed_wp, target_speed, stop)
        if self.safety_brake is not None:
            grid = obs.merged_occupancy if self.cooperative and self.bev == "merged" else obs.occupancy
            assert grid is not None
            if grid.shape[-2:] != self.safety_brake.config.shape:
                raise ValueError(
                    f"safety_brake: occupancy grids of {grid.shape[-2:]} cells, the brake reads "
                    f"{self.safety_brake.config.shape} (the default OccupancyConfig)"
                )
            blocked = self.safety_brake(grid, path, speed)
            throttle = np.where(blocked, 0.0, throttle)
            brake = np.where(blocked, 1.0, brake)
        return Controls(steer=steer, throttle=throttle, brake=brake)

    def next_partners(self) -> np.ndarray | None:
        """The CAV each active CAV's last sentence named (-1: the default partner)."""
        return self.requested[self.cav_index] if self.cooperative else None


class V2VVLABaselineAgent(V2VVLAAgent):
    """The non-cooperative baseline (SimLingo's inputs): camera, speed and target points only."""

    observations: ClassVar[frozenset[Observation]] = frozenset({Observation.EGO_STATE, Observation.CAMERA})
    cooperative: ClassVar[bool] = False
