"""Does a model leave a stop where the expert does? Its go/stop on the expert's own closed-loop states.

    (cd benchmarks && cmudrive eval --agent shadow_go_stop:ShadowGoStop --routes cmudrive44 \\
        --routes-subset NonSignalizedJunctionRightTurn_1,VanillaNonSignalizedTurn_1 \\
        --agent-option out=../runs/shadow [--agent-option every=1] [--checkpoint DIR] \\
        --out ../runs/shadow-eval)
    python benchmarks/shadow_go_stop.py runs/shadow [runs/shadow-other ...]   # the table, one row each

``benchmarks/go_stop.py`` scores held-out dataset rows, where the drive-offs that matter (after a stop
sign, a light, a queue) are a handful: 11 of 10,000 rows of ``data/train3``, against 61 at the routes'
starts. This agent lets the privileged expert drive every CAV (its controls, its route, its scores) and,
every ``every`` ticks (1 catches every drive-off: the expert is past 0.1 m/s within a few ticks of its
decision), asks the learned model for its go/stop on the rows the closed-loop agent would
build from the same observations (:class:`cmudrive.model.row.RowBuilder`) for every CAV standing below
0.1 m/s. The model's decision is the agent's (SimLingo's brake rule on its predicted speed, or its stop
probability for a model that reads its speed); the expert's is its own (``expert_stops`` on its target
speed). Rows are counted per situation: the expert drives off at the route's start (t < 2 s), drives off
later, or stays. One JSON file per route is written to ``out``; the second command above merges them.
A baseline checkpoint needs ``--agent-option cooperative=false``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
from go_stop import ROUTE_START

from cmudrive.agents.base import AgentSetupError, Observation, Observations, RouteSetup
from cmudrive.agents.control import STOPPED_SPEED, brakes, expert_stops
from cmudrive.agents.expert import ExpertAgent
from cmudrive.model.agent import load_checkpoint, resolve_checkpoint
from cmudrive.model.row import RowBuilder
from cmudrive.sim.dynamics import Controls

SITUATIONS = ("drives off at the start", "drives off later", "stays")


class ShadowGoStop(ExpertAgent):
    """The expert drives; the model's go/stop is asked on the standing CAVs' rows (module docstring)."""

    observations = frozenset(
        {Observation.PRIVILEGED, Observation.EGO_STATE, Observation.CAMERA, Observation.MERGED_OCCUPANCY}
    )

    def __init__(
        self, out: str, checkpoint: str | None = None, every: int = 5, cooperative: bool = True, **kwargs: Any
    ) -> None:
        super().__init__(**kwargs)
        if every < 1:
            raise ValueError(f"every must be >= 1 tick, got {every}")
        self.out, self.every, self.cooperative = Path(out), every, cooperative
        self.checkpoint = resolve_checkpoint(checkpoint, cooperative)
        self.model: Any = None
        self.route_id: str | None = None  # set once the route is set up: destroy() writes only then

    def setup(self, route: RouteSetup) -> None:
        self.route_id = None
        super().setup(route)
        if self.model is None:
            self.model = load_checkpoint(self.checkpoint, "cpu", self.cooperative)
            if not self.model.config.speed_query:
                raise AgentSetupError(f"{self.checkpoint}: a model without a speed query; go/stop needs one")
        self.route_id = route.route_id
        self.row_builder = RowBuilder(route.cavs)
        self.rows: list[dict[str, Any]] = []

    def run_step(self, obs: Observations) -> Controls:
        controls = super().run_step(obs)
        grid = obs.merged_occupancy if self.cooperative else None
        # every tick: the standing clock and the target points advance
        inputs = self.row_builder.inputs(obs, grid)
        speed = np.asarray(obs.speed, np.float64)
        standing = np.flatnonzero(speed < STOPPED_SPEED)
        if obs.tick % self.every or not len(standing):
            return controls
        rows = self.row_builder.model_rows(inputs)
        pred = self.model.predict([rows[a] for a in standing], max_new_tokens=0)
        target = pred.target_speed.float().numpy().astype(np.float64)
        model_stops = brakes(speed[standing], target)
        if self.model.config.speed_in_prompt:
            model_stops |= pred.stop_prob.float().numpy() > 0.5
        decision = self.decision
        assert decision is not None
        expert = expert_stops(speed[standing], np.asarray(decision.target_speed)[standing])
        for i, a in enumerate(standing):
            situation = "stays" if expert[i] else SITUATIONS[int(obs.time >= ROUTE_START)]
            self.rows.append(
                {
                    "tick": int(obs.tick),
                    "cav": int(obs.cav_index[a]),
                    "situation": situation,
                    "agrees": bool(model_stops[i] == expert[i]),
                    "model_speed": float(target[i]),
                    "expert_desired": float(np.asarray(decision.desired_speed)[a]),
                }
            )
        return controls

    def destroy(self) -> None:
        if self.route_id is None:
            return
        self.out.mkdir(parents=True, exist_ok=True)
        record = {"route_id": self.route_id, "checkpoint": str(self.checkpoint), "rows": self.rows}
        (self.out / f"{self.route_id}.json").write_text(json.dumps(record))


def table(folder: Path) -> dict[str, tuple[float, int]]:
    """Situation -> (share of rows where the model agrees with the expert, number of rows), over every
    route record in ``folder``."""
    rows = [r for f in sorted(folder.glob("*.json")) for r in json.loads(f.read_text())["rows"]]
    out = {}
    for name in SITUATIONS:
        agree = [r["agrees"] for r in rows if r["situation"] == name]
        out[name] = (float(np.mean(agree)) if agree else float("nan"), len(agree))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, help="the agent's out folders, one per model")
    args = parser.parse_args()
    names = None
    for folder in args.folders:
        t = table(folder)
        if names is None:
            names = list(t)
            print("| model | " + " | ".join(names) + " |")
            print("|---|" + "---|" * len(names))
        print(f"| {folder} | " + " | ".join(f"{v:.1%} ({n})" for v, n in t.values()) + " |")


if __name__ == "__main__":
    main()
