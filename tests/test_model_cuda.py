"""V2V-VLA on a CUDA device (skipped where there is none, as on CI): a user who trains or drives on a GPU
must get the model the CPU gets. The checks run on a GPU machine by hand (docs/model.md, "On a GPU")."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

pytest.importorskip("torch")
pytest.importorskip("transformers")

import torch

from cmudrive.data.synthetic import write_synthetic_shards
from cmudrive.model import V2VVLA
from cmudrive.model.train import TrainConfig, train
from tests.model_rows import rows
from tests.test_model_modeling import tiny

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


def test_a_forward_pass_on_cuda_gives_the_cpus_outputs() -> None:
    """fp32 on both; cuDNN's TF32 convolutions (the patch embedding) allow ~1e-3 of difference."""
    cpu = tiny()
    gpu = copy.deepcopy(cpu).to("cuda")
    batch = cpu.processor(rows(4))
    with torch.no_grad():
        a, b = cpu(batch), gpu(batch.to("cuda"))
    for name in ("logits", "path", "speed_waypoints", "target_speed"):
        x, y = getattr(a, name), getattr(b, name).cpu()
        assert torch.allclose(x, y, atol=2e-3, rtol=1e-3), (name, float((x - y).abs().max()))
    assert abs(float(a.loss) - float(b.loss)) < 1e-3


def test_predict_on_cuda_gives_the_cpus_waypoints() -> None:
    cpu = tiny()
    gpu = copy.deepcopy(cpu).to("cuda")
    prompts = [{k: v for k, v in r.items() if k != "commentary"} for r in rows(3)]
    a, b = cpu.predict(prompts, max_new_tokens=0), gpu.predict(prompts, max_new_tokens=0)
    assert torch.allclose(a.path, b.path.cpu(), atol=2e-3)
    assert torch.allclose(a.speed_waypoints, b.speed_waypoints.cpu(), atol=2e-3)


def test_a_model_trained_on_cuda_in_bf16_loads_on_the_cpu(tmp_path: Path) -> None:
    """``cmudrive train`` on a GPU (mixed precision ``auto``: bf16 autocast, fp32 weights) saves a
    checkpoint that a CPU-only user loads and drives with: fp32 weights, the GPU's outputs."""
    data = tmp_path / "data"
    write_synthetic_shards(data, routes=3, rows_per_route=16, seed=0)
    out = tmp_path / "run"
    config = TrainConfig(data=str(data), out=str(out), batch_size=8, max_steps=6, save_every=6, log_every=1)
    train(config, progress=False)
    log = [json.loads(ln) for ln in (out / "metrics.jsonl").read_text().splitlines()]
    losses = [r["loss"] for r in log if r["split"] == "train"]
    assert len(losses) == 6 and all(torch.isfinite(torch.tensor(loss)) for loss in losses)
    on_cpu = V2VVLA.from_pretrained(out / "model").eval()
    on_gpu = V2VVLA.from_pretrained(out / "model", device="cuda").eval()
    assert all(p.dtype == torch.float32 and p.device.type == "cpu" for p in on_cpu.parameters())
    prompts = [{k: v for k, v in r.items() if k != "commentary"} for r in rows(2)]
    a, b = on_cpu.predict(prompts, max_new_tokens=0), on_gpu.predict(prompts, max_new_tokens=0)
    assert torch.isfinite(a.path).all()
    assert torch.allclose(a.path, b.path.cpu(), atol=2e-3)
