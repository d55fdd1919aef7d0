"""Tokenizers: the shipped tiny tokenizer (``tiny``/``small``) and the special tokens every model needs.

The ``internvl2-1b`` configuration reads the real Qwen2 tokenizer from its checkpoint directory. The
randomly initialised ``tiny``/``small`` models use a small byte-level BPE tokenizer built here with the
``tokenizers`` library from the sentence templates of the prompt, the commentary and the communication
output, and shipped in ``cmudrive/assets/models/tokenizer-tiny`` (a few tens of kB; rebuilt identically
by ``python -m cmudrive.model.tokenizer``). Byte-level BPE encodes any text, so commentary wording the
templates below do not know still round-trips, only in more tokens. Digits are split one per token like
Qwen2's, so numbers such as speeds and CAV positions are spelled digit by digit.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from transformers import PreTrainedTokenizerBase

TINY_TOKENIZER_DIR = Path(__file__).resolve().parents[1] / "assets" / "models" / "tokenizer-tiny"

# Special tokens (InternVL's names for the image ones).
IMG_START = "<img>"
IMG_END = "</img>"
IMG_CONTEXT = "<IMG_CONTEXT>"  # one per visual token; replaced by the projected vision features
TARGET_POINT = "<TARGET_POINT>"  # two per prompt; replaced by the target-point MLP's embeddings
CAV_POINT = "<CAV_POINT>"  # one per listed CAV (``cav_tokens``); replaced by the CAV-pose MLP's embedding
PAD = "<pad>"
EOS = "</s>"
SPECIAL_TOKENS = (PAD, EOS, IMG_START, IMG_END, IMG_CONTEXT, TARGET_POINT, CAV_POINT)
# added to a pretrained base's tokenizer where absent (a saved checkpoint's tokenizer is loaded as saved: its
# embeddings were sized for it)
MODEL_TOKENS = (IMG_START, IMG_END, IMG_CONTEXT, TARGET_POINT, CAV_POINT)
TINY_VOCAB_SIZE = 1024

_OBJECTS = (
    "car", "vehicle", "truck", "van", "bus", "motorcycle", "bicycle", "cyclist", "pedestrian", "walker",
    "child", "traffic cone", "cones", "construction site", "accident", "parked vehicle", "emergency vehicle",
    "ambulance", "police car", "fire truck", "obstacle", "stop sign", "traffic light", "red light",
    "yellow light", "green light", "door", "CAV", "critical object",
)  # fmt: skip
_COLOURS = ("white", "black", "red", "blue", "green", "yellow", "grey", "silver", "orange", "brown")
_DIRECTIONS = ("front", "front left", "front right", "left", "right", "behind", "ahead", "oncoming lane")
_ROUTE = ("Follow the route.", "Turn left.", "Turn right.", "Go straight at the junction.",
          "Change to the left lane.", "Change to the right lane.", "Go around the {o} on the left.",
          "Steer clear of the {o}.", "Give way to the {o}.")  # fmt: skip
_SPEED = ("Remain stopped", "Stop now", "Maintain the current speed", "Accelerate", "Decelerate",
          "Slow down", "Wait", "Start driving")  # fmt: skip
_REASON = (" because of the {c} {o} to the {d}", " due to the {o}", " for the {o} in {d}",
           " to avoid a collision with the {c} {o}", " because of the {o}", "")  # fmt: skip


def corpus() -> list[str]:
    """Sentences the tiny tokenizer is trained on (deterministic order)."""
    lines = [
        "Current speed: 0.0 m/s. Target waypoint: <TARGET_POINT><TARGET_POINT>.",
        "Other CAVs: none.",
        "Other CAVs: CAV 3 at (12.5, -3.0), CAV 10 at (-41.2, 7.9).",
        "Other CAVs: 3<CAV_POINT> 10<CAV_POINT> 15<CAV_POINT>.",
        "Communication: none.",
        "Communication: CAV 4 can see the critical object.",
        "What should the ego do next?",
        "Waypoints:",
        "Caution, a pedestrian is crossing. Watch out for the cyclist. Mind the walker on the left.",
    ]
    for route, speed, reason in itertools.product(_ROUTE, _SPEED, _REASON):
        for obj, colour, direction in zip(_OBJECTS, itertools.cycle(_COLOURS), itertools.cycle(_DIRECTIONS)):
            r = route.format(o=obj)
            lines.append(f"{r} {speed}{reason.format(c=colour, o=obj, d=direction)}.")
    for k, obj in zip(range(16), itertools.cycle(_OBJECTS)):
        lines.append(f"CAV {k} can see the {obj} that the ego cannot see. Communicate with CAV {k}.")
    lines.append(" ".join(str(i) for i in range(100)) + " -0.5 +1.25 (3.0, -2.0)")
    return lines


def build_tiny_tokenizer() -> PreTrainedTokenizerBase:
    """Train the tiny byte-level BPE tokenizer on :func:`corpus` (a few seconds on one core)."""
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers, trainers
    from transformers import PreTrainedTokenizerFast

    tok = Tokenizer(models.BPE())
    tok.pre_tokenizer = pre_tokenizers.Sequence(
        [pre_tokenizers.Digits(individual_digits=True), pre_tokenizers.ByteLevel(add_prefix_space=False)]
    )
    tok.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(
        vocab_size=TINY_VOCAB_SIZE,
        special_tokens=list(SPECIAL_TOKENS),
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
        show_progress=False,
    )
    tok.train_from_iterator(corpus(), trainer=trainer)
    return PreTrainedTokenizerFast(
        tokenizer_object=tok,
        pad_token=PAD,
        eos_token=EOS,
        additional_special_tokens=[IMG_START, IMG_END, IMG_CONTEXT, TARGET_POINT, CAV_POINT],
        padding_side="left",
    )


def load_tokenizer(
    path: str | Path | None = None, add: tuple[str, ...] = MODEL_TOKENS
) -> PreTrainedTokenizerBase:
    """The tokenizer in ``path`` (a pretrained checkpoint's) or the shipped tiny one, with the tokens ``add``
    added where missing (``()`` for a saved V2V-VLA checkpoint's own tokenizer, whose embeddings were sized
    for it), a pad token, and left padding (waypoint queries end every row)."""
    from transformers import AutoTokenizer

    tok = AutoTokenizer.from_pretrained(str(path or TINY_TOKENIZER_DIR))
    missing = [t for t in add if t not in tok.get_vocab()]
    if missing:
        tok.add_tokens(missing, special_tokens=True)
    if tok.pad_token is None:
        tok.pad_token = tok.eos_token
    tok.padding_side = "left"
    return tok


if __name__ == "__main__":
    build_tiny_tokenizer().save_pretrained(str(TINY_TOKENIZER_DIR))
    print(f"wrote {TINY_TOKENIZER_DIR}")
