"""Model configuration (named configs, unknown keys rejected) and the shipped tiny tokenizer."""

from __future__ import annotations

import importlib.util
import json

import pytest

from cmudrive.model.config import NAMED_CONFIGS, ModelConfig, get_config
from cmudrive.model.tokenizer import (
    IMG_CONTEXT,
    TARGET_POINT,
    TINY_TOKENIZER_DIR,
    build_tiny_tokenizer,
    load_tokenizer,
)

needs_transformers = pytest.mark.skipif(
    importlib.util.find_spec("transformers") is None,
    reason="the tokenizer needs the 'model' extra (torch, transformers, peft)",
)


def test_named_configs_and_overrides() -> None:
    assert set(NAMED_CONFIGS) == {"tiny", "tiny-v1", "small"}
    tiny = get_config("tiny")
    assert tiny.cooperative and tiny.n_images == 3
    baseline = get_config("tiny", cooperative=False)
    assert baseline.n_images == 2 and baseline.text == tiny.text
    assert get_config("tiny", text={"num_layers": 2}).text.num_layers == 2  # type: ignore[union-attr]


def test_the_committed_checkpoints_were_saved_with_named_configurations() -> None:
    """Retraining with --config tiny-v1 builds the first pair's architecture and inputs, --config tiny
    (the default) the defaults' (with their flags: --baseline, --no-speed-input, --ego-path)."""
    import json
    from pathlib import Path

    from cmudrive.model.config import ModelConfig

    models = Path(__file__).resolve().parents[1] / "cmudrive" / "assets" / "models"
    for name, config in (
        ("v2v-vla-tiny", "tiny-v1"),  # the first pair
        ("v2v-vla-tiny-no-speed", "tiny"),  # the defaults
        ("v2v-vla-baseline-tiny-no-speed", "tiny"),
    ):
        saved = ModelConfig.from_dict(json.loads((models / name / "vla_config.json").read_text())["config"])
        rebuilt = get_config(
            config,
            cooperative=saved.cooperative,
            speed_in_prompt=saved.speed_in_prompt,
            path_inputs=saved.path_inputs,  # --ego-path: the default V2V-VLA's
        ).replace(name=saved.name)
        assert rebuilt == saved, name


def test_unknown_keys_are_rejected() -> None:
    with pytest.raises(ValueError, match="unknown ModelConfig keys"):
        get_config("tiny", cooperate=True)
    with pytest.raises(ValueError, match="unknown TextConfig keys"):
        get_config("tiny", text={"layers": 2})
    with pytest.raises(ValueError, match="unknown model config"):
        get_config("huge")


def test_internvl2_1b_needs_a_local_checkpoint() -> None:
    with pytest.raises(ValueError, match="pretrained_path"):
        get_config("internvl2-1b")
    cfg = get_config("internvl2-1b", pretrained_path="/nowhere")
    assert cfg.vision is None and cfg.llm_training == "lora" and cfg.lora.r == 32 and cfg.lora.alpha == 64
    with pytest.raises(ValueError, match="vision/text must be None"):
        ModelConfig(pretrained_path="/nowhere")


def test_config_json_round_trip() -> None:
    cfg = get_config("small", cooperative=False, lora={"r": 8, "alpha": 16})
    again = ModelConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert again == cfg


@needs_transformers
def test_shipped_tiny_tokenizer_is_the_one_the_builder_makes() -> None:
    shipped, built = load_tokenizer(), build_tiny_tokenizer()
    assert shipped.get_vocab() == built.get_vocab()
    text = "Current speed: 12.3 m/s. Turn left. Communication: CAV 14 can see the ambulance. Zebra, naïve!"
    assert shipped(text)["input_ids"] == built(text)["input_ids"]
    assert shipped.decode(shipped(text)["input_ids"]) == text  # byte-level: unseen words round-trip
    assert (TINY_TOKENIZER_DIR / "tokenizer.json").stat().st_size < 100_000


@needs_transformers
def test_special_tokens_are_single_ids_and_digits_are_split() -> None:
    tok = load_tokenizer()
    ids = tok(f"{IMG_CONTEXT}{IMG_CONTEXT}{TARGET_POINT} 12.5", add_special_tokens=False)["input_ids"]
    pieces = tok.convert_ids_to_tokens(ids)
    assert pieces[:3] == [IMG_CONTEXT, IMG_CONTEXT, TARGET_POINT]
    assert [p for p in pieces[3:] if p.strip("Ġ")] == ["1", "2", ".", "5"]
    assert tok.padding_side == "left" and tok.pad_token_id != tok.eos_token_id
