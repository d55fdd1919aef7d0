"""Training throughput of V2V-VLA ``tiny`` on the CPU, through the whole ``cmudrive train`` pipeline
(Parquet rows read and decoded, camera-rotation augmentation, processor, forward, backward, clipping,
AdamW, schedule, logging).

    python benchmarks/train.py [--data DIR] [--steps 30] [--warmup-steps 5] [--batch-size 8] [--threads 1]

Without ``--data`` it writes synthetic shards (``cmudrive.data.synthetic``: the schema's columns, images
of the camera's size, sentences of the commentary's kind) to a temp folder. The first ``--warmup-steps``
are not counted; the last line is ``samples_per_s=<value>`` over the counted steps.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

import torch

from cmudrive.data.synthetic import write_synthetic_shards
from cmudrive.model.train import TrainConfig, train


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=None, help="dataset folder (default: synthetic shards)")
    parser.add_argument("--config", default="tiny")
    parser.add_argument("--steps", type=int, default=30, help="timed steps")
    parser.add_argument("--warmup-steps", type=int, default=5, help="steps not timed")
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--workers", type=int, default=0, help="DataLoader workers")
    parser.add_argument("--baseline", action="store_true")
    parser.add_argument("--compile", action="store_true", help="torch.compile the language model")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data
        if data is None:
            data = Path(tmp) / "data"
            write_synthetic_shards(data, routes=4, rows_per_route=64, seed=0)
        total = args.warmup_steps + args.steps
        config = TrainConfig(
            data=str(data),
            out=str(Path(tmp) / "run"),
            model=args.config,
            cooperative=not args.baseline,
            max_steps=total,
            batch_size=args.batch_size,
            save_every=total,
            log_every=1,
            val_fraction=0.0,
            num_workers=args.workers,
            compile=args.compile,
        )
        load = os.getloadavg()
        train(config, progress=False)
        log = [json.loads(ln) for ln in (Path(tmp) / "run" / "metrics.jsonl").read_text().splitlines()]
    steps = [r for r in log if r["split"] == "train" and r["step"] > args.warmup_steps]
    seconds = sum(args.batch_size / r["samples_per_s"] for r in steps)
    rate = len(steps) * args.batch_size / seconds
    ms = sorted(1e3 * args.batch_size / r["samples_per_s"] for r in steps)
    print(
        f"{args.config}{' baseline' if args.baseline else ''}: {len(steps)} steps of {args.batch_size} rows, "
        f"median {ms[len(ms) // 2]:.0f} ms per step (min {ms[0]:.0f}, max {ms[-1]:.0f}); "
        f"{args.threads} torch threads, {args.workers} loader workers"
        f"{', compiled' if args.compile else ''}; load average before "
        f"{load[0]:.2f}, after {os.getloadavg()[0]:.2f}"
    )
    print(f"samples_per_s={rate:.2f}")


if __name__ == "__main__":
    main()
