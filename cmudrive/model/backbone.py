"""The backbone of V2V-VLA: ``transformers.InternVLForConditionalGeneration`` (InternViT vision tower,
pixel-shuffle + ``InternVLMultiModalProjector``, ``Qwen2Model`` language model, LM head), randomly
initialised from a :class:`~cmudrive.model.config.ModelConfig`'s sizes or read with ``from_pretrained``
from a local directory (a refused size mismatch names each field), with peft LoRA on the language model's
linear layers."""

from __future__ import annotations

from typing import Any, cast

import torch
from transformers import (
    InternVLConfig,
    InternVLForConditionalGeneration,
    InternVLVisionConfig,
    PreTrainedTokenizerBase,
    Qwen2Config,
)

from cmudrive.model.config import ModelConfig
from cmudrive.model.tokenizer import IMG_CONTEXT


def backbone_config(config: ModelConfig, tokenizer: PreTrainedTokenizerBase) -> InternVLConfig:
    """The InternVL config of a randomly initialised backbone of ``config``'s sizes."""
    assert config.vision is not None and config.text is not None
    v, t = config.vision, config.text
    vision = InternVLVisionConfig(
        hidden_size=v.hidden_size,
        num_hidden_layers=v.num_layers,
        num_attention_heads=v.num_heads,
        intermediate_size=v.intermediate_size,
        image_size=v.image_size,
        patch_size=v.patch_size,
    )
    text = Qwen2Config(
        vocab_size=len(tokenizer),
        hidden_size=t.hidden_size,
        intermediate_size=t.intermediate_size,
        num_hidden_layers=t.num_layers,
        num_attention_heads=t.num_heads,
        num_key_value_heads=t.num_kv_heads,
        max_position_embeddings=t.max_position_embeddings,
        rope_parameters={"rope_type": "default", "rope_theta": t.rope_theta},
        pad_token_id=tokenizer.pad_token_id,
        eos_token_id=tokenizer.eos_token_id,
    )
    return InternVLConfig(
        vision_config=vision,
        text_config=text,
        image_token_id=token_id(tokenizer, IMG_CONTEXT),
        image_seq_length=(v.image_size // v.patch_size) ** 2 // 4,
        downsample_ratio=0.5,
    )


def size_mismatch(config: ModelConfig, backbone: InternVLConfig) -> str | None:
    """Where ``config``'s vision/text sizes differ from the backbone config the weights were saved with
    (``vision.hidden_size is 384, the backbone's 96``), or None. A config with ``pretrained_path`` takes
    its sizes from the backbone and has none to differ."""
    if config.vision is None or config.text is None:
        return None
    v, t = config.vision, config.text
    bv = cast(InternVLVisionConfig, backbone.vision_config)
    bt = cast(Qwen2Config, backbone.text_config)

    def side(value: Any) -> int:  # transformers keeps image/patch sizes as [h, w]
        return int(value[0]) if isinstance(value, list | tuple) else int(value)

    pairs = {
        "vision.hidden_size": (v.hidden_size, bv.hidden_size),
        "vision.num_layers": (v.num_layers, bv.num_hidden_layers),
        "vision.num_heads": (v.num_heads, bv.num_attention_heads),
        "vision.intermediate_size": (v.intermediate_size, bv.intermediate_size),
        "vision.image_size": (v.image_size, side(bv.image_size)),
        "vision.patch_size": (v.patch_size, side(bv.patch_size)),
        "text.hidden_size": (t.hidden_size, bt.hidden_size),
        "text.num_layers": (t.num_layers, bt.num_hidden_layers),
        "text.num_heads": (t.num_heads, bt.num_attention_heads),
        "text.num_kv_heads": (t.num_kv_heads, bt.num_key_value_heads),
        "text.intermediate_size": (t.intermediate_size, bt.intermediate_size),
        "text.max_position_embeddings": (t.max_position_embeddings, bt.max_position_embeddings),
    }
    wrong = [
        f"{name} is {ours}, the backbone's {theirs}"
        for name, (ours, theirs) in pairs.items()
        if ours != theirs
    ]
    return "; ".join(wrong) or None


def token_id(tokenizer: PreTrainedTokenizerBase, token: str) -> int:
    return int(tokenizer.get_vocab()[token])


def build_backbone(
    config: ModelConfig, tokenizer: PreTrainedTokenizerBase
) -> InternVLForConditionalGeneration:
    """Random backbone of the config's sizes, or the pretrained one in ``config.pretrained_path``."""
    if config.pretrained_path is None:
        backbone = InternVLForConditionalGeneration(backbone_config(config, tokenizer))
        backbone.set_attn_implementation(config.attn_implementation)
        return backbone
    backbone = InternVLForConditionalGeneration.from_pretrained(
        config.pretrained_path, dtype=torch.float32, attn_implementation=config.attn_implementation
    )
    if backbone.config.image_token_id != token_id(tokenizer, IMG_CONTEXT):
        raise ValueError(
            f"{config.pretrained_path}: the config's image_token_id is not the tokenizer's {IMG_CONTEXT}"
        )
    if len(tokenizer) > cast(Qwen2Config, backbone.config.text_config).vocab_size:  # <TARGET_POINT> added
        backbone.resize_token_embeddings(len(tokenizer))
    return backbone


def add_lora(config: ModelConfig, backbone: InternVLForConditionalGeneration) -> None:
    """LoRA adapters on the language model's linear layers (not the vision tower, not the LM head)."""
    if config.llm_training != "lora":
        return
    from peft import LoraConfig, inject_adapter_in_model  # imported here: 3-6 s, and tiny does not use it

    s = config.lora
    targets = s.target_modules if isinstance(s.target_modules, str) else list(s.target_modules)
    lora = LoraConfig(r=s.r, lora_alpha=s.alpha, lora_dropout=s.dropout, target_modules=targets)
    inject_adapter_in_model(lora, backbone.model.language_model)
