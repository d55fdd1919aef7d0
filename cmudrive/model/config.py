"""Configuration of V2V-VLA: frozen dataclasses, named configurations, unknown keys rejected.

Importing this module needs no torch; :mod:`cmudrive.model.modeling` turns a :class:`ModelConfig` into a
model. Four named configurations (:func:`get_config`):

- ``tiny``: under a million parameters, random initialisation, trains on a 2-core CPU; 128 px tiles.
- ``tiny-v1``: ``tiny`` with the inputs of the checkpoints committed before (64 px tiles), to reproduce them.
- ``small``: tens of millions of parameters, random initialisation, 224 px tiles (a GPU run).
- ``internvl2-1b``: the paper's size; the backbone (InternViT-300M + MLP projector + Qwen2-0.5B) and its
  tokenizer are read with ``from_pretrained`` from ``pretrained_path``, a local directory in the Hugging
  Face ``InternVLForConditionalGeneration`` format. Nothing is downloaded.

``cooperative=False`` gives the non-cooperative baseline (SimLingo's inputs and outputs: camera only, no
merged occupancy image, no other CAVs in the prompt, no communication sentence), same size otherwise.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal, TypeVar

LlmTraining = Literal["lora", "full", "frozen"]


@dataclass(frozen=True)
class VisionConfig:
    """InternViT-style vision encoder (``transformers.InternVLVisionConfig``); one square tile in."""

    hidden_size: int = 128
    num_layers: int = 4
    num_heads: int = 4
    intermediate_size: int = 512
    image_size: int = 64  # [px] side of one square tile
    patch_size: int = 8  # [px]

    def __post_init__(self) -> None:
        if self.image_size % self.patch_size:
            raise ValueError(
                f"image_size {self.image_size} is not a multiple of patch_size {self.patch_size}"
            )
        if (self.image_size // self.patch_size) % 2:
            raise ValueError("the patch grid side must be even (pixel shuffle halves it)")
        if self.hidden_size % self.num_heads:
            raise ValueError("hidden_size must be a multiple of num_heads")


@dataclass(frozen=True)
class TextConfig:
    """Qwen2-style language model (``transformers.Qwen2Config``); the vocabulary comes from the tokenizer."""

    hidden_size: int = 192
    num_layers: int = 4
    num_heads: int = 6
    num_kv_heads: int = 2
    intermediate_size: int = 512
    max_position_embeddings: int = 1024
    rope_theta: float = 10000.0

    def __post_init__(self) -> None:
        if self.hidden_size % self.num_heads or self.num_heads % self.num_kv_heads:
            raise ValueError("hidden_size % num_heads and num_heads % num_kv_heads must be 0")


@dataclass(frozen=True)
class LoraSettings:
    """peft LoRA on the language model's linear layers (SimLingo: r 32, alpha 64, dropout 0.1, all linear)."""

    r: int = 32
    alpha: int = 64
    dropout: float = 0.1
    target_modules: str | tuple[str, ...] = "all-linear"  # peft's name for every nn.Linear of the LLM


@dataclass(frozen=True)
class ModelConfig:
    """Everything that defines a V2V-VLA model; saved next to its weights (``vla_config.json``).

    ``vision``/``text`` give the architecture of a randomly initialised backbone; they must be ``None``
    when ``pretrained_path`` is set (the checkpoint's own ``config.json`` then defines it)."""

    name: str = "tiny"
    cooperative: bool = True
    vision: VisionConfig | None = field(default_factory=VisionConfig)
    text: TextConfig | None = field(default_factory=TextConfig)
    pretrained_path: str | None = None  # local HF InternVL directory (weights + tokenizer)
    tokenizer_path: str | None = None  # None: the pretrained directory, else the shipped tiny tokenizer
    # How the language model is trained: "lora" (frozen base + peft adapters, the paper), "full" (all
    # weights; for randomly initialised backbones, where there is nothing to preserve) or "frozen".
    llm_training: LlmTraining = "lora"
    lora: LoraSettings = field(default_factory=LoraSettings)
    train_embeddings: bool = False  # token embeddings / tied LM head trainable when the LLM is not "full"
    attn_implementation: str = "sdpa"
    # Inputs
    camera_tiles: int = 2  # the front camera becomes this many square tiles side by side
    # fraction of the camera image cut off at the bottom: SimLingo's 4.8/16 removes CARLA's bonnet; our
    # renderer draws no bonnet, so tiny and small keep the whole image (0.0); the field's default stays
    # SimLingo's for checkpoints saved before the field changed
    bonnet_crop: float = 4.8 / 16
    # how the merged BEV render (W x H = 128 x 192 cells of 0.5 m, ego driving up) becomes one S x S tile:
    # "pad": resized keeping its aspect and centred on black (1.5 m per pixel at 64 px, a third black);
    # "stretch": the whole render resized to S x S, no padding (at 128 px: 0.5 m per pixel across, 0.75 m
    # along the driving direction)
    bev_fit: str = "pad"
    target_point_hidden: tuple[int, ...] = (256, 512)  # MLP 2 -> ... -> LLM hidden, ReLU
    target_point_scale: float = 10.0  # [m] target points are divided by this before the MLP
    # the prompt states the CAV's speed (SimLingo); False: the model sees no speed and must judge from its
    # images whether to go (a speed-fed model copies its speed: "standing stays standing", docs/model.md)
    speed_in_prompt: bool = True
    # the prompt states how long the CAV has stood ("Stopped for 2.5 s.", nothing while it moves; the row's
    # ``standing``, cmudrive.model.row): what a model without its speed needs to leave a stop sign or
    # know that it stands, without a speed to copy while it drives (docs/model.md, "Go/stop")
    standing_in_prompt: bool = False
    max_other_cavs: int = 8  # the nearest ones are listed in the prompt
    # the other CAVs in the prompt as "<id><CAV_POINT>", one embedding per CAV from an MLP of its pose
    # (x, y [m] / target_point_scale, cos yaw, sin yaw) like the target points (about 3 tokens a CAV), instead
    # of "CAV 3 at (12, -3)" spelt in digits (about 11 tokens, whole metres, no heading)
    cav_tokens: bool = False
    other_cavs_range_m: float = 70.0  # [m] CAVs farther than this are not listed (V2V range)
    task_prompt: str = "What should the ego do next?"
    chat_template: bool = False  # wrap the prompt with the tokenizer's chat template (Qwen2 chat models)
    # Outputs
    n_path: int = 20  # path points, 1 m apart
    n_speed: int = 10  # speed waypoints, 0.25 s apart
    waypoint_head_hidden: int = 256
    max_answer_tokens: int = 96  # longer answers are cut (training) / generation stops (inference)
    # one more query after the waypoint queries, read by a head that predicts the expert's target speed
    # [m/s] (where it means to be in 0.5 s) and whether it stops (brakes to a stand or holds): the
    # controller's go/stop and desired speed come from it instead of from the speed waypoints
    # (docs/model.md, "Go/stop")
    speed_query: bool = False
    # what the path queries may attend to: "all" (every input, the paper's model) or "ego" (the CAV's own
    # camera, speed and target points only: the prompt puts the merged image and the other CAVs last, and
    # neither the prompt before them nor the path queries can attend to them; the speed query, the speed
    # waypoints and the language still read everything). Only for the cooperative model (docs/model.md,
    # "Path from the ego's own inputs")
    path_inputs: str = "all"

    def __post_init__(self) -> None:
        if self.pretrained_path is not None and (self.vision is not None or self.text is not None):
            raise ValueError(
                "with pretrained_path the checkpoint defines the architecture: vision/text must be None"
            )
        if self.pretrained_path is None and (self.vision is None or self.text is None):
            raise ValueError(
                f"config {self.name!r}: set pretrained_path (a local InternVL checkpoint directory) "
                "or give vision and text sizes"
            )
        if not 0.0 <= self.bonnet_crop < 1.0:
            raise ValueError(f"bonnet_crop must be in [0, 1), got {self.bonnet_crop}")
        if self.bev_fit not in ("pad", "stretch"):
            raise ValueError(f"bev_fit must be pad or stretch, got {self.bev_fit!r}")
        if self.path_inputs not in ("all", "ego"):
            raise ValueError(f"path_inputs must be all or ego, got {self.path_inputs!r}")
        if self.path_inputs == "ego" and not self.cooperative:
            raise ValueError("path_inputs='ego' is for the cooperative model (the baseline sees no other)")
        if self.llm_training not in ("lora", "full", "frozen"):
            raise ValueError(f"llm_training must be lora, full or frozen, got {self.llm_training!r}")

    @property
    def n_queries(self) -> int:
        """Learnable queries after the prompt: path, speed waypoints and, with ``speed_query``, one more."""
        return self.n_path + self.n_speed + (1 if self.speed_query else 0)

    @property
    def n_images(self) -> int:
        """Tiles per sample through the vision encoder: the camera's, plus one merged-BEV tile."""
        return self.camera_tiles + (1 if self.cooperative else 0)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModelConfig:
        return _from_dict(cls, data)

    def replace(self, **overrides: Any) -> ModelConfig:
        """A copy with fields replaced; nested sections accept dicts (``text={"num_layers": 2}``)."""
        return _from_dict(ModelConfig, {**self.to_dict(), **_plain(overrides)})


T = TypeVar("T")
_SECTIONS: dict[str, type] = {"vision": VisionConfig, "text": TextConfig, "lora": LoraSettings}


def _plain(values: dict[str, Any]) -> dict[str, Any]:
    return {k: dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v for k, v in values.items()}  # type: ignore[arg-type]


def _from_dict(cls: type[T], data: dict[str, Any]) -> T:
    """Build dataclass ``cls`` from a JSON-like dict, raising on keys it does not have."""
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - names)
    if unknown:
        raise ValueError(f"unknown {cls.__name__} keys: {unknown}")
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        section = _SECTIONS.get(key) if cls is ModelConfig else None
        if section is not None and isinstance(value, dict):
            value = _from_dict(section, value)
        elif isinstance(value, list):
            value = tuple(value)
        kwargs[key] = value
    return cls(**kwargs)


NAMED_CONFIGS: dict[str, ModelConfig] = {
    "tiny": ModelConfig(
        name="tiny",
        # 128 px tiles of 16 px patches: the camera at its stored resolution (2 tiles of 256 x 128, no
        # resize), the same 16 tokens per tile as the 64 px / 8 px tiles before (docs/model.md)
        vision=VisionConfig(
            hidden_size=96, num_layers=1, num_heads=4, intermediate_size=256, image_size=128, patch_size=16
        ),
        text=TextConfig(hidden_size=128, num_layers=2, num_heads=4, num_kv_heads=2, intermediate_size=256),
        llm_training="full",
        bonnet_crop=0.0,
        bev_fit="stretch",
        target_point_hidden=(32, 64),
        waypoint_head_hidden=64,
        max_other_cavs=8,
        cav_tokens=True,
        speed_query=True,
    ),
    # tiny as the pairs committed before the inputs changed (docs/model.md, "Inputs"): 64 px tiles of 8 px
    # patches, SimLingo's bonnet crop, the BEV padded to a square, 4 CAVs spelt out, go/stop read from the
    # speed waypoints; kept to reproduce and compare them
    "tiny-v1": ModelConfig(
        name="tiny-v1",
        vision=VisionConfig(
            hidden_size=96, num_layers=1, num_heads=4, intermediate_size=256, image_size=64, patch_size=8
        ),
        text=TextConfig(hidden_size=128, num_layers=2, num_heads=4, num_kv_heads=2, intermediate_size=256),
        llm_training="full",
        target_point_hidden=(32, 64),
        waypoint_head_hidden=64,
        max_other_cavs=4,
    ),
    "small": ModelConfig(
        name="small",
        vision=VisionConfig(
            hidden_size=384, num_layers=6, num_heads=6, intermediate_size=1536, image_size=224, patch_size=14
        ),
        text=TextConfig(hidden_size=512, num_layers=8, num_heads=8, num_kv_heads=2, intermediate_size=1408),
        llm_training="full",
        bonnet_crop=0.0,
        bev_fit="stretch",
        target_point_hidden=(128, 256),
        waypoint_head_hidden=128,
        cav_tokens=True,
        speed_query=True,
    ),
}

INTERNVL2_1B = "internvl2-1b"


def get_config(name: str, **overrides: Any) -> ModelConfig:
    """The named configuration ``tiny``, ``small`` or ``internvl2-1b`` with fields overridden.

    ``internvl2-1b`` needs ``pretrained_path=``: a local directory holding the InternVL2-1B backbone in
    the Hugging Face InternVL format (``config.json``, ``*.safetensors``, tokenizer files)."""
    if name == INTERNVL2_1B:
        if not overrides.get("pretrained_path"):
            raise ValueError("internvl2-1b needs pretrained_path=<local InternVL checkpoint directory>")
        base = {
            "name": INTERNVL2_1B,
            "vision": None,
            "text": None,
            "llm_training": "lora",
            "chat_template": True,
            "pretrained_path": overrides["pretrained_path"],
        }
        return ModelConfig.from_dict({**base, **_plain(overrides)})
    if name not in NAMED_CONFIGS:
        raise ValueError(f"unknown model config {name!r}; known: {[*NAMED_CONFIGS, INTERNVL2_1B]}")
    return NAMED_CONFIGS[name].replace(**overrides) if overrides else NAMED_CONFIGS[name]
