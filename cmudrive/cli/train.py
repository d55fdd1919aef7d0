"""``cmudrive train``: V2V-VLA (or its baseline) on a dataset folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cmudrive.cli.common import (
    console,
    fail,
)


def train_model(
    data: Annotated[
        str,
        typer.Option(
            help="dataset folder of <route>.parquet shards (data collect), or several separated by commas "
            "(an expert collection and closed-loop ones on the same routes; docs/model.md, 'DAgger')"
        ),
    ],
    out: Annotated[Path, typer.Option(help="run folder: checkpoints, metrics.jsonl, tensorboard/, model/")],
    config: Annotated[str, typer.Option(help="model configuration: tiny, small, internvl2-1b")] = "tiny",
    baseline: Annotated[
        bool, typer.Option(help="train the non-cooperative baseline (same data, size and budget)")
    ] = False,
    pretrained_path: Annotated[
        Path | None, typer.Option(help="local InternVL checkpoint directory (internvl2-1b)")
    ] = None,
    resume: Annotated[bool, typer.Option(help="continue from OUT's last checkpoint")] = False,
    epochs: Annotated[int, typer.Option(min=1, help="passes over the training routes")] = 1,
    max_steps: Annotated[
        int | None, typer.Option(min=1, help="optimizer steps (instead of --epochs)")
    ] = None,
    batch_size: Annotated[int, typer.Option(min=1, help="rows per step and process")] = 8,
    lr: Annotated[
        float | None, typer.Option(help="peak learning rate (default: tiny 1e-3, internvl2-1b 3e-5)")
    ] = None,
    save_every: Annotated[int, typer.Option(min=1, help="checkpoint every N steps (and at the end)")] = 500,
    log_every: Annotated[int, typer.Option(min=1, help="a metrics line every N steps")] = 10,
    val_fraction: Annotated[float, typer.Option(help="share of the routes held out for validation")] = 0.1,
    standing_keep: Annotated[
        float,
        typer.Option(
            help="share of the standing rows kept (below 0.1 m/s and still there 2.5 s later; 47 % of "
            "the collection); fewer teach a model fed its speed to start again"
        ),
    ] = 1.0,
    communication_repeat: Annotated[
        int,
        typer.Option(
            min=1,
            help="times each row with a communication sentence (1.2 % of the collection) is seen per epoch",
        ),
    ] = 1,
    speed_input: Annotated[
        bool, typer.Option(help="the prompt states the CAV's speed (SimLingo); --no-speed-input: never")
    ] = True,
    standing_input: Annotated[
        bool,
        typer.Option(help='the prompt says how long the CAV stood ("Stopped for 2.5 s.", docs/model.md)'),
    ] = False,
    ego_path: Annotated[
        bool,
        typer.Option(
            help="V2V-VLA's path from the ego's own inputs only; the merged image and the other CAVs reach "
            "its speed and language (docs/model.md)"
        ),
    ] = False,
    init_from: Annotated[
        Path | None,
        typer.Option(
            help="start from the weights of this model folder (a run's model/; same configuration sizes; "
            "V2V-VLA may start from a baseline's) instead of fresh ones: fine-tuning"
        ),
    ] = None,
    speed_dropout: Annotated[
        float, typer.Option(help="share of training rows whose prompt leaves the speed out")
    ] = 0.0,
    cooperative_dropout: Annotated[
        float,
        typer.Option(
            help="share of V2V-VLA's training rows shown without the other CAVs and the merged image "
            "(the camera alone steers them)"
        ),
    ] = 0.0,
    bucket_power: Annotated[
        float | None,
        typer.Option(
            help="bucketed sampling: bucket shares (starts, stands, stops, turns, follows, slows, cruises) "
            "proportional to count ** P; 1 samples as collected, 0 equal shares (default: no buckets)"
        ),
    ] = None,
    threads: Annotated[
        int | None,
        typer.Option(
            min=1, help="torch threads of this process (default: torch's choice; 1 per process on a CPU)"
        ),
    ] = None,
    num_workers: Annotated[int, typer.Option(min=0, help="DataLoader worker processes")] = 0,
    compile: Annotated[
        bool, typer.Option(help="torch.compile the language model (~1 min to compile; docs/model.md)")
    ] = False,
    mixed_precision: Annotated[
        str, typer.Option(help="auto (bf16/fp16 on GPUs, none on CPU), no, fp16, bf16")
    ] = "auto",
    augment_prob: Annotated[
        float, typer.Option(help="share of training rows rotated by up to +-20 deg (0: off)")
    ] = 0.5,
    seed: Annotated[int, typer.Option(help="model initialisation, data order, augmentation, split")] = 0,
) -> None:
    """Train V2V-VLA (or --baseline) on a dataset folder; the same command on a CPU, one GPU or several
    (accelerate launch -m cmudrive.cli train ...)."""
    try:
        import torch

        from cmudrive.model.augment import YawAugment
        from cmudrive.model.train import TrainConfig, train
    except ImportError as exc:
        fail(ImportError(f"training needs the model extra (pip install -e '.[model]'): {exc}"))
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        cfg = TrainConfig(
            data=data,
            out=str(out),
            model=config,
            cooperative=not baseline,
            pretrained_path=str(pretrained_path) if pretrained_path else None,
            epochs=epochs,
            max_steps=max_steps,
            batch_size=batch_size,
            lr=lr,
            save_every=save_every,
            log_every=log_every,
            val_fraction=val_fraction,
            standing_keep=standing_keep,
            communication_repeat=communication_repeat,
            speed_input=speed_input,
            standing_input=standing_input,
            ego_path=ego_path,
            init_from=str(init_from) if init_from else None,
            speed_dropout=speed_dropout,
            cooperative_dropout=cooperative_dropout,
            bucket_power=bucket_power,
            num_workers=num_workers,
            compile=compile,
            mixed_precision=mixed_precision,
            augment=YawAugment(prob=augment_prob),
            seed=seed,
        )
        metrics = train(cfg, resume=resume)
    except (OSError, ValueError) as exc:
        fail(exc)
    shown = ", ".join(f"{k} {v:.3f}" for k, v in metrics.items())
    console.print(f"model: {out / 'model'}" + (f"; validation: {shown}" if shown else ""))
