"""Training V2V-VLA (``cmudrive train``): Parquet shards in, checkpoints, metrics and TensorBoard logs out.

The same code runs on a CPU, one GPU or several (``accelerate launch cmudrive train ...``): Hugging Face
``accelerate`` places the model, shards the batches and handles mixed precision; there is no distributed
code of our own. The recipe is SimLingo's (``reference/MODEL_AND_EXPERT.md``): AdamW (weight decay 0.1),
a one-cycle schedule with 5 % warm-up, gradient clipping at 0.3, fp16/bf16 on GPUs, camera-rotation
augmentation (:mod:`cmudrive.model.augment`). The learning rate defaults per configuration
(:data:`DEFAULT_LR`).

Output folder ``OUT``::

    OUT/train_config.json          the TrainConfig (a resume must match it)
    OUT/metrics.jsonl              one JSON line per logged step ({"split": "train"|"val", "step", ...})
    OUT/tensorboard/               the same scalars for TensorBoard
    OUT/checkpoints/step_000500/   accelerate state (model, optimizer, scheduler, RNG) + state.json
    OUT/model/                     the final weights (V2VVLA.save_pretrained), also in each checkpoint

Data: the rows :mod:`cmudrive.model.dataset` selects and reads (whole routes held out for validation,
standing rows thinned, rows drawn by situation with ``--bucket-power``), in the loader's workers when
there are any.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler

from cmudrive.model.augment import YawAugment
from cmudrive.model.config import ModelConfig, get_config
from cmudrive.model.dataset import BucketSampler, DrivingDataset, EpochSampler, load_split, sampling_buckets
from cmudrive.model.modeling import V2VVLA
from cmudrive.model.processor import VLABatch
from cmudrive.provenance import describe_diff, settings_diff

# SimLingo's 3e-5 is a fine-tuning rate for a pretrained 1B model (LoRA on the LLM). tiny and small start
# from random weights: 1e-3 is the usual rate for transformers of a few million parameters trained from
# scratch (nanoGPT's character-level model); 3e-4 for tens of millions (see docs/model.md, "Training").
DEFAULT_LR: dict[str, float] = {"tiny": 1e-3, "tiny-v1": 1e-3, "small": 3e-4, "internvl2-1b": 3e-5}
CHECKPOINTS = "checkpoints"
FINAL = "model"
STATE = "state.json"


@dataclass(frozen=True)
class TrainConfig:
    """One training run: ``epochs`` passes over the training routes, or ``max_steps`` optimizer steps when
    given (then as many epochs as that takes)."""

    data: str  # folder of <route>.parquet shards, or several separated by commas
    out: str  # output folder
    model: str = "tiny"  # named configuration (cmudrive.model.get_config)
    cooperative: bool = True  # False: the non-cooperative baseline (same data, size and budget)
    pretrained_path: str | None = None  # for internvl2-1b: the local InternVL checkpoint
    epochs: int = 1
    max_steps: int | None = None
    batch_size: int = 8  # per process
    lr: float | None = None  # None: DEFAULT_LR of the configuration
    weight_decay: float = 0.1
    warmup: float = 0.05  # [-] share of the steps spent warming up (one-cycle pct_start)
    grad_clip: float = 0.3  # max global gradient norm
    save_every: int = 500  # [steps] checkpoint interval (and one at the end)
    keep_checkpoints: int = 3  # the newest ones are kept
    log_every: int = 10  # [steps]
    val_fraction: float = 0.1  # [-] share of the routes held out
    # [-] share of the "standing" training rows kept (a CAV below 0.1 m/s that stays within 0.5 m over its
    # 2.5 s of speed waypoints): 47 % of the collected rows, against 4 % that stand and then start; a
    # model fed speed learns "standing stays standing" from that prior and never starts (docs/model.md)
    standing_keep: float = 1.0
    # [-] times each row with a communication sentence (a partner sees what the ego does not) appears per
    # epoch: 1.2 % of the collection, too few for the partner choice to be learnt at all (docs/model.md)
    communication_repeat: int = 1
    speed_input: bool = True  # the prompt states the CAV's speed (SimLingo); False: no speed anywhere
    speed_dropout: float = 0.0  # [-] share of training rows whose prompt leaves the speed out
    # [-] share of a cooperative model's training rows shown without what the other CAVs give (empty
    # merged image, no other CAVs, no partner): the camera alone must steer them (docs/model.md)
    cooperative_dropout: float = 0.0
    standing_input: bool = False  # the prompt states how long the CAV has stood (ModelConfig)
    # the cooperative model's path from the ego's own inputs only (ModelConfig.path_inputs="ego")
    ego_path: bool = False
    # a saved model folder (save_pretrained) whose weights start the run instead of fresh ones; its sizes
    # must be this configuration's (prompt settings may differ: fine-tuning with a new input)
    init_from: str | None = None
    # bucketed sampling (SimLingo's spirit): each epoch draws as many rows as there are training rows,
    # bucket b (starts, stands, stops, turns, follows, slows, cruises: sampling_buckets) getting a share
    # proportional to count_b ** bucket_power: 1.0 samples as collected (a plain permutation), 0.0 gives
    # every bucket the same share; None: a permutation of the rows, no buckets
    bucket_power: float | None = None
    val_batches: int = 50  # at most this many batches per validation
    seed: int = 0
    num_workers: int = 0  # DataLoader worker processes (image decoding, augmentation, tokenising)
    mixed_precision: str = "auto"  # auto (bf16 or fp16 on GPUs, none on CPU), no, fp16, bf16
    # torch.compile the language model in place (dynamic shapes: prompts vary in length); the weights'
    # names and the checkpoints stay the same (docs/model.md, "Throughput")
    compile: bool = False
    augment: YawAugment = field(default_factory=YawAugment)

    def __post_init__(self) -> None:
        if self.mixed_precision not in ("auto", "no", "fp16", "bf16"):
            raise ValueError(f"mixed_precision must be auto, no, fp16 or bf16, got {self.mixed_precision!r}")
        if not 0.0 <= self.val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in [0, 1), got {self.val_fraction}")
        if not 0.0 < self.standing_keep <= 1.0:
            raise ValueError(f"standing_keep must be in (0, 1], got {self.standing_keep}")
        if not 0.0 <= self.speed_dropout < 1.0:
            raise ValueError(f"speed_dropout must be in [0, 1), got {self.speed_dropout}")
        if not 0.0 <= self.cooperative_dropout < 1.0:
            raise ValueError(f"cooperative_dropout must be in [0, 1), got {self.cooperative_dropout}")
        if self.ego_path and not self.cooperative:
            raise ValueError("ego_path needs the cooperative model (the baseline sees only its own inputs)")
        if self.cooperative_dropout and not self.cooperative:
            raise ValueError("cooperative_dropout needs the cooperative model (no such inputs)")
        if self.bucket_power is not None and not 0.0 <= self.bucket_power <= 1.0:
            raise ValueError(f"bucket_power must be in [0, 1], got {self.bucket_power}")
        if self.speed_dropout and not self.speed_input:
            raise ValueError("speed_dropout needs speed_input (a model without speed has nothing to drop)")
        for name in (
            "epochs",
            "batch_size",
            "save_every",
            "log_every",
            "keep_checkpoints",
            "communication_repeat",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.max_steps is not None and self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")

    @property
    def learning_rate(self) -> float:
        return self.lr if self.lr is not None else DEFAULT_LR.get(self.model, 3e-5)

    def model_config(self) -> ModelConfig:
        extra: dict[str, Any] = {"pretrained_path": self.pretrained_path} if self.pretrained_path else {}
        if not self.speed_input:
            extra["speed_in_prompt"] = False
        if self.standing_input:
            extra["standing_in_prompt"] = True
        if self.ego_path:
            extra["path_inputs"] = "ego"
        return get_config(self.model, cooperative=self.cooperative, **extra)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        data = dict(data)
        data["augment"] = YawAugment(**data.get("augment", {}))
        return cls(**data)


# ---- training ---------------------------------------------------------------------------------------
@dataclass
class TrainState:
    """Where a run is: saved with every checkpoint (``state.json``)."""

    step: int = 0  # optimizer steps done
    epoch: int = 0  # current epoch
    batch_in_epoch: int = 0  # batches of the current epoch already consumed


def mixed_precision(choice: str) -> str:
    """``auto``: bf16 on GPUs that have it, else fp16 on GPUs; none on the CPU."""
    if choice != "auto":
        return choice
    if not torch.cuda.is_available():
        return "no"
    return "bf16" if torch.cuda.is_bf16_supported() else "fp16"


def latest_checkpoint(out: Path) -> Path | None:
    found = sorted((out / CHECKPOINTS).glob("step_*"), key=lambda p: int(p.name.split("_")[1]))
    done = [p for p in found if (p / STATE).is_file()]
    return done[-1] if done else None


def init_weights(model: V2VVLA, source: Path) -> None:
    """Load the weights of the saved model folder ``source`` into ``model`` (every tensor, same shapes).

    A cooperative model may start from a baseline's weights (the same tensors: the baseline only leaves
    the occupancy tile, the other CAVs and the communication sentence out of its rows), a warm start that
    keeps what the camera-only model learnt; a baseline never starts from a cooperative model's weights,
    which would carry cooperative training into the model it is compared against."""
    try:
        saved = V2VVLA.from_pretrained(source)
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"--init-from {source}: not a V2VVLA.save_pretrained folder ({exc})") from exc
    if saved.config.cooperative and not model.config.cooperative:
        raise ValueError(
            f"--init-from {source}: a cooperative model; the baseline starts from a baseline's weights"
        )
    try:
        model.load_state_dict(saved.state_dict())
    except RuntimeError as exc:
        raise ValueError(f"--init-from {source}: its weights do not fit this configuration: {exc}") from exc


def _accelerator(precision: str) -> Any:
    """accelerate keeps one precision per process: a run in a process that trained before with another
    (an ablation script, a notebook, the tests; on a GPU ``auto`` is bf16) clears it first instead of
    failing with "AcceleratorState has already been initialized". Never under a distributed launch."""
    from accelerate import Accelerator
    from accelerate.state import AcceleratorState, PartialState

    state = AcceleratorState._shared_state
    if state and state.get("_mixed_precision") != precision and PartialState().num_processes == 1:
        AcceleratorState._reset_state()
    return Accelerator(mixed_precision=precision)


def train(config: TrainConfig, resume: bool = False, progress: bool = True) -> dict[str, float]:
    """Run (or continue) a training run; returns the last validation metrics (empty without validation)."""
    return Trainer(config, resume, progress).run()


class Trainer:
    """One run: ``__init__`` builds data, model, optimizer and schedule (and loads the checkpoint to resume
    from), ``run`` steps until ``total`` optimizer steps, logging and checkpointing as it goes."""

    def __init__(self, config: TrainConfig, resume: bool, progress: bool) -> None:
        from accelerate.utils import set_seed

        self.config, self.out, self.progress = config, Path(config.out), progress
        train_rows, val_rows, val_routes = load_split(config)
        if len(train_rows) == 0:
            raise ValueError(f"{config.data}: no training rows after holding out routes {val_routes}")
        _check_out(config, self.out, resume)
        self.accelerator = acc = _accelerator(mixed_precision(config.mixed_precision))
        set_seed(config.seed)
        model = V2VVLA.from_config(config.model_config())
        if config.init_from is not None:
            init_weights(model, Path(config.init_from))
        if config.compile:
            model.backbone.model.language_model.compile(dynamic=True)
        self.train_set = DrivingDataset(
            train_rows, config.augment, config.seed, config.speed_dropout, config.cooperative_dropout
        )
        self.sampler: EpochSampler | BucketSampler = (
            EpochSampler(len(self.train_set), config.seed)
            if config.bucket_power is None
            else BucketSampler(sampling_buckets(train_rows), config.seed, config.bucket_power)
        )
        # the loader first: its prepared length is the per-process batches of an epoch
        self.loader = acc.prepare(_loader(self.train_set, self.sampler, model, config))
        val = DrivingDataset(val_rows)
        self.val_loader = (
            acc.prepare(_loader(val, EpochSampler(len(val), 0, shuffle=False), model, config))
            if len(val)
            else None
        )
        self.total = config.max_steps if config.max_steps is not None else len(self.loader) * config.epochs
        params = [p for p in model.parameters() if p.requires_grad]
        optimizer = torch.optim.AdamW(params, lr=config.learning_rate, weight_decay=config.weight_decay)
        scheduler = torch.optim.lr_scheduler.OneCycleLR(
            optimizer,
            max_lr=config.learning_rate,
            # accelerate steps a prepared scheduler once per process per optimizer step: count in those
            total_steps=self.total * acc.num_processes,
            pct_start=config.warmup,
            anneal_strategy="cos",
            cycle_momentum=False,
        )
        self.model, self.optimizer, self.scheduler = acc.prepare(model, optimizer, scheduler)
        self.state = TrainState()
        last = latest_checkpoint(self.out) if resume else None
        if last is not None:
            self.state = _load_checkpoint(acc, last)
            acc.print(f"resuming from {last} (step {self.state.step})")
        self.metrics = _MetricsLog(self.out, self.state.step, acc.is_main_process)
        if acc.is_main_process:
            (self.out / "train_config.json").write_text(json.dumps(config.to_dict(), indent=2) + "\n")
        info = {"val_routes": val_routes, "total_steps": self.total, "train_rows": len(self.train_set)}
        info |= {"val_rows": len(val), "lr": config.learning_rate, "mixed_precision": acc.mixed_precision}
        self.metrics.write({"split": "info", "step": self.state.step, **info})

    def run(self) -> dict[str, float]:
        from tqdm.auto import tqdm

        acc, state = self.accelerator, self.state
        show = self.progress and acc.is_main_process
        self.bar = tqdm(total=self.total, initial=state.step, disable=not show, desc="train", unit="step")
        self.val_metrics: dict[str, float] = {}
        self.window: list[dict[str, float]] = []
        self.tick = time.perf_counter()
        self.model.train()
        while state.step < self.total:
            for batch in self._epoch():
                logs = _step(self.model, batch, self.optimizer, self.scheduler, acc, self.config.grad_clip)
                self._after_step(logs, len(batch) * acc.num_processes)
                if state.step >= self.total:
                    break
            else:
                state.epoch += 1
                state.batch_in_epoch = 0
        self.bar.close()
        acc.wait_for_everyone()
        if acc.is_main_process:
            acc.unwrap_model(self.model).save_pretrained(self.out / FINAL)
        self.metrics.close()
        acc.end_training()
        return self.val_metrics

    def _epoch(self) -> Any:
        """The batches of the current epoch still to run (all of them, or those after a resume point)."""
        epoch, done = self.state.epoch, self.state.batch_in_epoch
        self.loader.set_epoch(epoch)  # accelerate's epoch counter; it passes it to the sampler
        self.sampler.set_epoch(epoch)
        self.train_set.set_epoch(epoch)
        return self.accelerator.skip_first_batches(self.loader, done) if done else self.loader

    def _after_step(self, logs: dict[str, float], samples: int) -> None:
        """Count the step; log every ``log_every`` steps; validate and checkpoint every ``save_every``."""
        state, config = self.state, self.config
        state.step += 1
        state.batch_in_epoch += 1
        self.window.append({**logs, "samples": samples})
        self.bar.update(1)
        last = state.step == self.total
        if state.step % config.log_every == 0 or last:
            now = time.perf_counter()
            row = _summarise(self.window, now - self.tick)
            self.metrics.write({**row, "split": "train", "step": state.step, "epoch": state.epoch})
            self.bar.set_postfix(loss=f"{row['loss']:.3f}")
            self.window, self.tick = [], now
        if state.step % config.save_every == 0 or last:
            if self.val_loader is not None:
                self.val_metrics = evaluate(self.model, self.val_loader, self.accelerator, config.val_batches)
                self.metrics.write({"split": "val", "step": state.step, **self.val_metrics})
            _save(self.accelerator, self.model, self.out, state, config.keep_checkpoints)
            self.tick = time.perf_counter()  # checkpoints and validation are not training speed


RESUME_MAY_CHANGE = ("num_workers", "log_every", "compile")  # settings that do not change what is trained


def _load_checkpoint(accelerator: Any, path: Path) -> TrainState:
    """Load the accelerate state of checkpoint ``path`` and its ``state.json``. torch's safe loader
    (``weights_only``) refuses a file that pickles anything beyond tensors and plain containers, and
    nothing in the folder is trusted further: each refusal or unreadable file is a ``ValueError`` that
    names the checkpoint, not a traceback."""
    import pickle

    try:
        accelerator.load_state(str(path))
    except pickle.UnpicklingError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ValueError(
            f"{path}: --resume refused this checkpoint: a file in it holds pickled objects that torch's "
            f"safe loader does not load ({first}); it was not written by cmudrive train, or was altered. "
            "Delete the folder to resume from an earlier checkpoint."
        ) from None
    except (OSError, RuntimeError, KeyError, EOFError, ValueError) as exc:
        raise ValueError(
            f"{path}: --resume cannot load this checkpoint ({type(exc).__name__}: {exc})"
        ) from None
    try:
        state = TrainState(**json.loads((path / STATE).read_text()))
    except (OSError, ValueError, TypeError, RecursionError) as exc:
        raise ValueError(f"{path / STATE}: not a training state ({exc})") from None
    values = dataclasses.astuple(state)
    if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in values):
        raise ValueError(f"{path / STATE}: step, epoch and batch_in_epoch must be counts, got {values}")
    return state


def _check_out(config: TrainConfig, out: Path, resume: bool) -> None:
    saved = out / "train_config.json"
    if resume and saved.is_file():
        then = json.loads(saved.read_text())
        # a setting added since the run began: the run used its default
        for f in dataclasses.fields(TrainConfig):
            if f.name not in then and f.default is not dataclasses.MISSING:
                then[f.name] = f.default
        diff = settings_diff(then, config.to_dict(), ignore=RESUME_MAY_CHANGE)
        if diff:
            raise ValueError(f"{out}: --resume with a different configuration:\n{describe_diff(diff)}")
    elif not resume and (out / CHECKPOINTS).exists():
        raise FileExistsError(f"{out} already holds a run: continue it with --resume or pick another --out")
    out.mkdir(parents=True, exist_ok=True)


def _loader(dataset: Dataset, sampler: Sampler[int], model: V2VVLA, config: TrainConfig) -> DataLoader:
    return DataLoader(
        dataset,
        batch_size=config.batch_size,
        sampler=sampler,
        collate_fn=model.processor,
        num_workers=config.num_workers,
        persistent_workers=False,  # a fresh worker copy per epoch sees the epoch set on the dataset
        pin_memory=torch.cuda.is_available(),
    )


def _step(
    model: Any, batch: VLABatch, optimizer: Any, scheduler: Any, accelerator: Any, clip: float
) -> dict[str, float]:
    lr = float(optimizer.param_groups[0]["lr"])  # the rate this step uses
    out = model(batch)
    accelerator.backward(out.loss)
    norm = accelerator.clip_grad_norm_(model.parameters(), clip)
    optimizer.step()
    scheduler.step()
    optimizer.zero_grad(set_to_none=True)
    return {
        "loss": float(out.loss.detach()),
        "lm_loss": float(out.lm_loss.detach()),
        "waypoint_loss": float(out.waypoint_loss.detach()),
        "speed_loss": float(out.speed_loss.detach()),
        "grad_norm": float(norm),
        "lr": lr,
    }


@torch.no_grad()
def evaluate(model: Any, loader: DataLoader, accelerator: Any, max_batches: int) -> dict[str, float]:
    """Mean losses and the mean path / speed-waypoint errors [m] (L2 per point) on held-out routes; with
    a speed query also the mean target-speed error [m/s] and the share of rows whose go/stop (stop
    probability above 0.5) is the expert's."""
    was = model.training
    model.eval()
    sums: dict[str, float] = {}
    count = 0
    for i, batch in enumerate(loader):
        if i >= max_batches:
            break
        out = model(batch)
        metrics = {
            "loss": out.loss,
            "lm_loss": out.lm_loss,
            "waypoint_loss": out.waypoint_loss,
            "path_l2_m": (out.path - batch.path).norm(dim=-1).mean(),
            "speed_l2_m": (out.speed_waypoints - batch.speed_waypoints).norm(dim=-1).mean(),
        }
        if out.target_speed is not None and out.stop_logit is not None:
            metrics["speed_loss"] = out.speed_loss
            metrics["target_speed_err_mps"] = (out.target_speed - batch.target_speed).abs().mean()
            metrics["go_stop_agree"] = ((out.stop_logit > 0).float() == batch.stop).float().mean()
        values = torch.stack([v.float() for v in metrics.values()])
        gathered = accelerator.gather_for_metrics(values[None]).mean(0)
        for k, v in zip(metrics, gathered.tolist(), strict=True):
            sums[k] = sums.get(k, 0.0) + v
        count += 1
    model.train(was)
    return {k: v / max(count, 1) for k, v in sums.items()}


def _summarise(window: list[dict[str, float]], seconds: float) -> dict[str, Any]:
    """Means over the steps since the last log line; ``lr`` of the last step."""
    keys = ("loss", "lm_loss", "waypoint_loss", "speed_loss", "grad_norm")
    row: dict[str, Any] = {k: float(np.mean([w[k] for w in window])) for k in keys}
    row["lr"] = window[-1]["lr"]
    row["samples_per_s"] = sum(w["samples"] for w in window) / max(seconds, 1e-9)
    return row


def _save(accelerator: Any, model: Any, out: Path, state: TrainState, keep: int) -> None:
    path = out / CHECKPOINTS / f"step_{state.step:06d}"
    quiet = logging.getLogger("accelerate.utils.other")  # "removed shared tensor": the tied LM head,
    level = quiet.level  # which safetensors stores once and load_state ties again (tested by resuming)
    quiet.setLevel(logging.ERROR)
    try:
        accelerator.save_state(str(path))
    finally:
        quiet.setLevel(level)
    if accelerator.is_main_process:
        accelerator.unwrap_model(model).save_pretrained(path / FINAL)
        (path / STATE).write_text(json.dumps(dataclasses.asdict(state)) + "\n")  # last: marks it complete
        done = sorted((out / CHECKPOINTS).glob("step_*"), key=lambda p: int(p.name.split("_")[1]))
        for old in done[:-keep]:
            shutil.rmtree(old, ignore_errors=True)
    accelerator.wait_for_everyone()


class _MetricsLog:
    """``OUT/metrics.jsonl`` and the same scalars in ``OUT/tensorboard``, on the main process only; the
    lines and events past ``resume_step`` (from an interrupted run) are dropped."""

    def __init__(self, out: Path, resume_step: int, enabled: bool) -> None:
        from torch.utils.tensorboard import SummaryWriter

        self.path, self.enabled = out / "metrics.jsonl", enabled
        self.writer = SummaryWriter(str(out / "tensorboard"), purge_step=resume_step) if enabled else None
        if enabled and self.path.is_file():
            lines = [ln for ln in self.path.read_text().splitlines() if ln]
            kept = [ln for ln in lines if json.loads(ln)["step"] <= resume_step]
            self.path.write_text("".join(ln + "\n" for ln in kept))

    def write(self, row: dict[str, Any]) -> None:
        if not self.enabled:
            return
        with self.path.open("a") as f:
            f.write(json.dumps(row) + "\n")
        if self.writer is not None:
            for key, value in row.items():
                if isinstance(value, float):
                    self.writer.add_scalar(f"{row['split']}/{key}", value, row["step"])

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
