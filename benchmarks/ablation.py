"""Offline ablation of V2V-VLA's cooperative inputs on held-out routes: does the model use them?

    python benchmarks/ablation.py --data data/train [--rows 2000] [--threads 2]
        [--coop cmudrive/assets/models/v2v-vla-tiny] [--baseline cmudrive/assets/models/v2v-vla-baseline-tiny]

The validation routes of ``cmudrive train`` (the same route-level split, seed 0), every k-th row up to
``--rows``. The cooperative model is run on each row as it is (merged BEV, other CAVs), with the CAV's own
occupancy drawn in place of the merged one, with an empty occupancy image, and without the other CAVs;
the baseline as it is. For each: the mean L2 error [m] of the 20 path points and of the 10 speed
waypoints, over all rows and over the rows where a partner sees something the ego's camera does not
(``partner_label >= 0``, every such row of the validation routes). For the cooperative model on those rows,
also how often its generated communication sentence names the labelled partner.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from cmudrive.data.schema import packed_to_rgb
from cmudrive.model import V2VVLA
from cmudrive.model.dataset import DrivingDataset, expert_rows, load_rows, split_routes
from cmudrive.model.train import TrainConfig

Variant = Callable[[dict[str, Any]], dict[str, Any]]


def held_out_rows(
    data: str, limit: int, extra: tuple[str, ...] = ()
) -> tuple[Any, list[dict[str, Any]], list[dict[str, Any]]]:
    """(the validation rows of ``cmudrive train``'s default split - same routes, seed 0 -, every k-th of
    them up to ``limit`` as decoded rows, and every row with a labelled partner as decoded rows)."""
    ds = load_rows(data, extra)
    route_of = np.asarray(ds["route_id"])
    split = TrainConfig(data=data, out="unused")  # cmudrive train's defaults: the same held-out routes
    routes = split_routes(sorted(set(route_of.tolist())), split.val_fraction, split.seed)
    val = ds.select(np.flatnonzero(np.isin(route_of, routes) & expert_rows(ds)))  # the expert's own views
    decoded = DrivingDataset(val)
    step = max(1, len(decoded) // limit)
    rows = [decoded[i] for i in range(0, len(decoded), step)][:limit]
    seen = [decoded[int(i)] for i in np.flatnonzero(np.asarray(val["partner_label"]) >= 0)]
    return val, rows, seen


def predicted_waypoints(model: V2VVLA, rows: list[dict[str, Any]], batch: int = 64) -> tuple[Any, Any]:
    """(path (N, 20, 2), speed waypoints (N, 10, 2)) [m], float32 tensors: ``model``'s waypoints for
    ``rows``, in batches, no language."""
    path, speed = [], []
    with torch.no_grad():
        for i in range(0, len(rows), batch):
            pred = model.predict(rows[i : i + batch], max_new_tokens=0)
            path.append(pred.path.float())
            speed.append(pred.speed_waypoints.float())
    return torch.cat(path), torch.cat(speed)


def errors(model: V2VVLA, rows: list[dict[str, Any]]) -> tuple[float, float]:
    """Mean path and speed-waypoint L2 errors [m] of ``model`` on ``rows``."""
    path, speed = predicted_waypoints(model, rows)
    target_path = torch.tensor(np.stack([r["path"] for r in rows]), dtype=torch.float32)
    target_speed = torch.tensor(np.stack([r["speed_waypoints"] for r in rows]), dtype=torch.float32)
    return (
        float((path - target_path).norm(dim=-1).mean()),
        float((speed - target_speed).norm(dim=-1).mean()),
    )


def partner_accuracy(model: V2VVLA, rows: list[dict[str, Any]], batch: int = 32) -> float:
    """Share of ``rows`` whose generated communication sentence names their ``partner_label``."""
    hits = 0
    for i in range(0, len(rows), batch):
        chunk = rows[i : i + batch]
        pred = model.predict(chunk)
        hits += sum(int(p == int(r["partner_label"])) for p, r in zip(pred.partner, chunk, strict=True))
    return hits / max(len(rows), 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", required=True)
    parser.add_argument("--rows", type=int, default=2000)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--coop", default="cmudrive/assets/models/v2v-vla-tiny-no-speed")
    parser.add_argument("--baseline", default="cmudrive/assets/models/v2v-vla-baseline-tiny-no-speed")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    val, rows, seen = held_out_rows(args.data, args.rows, extra=("occupancy",))  # own grid for the ablation
    routes = len(set(val["route_id"]))
    print(f"{routes} validation routes, {len(val)} rows: {len(rows)} sampled, {len(seen)} with a partner")

    empty = packed_to_rgb(np.zeros_like(np.asarray(rows[0]["occupancy"])))
    variants: dict[str, Variant] = {
        "as collected": lambda r: r,
        "own occupancy instead of merged": lambda r: {
            **r,
            "merged_bev": packed_to_rgb(np.asarray(r["occupancy"])),
        },
        "empty occupancy image": lambda r: {**r, "merged_bev": empty},
        "no other CAVs in the prompt": lambda r: {**r, "other_cavs": []},
    }
    coop = V2VVLA.from_pretrained(args.coop).eval()
    baseline = V2VVLA.from_pretrained(args.baseline).eval()
    print("| model, input | path L2 [m] | speed L2 [m] | path L2, partner rows | speed L2, partner rows |")
    print("|---|---|---|---|---|")
    for name, change in variants.items():
        a, b = errors(coop, [change(r) for r in rows])
        c, d = errors(coop, [change(r) for r in seen])
        print(f"| V2V-VLA, {name} | {a:.3f} | {b:.3f} | {c:.3f} | {d:.3f} |")
    a, b = errors(baseline, rows)
    c, d = errors(baseline, seen)
    print(f"| baseline | {a:.3f} | {b:.3f} | {c:.3f} | {d:.3f} |")
    print(f"V2V-VLA names the labelled partner in {partner_accuracy(coop, seen):.1%} of the partner rows")


if __name__ == "__main__":
    main()
