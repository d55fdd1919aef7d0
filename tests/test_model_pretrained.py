"""The ``internvl2-1b`` code path (``from_pretrained`` of a local Hugging Face InternVL directory),
exercised with a small checkpoint this test saves in that format first: config.json + safetensors +
tokenizer files. Nothing is downloaded."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

pytest.importorskip("torch", reason="the model needs the 'model' extra (torch, transformers, peft)")
pytest.importorskip("transformers", reason="the model needs the 'model' extra (torch, transformers, peft)")
pytest.importorskip("peft", reason="the model needs the 'model' extra (torch, transformers, peft)")

import torch
from transformers import InternVLForConditionalGeneration

from cmudrive.model import V2VVLA, build_tiny_tokenizer, get_config
from cmudrive.model.backbone import backbone_config
from tests.model_rows import rows

torch.set_num_threads(1)
CHAT = (
    "{% for m in messages %}<|user|>{{ m['content'] }}\n{% endfor %}"
    "{% if add_generation_prompt %}<|assistant|>{% endif %}"
)


def save_small_internvl(directory: Path) -> InternVLForConditionalGeneration:
    """A 2-layer InternVL backbone whose vocabulary lacks the tokenizer's last two ids (as InternVL2-1B's
    lacks <TARGET_POINT>), saved like a Hugging Face checkpoint with a chat-template tokenizer."""
    tok = build_tiny_tokenizer()
    tok.chat_template = CHAT
    cfg = backbone_config(get_config("tiny", text={"num_layers": 2}, vision={"num_layers": 2}), tok)
    cfg.text_config.vocab_size = len(tok) - 2
    torch.manual_seed(1)
    base = InternVLForConditionalGeneration(cfg)
    base.save_pretrained(str(directory))
    tok.save_pretrained(str(directory))
    return base


def test_internvl2_1b_config_loads_a_local_checkpoint_and_round_trips(tmp_path: Path) -> None:
    base_dir = tmp_path / "InternVL-small-hf"
    base = save_small_internvl(base_dir)
    assert (base_dir / "config.json").exists() and (base_dir / "model.safetensors").exists()
    model = V2VVLA.from_config(get_config("internvl2-1b", pretrained_path=str(base_dir))).eval()

    # the weights are the checkpoint's; the vocabulary grew to the tokenizer's; LoRA r 32 on the LLM
    for name, p in base.model.vision_tower.named_parameters():
        assert torch.equal(p, model.backbone.model.vision_tower.get_parameter(name))
    q_proj = model.backbone.model.language_model.layers[1].self_attn.q_proj
    assert torch.equal(q_proj.base_layer.weight, base.model.language_model.layers[1].self_attn.q_proj.weight)
    assert q_proj.lora_A["default"].weight.shape[0] == 32 and q_proj.lora_dropout["default"].p == 0.1
    embeddings = model.backbone.get_input_embeddings().weight
    assert embeddings.shape[0] == len(model.tokenizer)
    assert torch.equal(embeddings[: len(model.tokenizer) - 2], base.get_input_embeddings().weight)
    counts = model.parameter_counts()
    assert counts["lm_head"] == 0  # tied to the (frozen) token embeddings, counted with the LLM
    assert counts["trainable"] == counts["total"] - counts["language_model"]  # frozen LLM base (+ embeddings)

    # geometry from the checkpoint's config.json; the prompt goes through its chat template
    assert model.processor.tokens_per_image == 16 and model.processor.image_size == 64
    batch = model.processor(rows(2))
    prompt = model.tokenizer.decode(batch.input_ids[0], skip_special_tokens=True)
    assert prompt.startswith("<|user|>") and prompt.endswith("next?\n<|assistant|>")
    assert batch.answer_ids is not None
    answer = model.tokenizer.decode(batch.answer_ids[0], skip_special_tokens=True)
    assert answer.startswith("Follow the route.")  # no leading space after the chat template
    out = model(batch)
    assert out.loss is not None and torch.isfinite(out.loss)

    # the saved model is self-contained: it loads with the base directory gone
    model.save_pretrained(tmp_path / "v2v-vla")
    shutil.rmtree(base_dir)
    loaded = V2VVLA.from_pretrained(tmp_path / "v2v-vla").eval()
    assert torch.equal(loaded(batch).path, out.path)  # type: ignore[arg-type]
    prompts = [{k: v for k, v in r.items() if k != "commentary"} for r in rows(2)]
    assert loaded.predict(prompts, 3).text == model.predict(prompts, 3).text
