"""Does a model go and stop where the expert does? The controller's one decision, on held-out rows.

    python benchmarks/go_stop.py --data data/train [--rows 20000] [--threads 2]
        [--checkpoint cmudrive/assets/models/v2v-vla-tiny-no-speed ...]

A waypoint model's waypoint errors say little about the one decision its closed-loop score hangs on:
whether the controller brakes. **The expert's decision** is SimLingo's brake rule
(:func:`cmudrive.agents.control.brakes`: a desired speed below 0.4 m/s, or one the CAV exceeds by more
than 10 %) applied to the expert's own target speed (``target_speed``: where its speed controller means
to be in 0.5 s; it holds the brake below 0.3 m/s). **A model's decision**, for a model with a speed query
(``speed_query``; what its agent uses): the brake rule applied to the speed it predicts to drive at
(learned from the expert's ``desired_speed``), or, for a model that reads its speed, its stop probability
above 0.5; and, for every model, the
rule applied to the desired speed that SimLingo's controller reads from its speed waypoints (0.25 s to
0.75 s; what the agent of a model without a speed query uses). The first lines of the table apply the
rule to the expert's own speed waypoints and to its desired speed: what a perfect copy of either would
decide.

Rows are the validation routes of ``cmudrive train``'s default split (every k-th row up to ``--rows``),
counted per situation: the CAV stands (below 0.1 m/s) and the expert drives off - at the route's start
(every CAV stands at t = 0, in front of an open road) or later (after a stop sign, a light, a queue: the
drive-offs the closed loop hangs on) - or stays; it moves and the expert drives on or brakes. Printed: the
share of rows where the decision is the expert's, per situation and over all rows.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from ablation import held_out_rows

from cmudrive.agents.control import STOPPED_SPEED, brakes, desired_speed, expert_stops
from cmudrive.model import V2VVLA

ROUTE_START = 2.0  # [s] a drive-off before this is the route's start (every CAV stands at t = 0)
SITUATIONS = (
    "stands, expert drives off at the route's start",
    "stands, expert drives off later",
    "stands, expert stays",
    "moves, expert drives",
    "moves, expert brakes",
)


def situations(speed: np.ndarray, expert: np.ndarray, time: np.ndarray) -> dict[str, np.ndarray]:
    """Row masks of the five situations (``time``: the rows' simulation time [s])."""
    standing = speed < STOPPED_SPEED
    return dict(
        zip(
            SITUATIONS,
            (
                standing & ~expert & (time < ROUTE_START),
                standing & ~expert & (time >= ROUTE_START),
                standing & expert,
                ~standing & ~expert,
                ~standing & expert,
            ),
            strict=True,
        )
    )


def decision_table(
    speed: np.ndarray, expert: np.ndarray, time: np.ndarray, stops: np.ndarray
) -> dict[str, tuple[float, int]]:
    """Agreement of the decisions ``stops`` (N,) bool with the expert's, per situation and over all rows:
    name -> (share of the rows where they agree, number of rows)."""
    masks = {**situations(speed, expert, time), "all rows": np.ones(len(speed), bool)}
    return {
        name: (float(np.mean(stops[m] == expert[m])) if m.any() else float("nan"), int(m.sum()))
        for name, m in masks.items()
    }


def model_stops(
    model: V2VVLA, rows: list[dict], speed: np.ndarray, batch: int = 64
) -> tuple[np.ndarray, np.ndarray | None]:
    """(N,) bool brake decisions on ``rows`` (no language): SimLingo's rule on the model's speed waypoints,
    and, for a model with a speed query, the agent's decision (its stop probability above 0.5, or the
    rule on its predicted speed; else None)."""
    rule, head = [], []
    with torch.no_grad():
        for i in range(0, len(rows), batch):
            pred = model.predict(rows[i : i + batch], max_new_tokens=0)
            wp = pred.speed_waypoints.float().numpy().astype(np.float64)
            rule.append(brakes(speed[i : i + batch], desired_speed(wp)))
            if pred.stop_prob is not None and pred.target_speed is not None:  # as V2VVLAAgent decides
                target = pred.target_speed.float().numpy().astype(np.float64)
                decided = brakes(speed[i : i + batch], target)
                if model.config.speed_in_prompt:  # the stop head only for a model that reads its speed
                    decided |= pred.stop_prob.float().numpy() > 0.5
                head.append(decided)
    return np.concatenate(rule), (np.concatenate(head) if head else None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", required=True)
    parser.add_argument("--rows", type=int, default=3000)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument(
        "--checkpoint",
        action="append",
        help="model directory, repeatable (default: the two committed default checkpoints)",
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    checkpoints = args.checkpoint or [
        "cmudrive/assets/models/v2v-vla-tiny-no-speed",
        "cmudrive/assets/models/v2v-vla-baseline-tiny-no-speed",
    ]
    _, rows, _ = held_out_rows(args.data, args.rows)
    speed = np.array([float(r["speed"]) for r in rows])
    time = np.array([float(r["time"]) for r in rows])
    expert = expert_stops(speed, np.array([float(r["target_speed"]) for r in rows]))
    expert_wp = np.stack([np.asarray(r["speed_waypoints"], np.float64) for r in rows])
    tables = {
        "the expert's speed waypoints, SimLingo's rule": decision_table(
            speed, expert, time, brakes(speed, desired_speed(expert_wp))
        ),
        "the expert's desired speed, SimLingo's rule": decision_table(
            speed, expert, time, brakes(speed, np.array([float(r["desired_speed"]) for r in rows]))
        ),
    }
    for path in checkpoints:
        model = V2VVLA.from_pretrained(path).eval()
        rule, head = model_stops(model, rows, speed)
        if head is not None:
            tables[f"{path}, rule on its speed (or stop head) (what the agent uses)"] = decision_table(
                speed, expert, time, head
            )
        tables[f"{path}, its speed waypoints, SimLingo's rule"] = decision_table(speed, expert, time, rule)
    counts = next(iter(tables.values()))
    print(f"{len(rows)} held-out rows; share of rows where the decision is the expert's:")
    print("| decisions of | " + " | ".join(f"{n} ({c[1]})" for n, c in counts.items()) + " |")
    print("|---|" + "---|" * len(counts))
    for name, table in tables.items():
        print(f"| {name} | " + " | ".join(f"{v[0]:.1%}" for v in table.values()) + " |")


if __name__ == "__main__":
    main()
