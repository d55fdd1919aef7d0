"""V2V-VLA sizes and CPU speed: parameter counts per configuration, the size of a tiny checkpoint, tiny
training throughput and tiny closed-loop inference latency.

    python benchmarks/model_speed.py [--threads 1] [--repeats 5] [--tokens 32]

Counts: ``tiny``, ``small`` (cooperative and baseline) and the InternVL2-1B architecture (InternViT-300M
+ projector + Qwen2-0.5B, vocabulary 151,655 + <TARGET_POINT>, LoRA r 32), the last built on the meta
device from its published sizes, so no weights are needed. Timed (median of ``--repeats``, after one
warm-up): ``tiny`` forward + backward + AdamW step at batch 8 (samples/s), and ``tiny`` ``predict`` for
16 CAVs (one tick): waypoints only (``max_new_tokens=0``) and with ``--tokens`` generated tokens (a random
model never ends its sentence, so this is the cost of an answer that long). Budget for the closed loop:
16 CAVs at 20 ticks/s = 50 ms per tick for all 16.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from transformers import InternVLConfig, InternVLForConditionalGeneration, InternVLVisionConfig, Qwen2Config

from cmudrive.model import V2VVLA, get_config, load_tokenizer


def row(i: int, rng: np.random.Generator) -> dict:
    return {
        "camera": Image.fromarray(rng.integers(0, 256, (128, 256, 3), dtype=np.uint8)),
        "merged_bev": Image.fromarray(rng.integers(0, 256, (192, 128, 3), dtype=np.uint8)),
        "speed": 5.0,
        "target_points": [[15.0, 0.0], [40.0, 2.0]],
        "other_cavs": [[k, 10.0 * k, 3.0, 0.0] for k in range(1, 6)],
        "path": np.stack([np.arange(20.0), np.zeros(20)], 1),
        "speed_waypoints": np.stack([np.arange(1, 11) * 1.25, np.zeros(10)], 1),
        "commentary": "Follow the route. Maintain the current speed.",
        "communication": "CAV 2 can see the pedestrian." if i % 2 else "",
        "partner_label": 2 if i % 2 else -1,
    }


def internvl2_1b_counts() -> dict[str, int]:
    """Parameter counts of the paper-size model, on the meta device (published InternVL2-1B sizes)."""
    tokenizer = load_tokenizer()  # only its special-token ids are read; the vocabulary size is set below
    vision = InternVLVisionConfig(
        hidden_size=1024, num_hidden_layers=24, num_attention_heads=16, intermediate_size=4096,
        image_size=448, patch_size=14, attention_bias=True,
    )  # fmt: skip
    text = Qwen2Config(
        vocab_size=151655 + 1, hidden_size=896, intermediate_size=4864, num_hidden_layers=24,
        num_attention_heads=14, num_key_value_heads=2,
    )  # fmt: skip
    hf = InternVLConfig(  # InternVL2-1B keeps a separate LM head (its published 0.94 B parameters)
        vision_config=vision,
        text_config=text,
        image_token_id=4,
        image_seq_length=256,
        tie_word_embeddings=False,
    )
    with torch.device("meta"):
        backbone = InternVLForConditionalGeneration(hf)
        model = V2VVLA(get_config("internvl2-1b", pretrained_path="(meta)"), backbone, tokenizer)
    return model.parameter_counts()


def timed(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--tokens", type=int, default=32)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    rng = np.random.default_rng(0)

    print(
        "parameters (M): total / trainable / vision / projector / LLM base / LM head / LoRA / driving heads"
    )
    for name, overrides in [("tiny", {}), ("tiny", {"cooperative": False}), ("small", {})]:
        counts = V2VVLA.from_config(get_config(name, **overrides)).parameter_counts()
        _print_counts(name + (" baseline" if overrides else ""), counts)
    _print_counts("internvl2-1b", internvl2_1b_counts())

    model = V2VVLA.from_config(get_config("tiny"))
    with tempfile.TemporaryDirectory() as tmp:
        model.save_pretrained(tmp)
        size = sum(f.stat().st_size for f in Path(tmp).rglob("*") if f.is_file())
        weights = (Path(tmp) / "model.safetensors").stat().st_size
    print(f"tiny checkpoint: {size / 1e6:.1f} MB on disk ({weights / 1e6:.1f} MB model.safetensors)")

    model.train()
    batch = model.processor([row(i, rng) for i in range(8)])
    optimizer = torch.optim.AdamW([p for p in model.parameters() if p.requires_grad], lr=1e-4)

    def train_step() -> None:
        out = model(batch)
        assert out.loss is not None
        optimizer.zero_grad()
        out.loss.backward()
        optimizer.step()

    step = timed(train_step, args.repeats)
    print(f"tiny train step, batch 8, {batch.input_ids.shape[1]} tokens + 30 queries per row: "
          f"{step * 1e3:.0f} ms = {8 / step:.1f} samples/s ({args.threads} threads)")  # fmt: skip

    model.eval()
    tick = [{k: v for k, v in row(i, rng).items() if k != "commentary"} for i in range(16)]
    processed = timed(lambda: model.processor(tick), args.repeats)
    prompt = model.processor(tick)
    waypoints_only = timed(lambda: model.predict(prompt, max_new_tokens=0), args.repeats)
    with_text = timed(lambda: model.predict(prompt, max_new_tokens=args.tokens), args.repeats)
    print(
        f"tiny predict, 16 CAVs: processor {processed * 1e3:.0f} ms, waypoints only "
        f"{waypoints_only * 1e3:.0f} ms, with {args.tokens} tokens of text {with_text * 1e3:.0f} ms "
        "(budget 50 ms per tick)"
    )


def _print_counts(name: str, c: dict[str, int]) -> None:
    keys = ("total", "trainable", "vision", "projector", "language_model", "lm_head", "lora", "driving_heads")
    print(f"  {name:16s} " + " / ".join(f"{c[k] / 1e6:.2f}" for k in keys))


if __name__ == "__main__":
    main()
