"""Does a model brake where the expert brakes? SimLingo's controller decision on held-out rows.

    python benchmarks/go_stop.py --data data/train [--rows 3000] [--threads 2]
        [--checkpoint cmudrive/assets/models/v2v-vla-tiny ...]

A waypoint model's waypoint errors say little about the one decision that its closed-loop score hangs on:
SimLingo's controller brakes when the desired speed read from the 0.25 s and 0.75 s speed waypoints is
below 0.4 m/s or exceeded by 10 % (:func:`cmudrive.agents.control.brakes`), and drives otherwise. This
script applies that rule to the expert's speed waypoints and to each model's, on the validation rows of
``cmudrive train``'s default split (every k-th row up to ``--rows``), and prints, for rows where the CAV
stands (below 0.1 m/s) and where it moves, how often the model drives where the expert drives and brakes
where the expert brakes. A model that copies its speed input starts in few of the "stands, expert
drives" rows; one that does not see the road stops in few of the "moves, expert brakes" rows.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from ablation import held_out_rows, predicted_waypoints

from cmudrive.agents.control import STOPPED_SPEED, brakes, desired_speed
from cmudrive.model import V2VVLA


def decision_table(speed: np.ndarray, expert: np.ndarray, model: np.ndarray) -> dict[str, tuple[float, int]]:
    """Agreement of the model's brake decisions with the expert's, per situation: name -> (share of the
    rows where the model decides as the expert, number of rows)."""
    expert_brakes = brakes(speed, desired_speed(expert))
    model_brakes = brakes(speed, desired_speed(model))
    standing = speed < STOPPED_SPEED
    cases = {
        "stands, expert drives": standing & ~expert_brakes,
        "stands, expert stays": standing & expert_brakes,
        "moves, expert drives": ~standing & ~expert_brakes,
        "moves, expert brakes": ~standing & expert_brakes,
    }
    return {
        name: (
            float(np.mean(model_brakes[mask] == expert_brakes[mask])) if mask.any() else float("nan"),
            int(mask.sum()),
        )
        for name, mask in cases.items()
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", required=True)
    parser.add_argument("--rows", type=int, default=3000)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument(
        "--checkpoint",
        action="append",
        help="model directory, repeatable (default: the two committed tiny checkpoints)",
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    checkpoints = args.checkpoint or [
        "cmudrive/assets/models/v2v-vla-tiny-no-speed",
        "cmudrive/assets/models/v2v-vla-baseline-tiny-no-speed",
    ]
    _, rows, _ = held_out_rows(args.data, args.rows)
    speed = np.array([float(r["speed"]) for r in rows])
    expert = np.stack([np.asarray(r["speed_waypoints"], np.float64) for r in rows])
    tables = {}
    for path in checkpoints:
        model = V2VVLA.from_pretrained(path).eval()
        tables[path] = decision_table(
            speed, expert, predicted_waypoints(model, rows)[1].numpy().astype(np.float64)
        )
    names = list(next(iter(tables.values())))
    counts = next(iter(tables.values()))
    print(f"{len(rows)} held-out rows; share of rows where the model decides as the expert:")
    print("| checkpoint | " + " | ".join(f"{n} ({counts[n][1]})" for n in names) + " |")
    print("|---|" + "---|" * len(names))
    for path, table in tables.items():
        print(f"| {path} | " + " | ".join(f"{table[n][0]:.1%}" for n in names) + " |")


if __name__ == "__main__":
    main()
