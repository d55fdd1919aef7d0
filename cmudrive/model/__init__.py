"""V2V-VLA, the cooperative vision-language-action model, and its non-cooperative SimLingo-style baseline.

``config`` and ``processor`` need no torch at import; ``V2VVLA`` (``modeling``) needs torch,
transformers and peft (the ``model`` extra) and is imported on first use. ``row`` is the row contract (a
CAV's observations and plan -> the model's input row, for data collection and closed loop alike) and
``agent`` the closed-loop agent (``cmudrive eval --agent v2v-vla``); neither imports torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from cmudrive.model.config import (
    NAMED_CONFIGS,
    LoraSettings,
    ModelConfig,
    TextConfig,
    VisionConfig,
    get_config,
)
from cmudrive.model.processor import VLABatch, VLAProcessor, parse_partner
from cmudrive.model.tokenizer import TINY_TOKENIZER_DIR, build_tiny_tokenizer, load_tokenizer

if TYPE_CHECKING:
    from cmudrive.model.modeling import V2VVLA, VLAOutput, VLAPrediction

_MODELING = ("V2VVLA", "VLAOutput", "VLAPrediction")


def __getattr__(name: str) -> Any:
    if name in _MODELING:
        from cmudrive.model import modeling

        return getattr(modeling, name)
    raise AttributeError(f"module 'cmudrive.model' has no attribute {name!r}")


__all__ = [
    "NAMED_CONFIGS",
    "TINY_TOKENIZER_DIR",
    "V2VVLA",
    "LoraSettings",
    "ModelConfig",
    "TextConfig",
    "VLABatch",
    "VLAOutput",
    "VLAPrediction",
    "VLAProcessor",
    "VisionConfig",
    "build_tiny_tokenizer",
    "get_config",
    "load_tokenizer",
    "parse_partner",
]
