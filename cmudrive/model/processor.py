"""Rows (dicts of one CAV at one tick) to a batch of tensors for :class:`cmudrive.model.V2VVLA`.

A row has the dataset's columns: ``camera`` (PIL RGB or (H, W, 3) uint8, 256 x 128), ``merged_bev``
(PIL RGB or array, the merged occupancy render, ego driving up), ``speed`` [m/s], ``target_points``
(2, 2) [m] (ego frame, x forward, y left), ``other_cavs`` (list of [cav, x, y, yaw]) and, for training,
``path`` (20, 2) [m], ``speed_waypoints`` (10, 2) [m], ``commentary`` (str), ``communication`` (str, ""
for none), ``partner_label`` (int, -1 for none) and, for a model with ``speed_query``, ``target_speed``
[m/s] (the expert's) and optionally ``stop`` (bool; default: SimLingo's brake rule at the row's speed for
that target, :func:`cmudrive.agents.control.expert_stops`). Other keys are ignored.

Token layout of one row (left-padded, so that every row ends at the same position and the model can
append its waypoint queries after it)::

    <pad>... <img> <IMG_CONTEXT>*(camera tokens) </img> [<img> <IMG_CONTEXT>*(BEV tokens) </img>] \\n
    [Current speed: 4.2 m/s.] [Stopped for 2.5 s.] Target waypoint: <TARGET_POINT><TARGET_POINT>.
    [Other CAVs: ...] {task}

(the standing time only with ``standing_in_prompt`` and while the CAV stands: :func:`standing_text`; the
speed is left out by a configuration with ``speed_in_prompt=False``, and from a training row whose
``speed`` is ``None``: speed dropout; with ``cav_tokens`` the other CAVs read "Other CAVs: 3<CAV_POINT>
10<CAV_POINT>.", each ``<CAV_POINT>`` replaced by an embedding of that CAV's pose) and, for training,
the answer apart (right-padded): the commentary,
and for the cooperative model " Communication: " followed by the communication sentence or "none.", then
``</s>``. The model puts its waypoint queries between the two (:class:`cmudrive.model.V2VVLA`): prompt,
queries, answer.

With ``path_inputs="ego"`` the cooperative part goes last, after the baseline's whole prompt:
"<img> camera </img>\\n [speed] Target waypoint: ... {task}\\n<img> BEV </img> Other CAVs: ...", and the
batch's ``ego_mask`` marks the tokens before that second ``<img>``: all that the path may read.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

from cmudrive.agents.control import expert_stops
from cmudrive.model.config import ModelConfig
from cmudrive.model.tokenizer import (
    CAV_POINT,
    IMG_CONTEXT,
    IMG_END,
    IMG_START,
    TARGET_POINT,
    load_tokenizer,
)

if TYPE_CHECKING:
    import torch
    from transformers import PreTrainedTokenizerBase

IMAGE_MEAN = np.array([0.485, 0.456, 0.406], np.float32)  # ImageNet, as InternVL
IMAGE_STD = np.array([0.229, 0.224, 0.225], np.float32)
IGNORE_INDEX = -100
COMMUNICATION_PREFIX = "Communication:"
NO_COMMUNICATION = "none."
_PARTNER_RE = re.compile(r"\bCAV\s*(\d+)")


@dataclass
class VLABatch:
    """Tensors of one batch of ``B`` rows; ``L`` tokens per row; the ``None`` fields are training targets."""

    pixel_values: torch.Tensor  # (B, n_images, 3, S, S) float32, ImageNet-normalised tiles
    input_ids: torch.Tensor  # (B, L) int64, the prompt, left-padded
    attention_mask: torch.Tensor  # (B, L) int64, 0 on padding
    target_points: torch.Tensor  # (B, 2, 2) float32 [m], ego frame
    cav_poses: torch.Tensor | None = None  # (M, 3) float32 x, y [m], yaw [rad] of the listed CAVs, row order
    # (B, L) bool, path_inputs="ego": the prompt's tokens before the cooperative part (the merged image and
    # the other CAVs, last in the prompt), which they and the path queries cannot see; None: no such limit
    ego_mask: torch.Tensor | None = None
    answer_ids: torch.Tensor | None = None  # (B, A) int64, the answer and </s>, right-padded
    labels: torch.Tensor | None = None  # (B, A) int64, answer_ids with IGNORE_INDEX on the padding
    path: torch.Tensor | None = None  # (B, n_path, 2) float32 [m]
    speed_waypoints: torch.Tensor | None = None  # (B, n_speed, 2) float32 [m]
    partner_label: torch.Tensor | None = None  # (B,) int64, -1 for none
    target_speed: torch.Tensor | None = None  # (B,) float32 [m/s], the expert's (speed_query)
    stop: torch.Tensor | None = None  # (B,) float32, 1 where the expert's target speed brakes (speed_query)

    def to(self, device: torch.device | str, non_blocking: bool = False) -> VLABatch:
        return self._map(lambda t: t.to(device, non_blocking=non_blocking))

    def pin_memory(self) -> VLABatch:
        """For ``DataLoader(..., collate_fn=processor, pin_memory=True)``."""
        return self._map(lambda t: t.pin_memory())

    def _map(self, fn: Callable[[torch.Tensor], torch.Tensor]) -> VLABatch:
        moved: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            moved[f.name] = None if value is None else fn(value)
        return replace(self, **moved)

    def __len__(self) -> int:
        return int(self.input_ids.shape[0])


def parse_partner(text: str) -> int:
    """The CAV named after "Communication:" in a generated answer, or -1 when it names none."""
    _, sep, tail = text.partition(COMMUNICATION_PREFIX)
    match = _PARTNER_RE.search(tail) if sep else None
    return int(match.group(1)) if match else -1


def _rgb(image: Any) -> Image.Image:
    if isinstance(image, Image.Image):
        return image.convert("RGB")
    array = np.asarray(image)
    if array.ndim != 3 or array.shape[2] != 3 or array.dtype != np.uint8:
        raise ValueError(f"expected an (H, W, 3) uint8 image, got {array.shape} {array.dtype}")
    return Image.fromarray(array)


# (3, 256) float32: the ImageNet-normalised value of each uint8 level, per channel
_LEVELS = np.ascontiguousarray(
    ((np.arange(256, dtype=np.float32)[:, None] * np.float32(1.0 / 255.0) - IMAGE_MEAN) / IMAGE_STD).T
)


def _normalise(tiles: np.ndarray) -> np.ndarray:
    """(..., S, S, 3) uint8 -> (..., 3, S, S) float32, ImageNet-normalised: (level / 255 - mean) / std,
    looked up per channel (the same float32 arithmetic, done once per level: 0.5 ms instead of 1.4 ms
    for a 16-CAV tick's 48 tiles)."""
    out = np.empty((*tiles.shape[:-3], 3, *tiles.shape[-3:-1]), np.float32)
    for c in range(3):
        np.take(_LEVELS[c], tiles[..., c], out=out[..., c, :, :])
    return out


class VLAProcessor:
    """Turns rows into :class:`VLABatch`; holds the tokenizer and the image geometry of the backbone."""

    def __init__(
        self, config: ModelConfig, tokenizer: PreTrainedTokenizerBase, image_size: int, tokens_per_image: int
    ) -> None:
        self.config = config
        self.tokenizer = tokenizer
        self.image_size = image_size  # [px] side of one tile
        self.tokens_per_image = tokens_per_image  # visual tokens per tile after pixel shuffle
        vocab = tokenizer.get_vocab()
        self.image_token_id = vocab[IMG_CONTEXT]
        self.image_start_id = vocab.get(IMG_START, -1)
        if self.ego_path and self.image_start_id < 0:
            raise ValueError(f"path_inputs='ego' needs the {IMG_START} token, which the tokenizer lacks")
        self.target_point_token_id = vocab[TARGET_POINT]
        self.cav_point_token_id = vocab.get(CAV_POINT, -1)
        if config.cav_tokens and self.cav_point_token_id < 0:
            raise ValueError(f"cav_tokens needs the {CAV_POINT} token, which the tokenizer lacks")
        if tokenizer.eos_token_id is None or tokenizer.pad_token_id is None:
            raise ValueError("the tokenizer needs an eos and a pad token")
        self.eos_token_id = int(tokenizer.eos_token_id)
        self.pad_token_id = int(tokenizer.pad_token_id)

    @property
    def ego_path(self) -> bool:
        """The path queries see only the ego's own inputs (``path_inputs="ego"``; the configuration allows it
        for the cooperative model only)."""
        return self.config.path_inputs == "ego"

    @classmethod
    def from_config(
        cls, config: ModelConfig, tokenizer: PreTrainedTokenizerBase | None = None
    ) -> VLAProcessor:
        """Geometry from ``config.vision`` or, for a pretrained backbone, from its ``config.json``."""
        tokenizer = tokenizer or load_tokenizer(config.tokenizer_path or config.pretrained_path)
        if config.vision is not None:
            side, patch, ratio = config.vision.image_size, config.vision.patch_size, 0.5
        else:
            assert config.pretrained_path is not None
            hf = json.loads((Path(config.pretrained_path) / "config.json").read_text())
            vision = hf["vision_config"]
            side, patch = _first(vision["image_size"]), _first(vision["patch_size"])
            ratio = float(hf.get("downsample_ratio", 0.5))
        tokens = round((side // patch) ** 2 * ratio**2)
        return cls(config, tokenizer, side, tokens)

    # ---- images -------------------------------------------------------------------------------------
    # Resizing uses PIL's bilinear filter, which widens its support when shrinking (area-averaging, no
    # aliasing) at 0.1 ms per image; a closed-loop tick processes 16-32 of them.
    def _camera_uint8(self, image: Any) -> np.ndarray:
        img = _rgb(image)
        keep = max(1, round(img.height * (1.0 - self.config.bonnet_crop)))
        n, s = self.config.camera_tiles, self.image_size
        if keep < img.height:  # crop first: resize(box=...) would let the filter read bonnet rows
            img = img.crop((0, 0, img.width, keep))
        if img.size != (n * s, s):  # tiny's 128 px tiles take the stored 256 x 128 camera as it is
            img = img.resize((n * s, s), Image.Resampling.BILINEAR)
        return np.asarray(img).reshape(s, n, s, 3).transpose(1, 0, 2, 3)  # (n, S, S, 3), left to right

    def _bev_uint8(self, image: Any) -> np.ndarray:
        img = _rgb(image)
        if self.config.bev_fit == "stretch":  # the whole render, no padding
            s = self.image_size
            if img.size != (s, s):
                img = img.resize((s, s), Image.Resampling.BILINEAR)
            return np.asarray(img)[None]
        s, side = self.image_size, max(img.width, img.height)
        w, h = max(1, round(img.width * s / side)), max(1, round(img.height * s / side))
        square = np.zeros((s, s, 3), np.uint8)
        top, left = (s - h) // 2, (s - w) // 2
        square[top : top + h, left : left + w] = np.asarray(img.resize((w, h), Image.Resampling.BILINEAR))
        return square[None]

    def camera_tiles(self, image: Any) -> np.ndarray:
        """(camera_tiles, 3, S, S): bonnet rows cropped, resized to tiles*S x S, split left to right."""
        return _normalise(self._camera_uint8(image))

    def bev_tile(self, image: Any) -> np.ndarray:
        """(1, 3, S, S): the merged BEV resized to S x S (``bev_fit="stretch"``) or, keeping its metres per
        pixel equal along both axes, centred on a black square (``"pad"``)."""
        return _normalise(self._bev_uint8(image))

    def pixel_values(self, row: dict[str, Any]) -> np.ndarray:
        """(n_images, 3, S, S) of one row: camera tiles, then the merged BEV for the cooperative model."""
        return _normalise(self._tiles_uint8(row))

    def _tiles_uint8(self, row: dict[str, Any]) -> np.ndarray:
        tiles = [self._camera_uint8(row["camera"])]
        if self.config.cooperative:
            tiles.append(self._bev_uint8(row["merged_bev"]))
        return np.concatenate(tiles)

    # ---- text ---------------------------------------------------------------------------------------
    def listed_cavs(self, other_cavs: Sequence[Sequence[float]]) -> list[Sequence[float]]:
        """The other CAVs the prompt lists: ``[cav, x, y, yaw]`` within range, nearest first, at most
        ``max_other_cavs``."""
        near = [c for c in other_cavs if math.hypot(c[1], c[2]) <= self.config.other_cavs_range_m]
        near.sort(key=lambda c: math.hypot(c[1], c[2]))
        return near[: self.config.max_other_cavs]

    def others_text(self, other_cavs: Sequence[Sequence[float]]) -> str:
        """The listed CAVs (ego frame, x forward, y left): "Other CAVs: 3<CAV_POINT> 10<CAV_POINT>." with
        ``cav_tokens`` (the pose goes in as an embedding), else "Other CAVs: CAV 3 at (12, -3), ..." in
        whole metres (digits are one token each, so every decimal costs tokens)."""
        listed = self.listed_cavs(other_cavs)
        if self.config.cav_tokens:
            return "Other CAVs: " + (" ".join(f"{int(c[0])}{CAV_POINT}" for c in listed) or "none") + "."
        spelt = [f"CAV {int(c[0])} at ({c[1]:.0f}, {c[2]:.0f})" for c in listed]
        return "Other CAVs: " + (", ".join(spelt) if spelt else "none") + "."

    def prompt(self, row: dict[str, Any]) -> str:
        """The prompt text of one row, image placeholders included."""
        ctx = IMG_CONTEXT * self.tokens_per_image
        images = IMG_START + ctx * self.config.camera_tiles + IMG_END
        text = f"Target waypoint: {TARGET_POINT}{TARGET_POINT}."
        if self.config.standing_in_prompt:
            if row.get("standing") is None:
                raise ValueError(
                    "this model's prompt states how long the CAV has stood: the row needs 'standing' [s], "
                    "-1 while it moves (cmudrive.model.row.RowBuilder or dataset.load_rows give it)"
                )
            text = standing_text(row["standing"]) + text
        if self.config.speed_in_prompt and row["speed"] is not None:  # None: dropped in training
            text = f"Current speed: {float(row['speed']):.1f} m/s. {text}"
        if self.ego_path:  # the cooperative part last
            shared = f"{IMG_START}{ctx}{IMG_END} {self.others_text(row.get('other_cavs') or [])}"
            text = f"{images}\n{text} {self.config.task_prompt}\n{shared}"
        else:
            if self.config.cooperative:
                images += IMG_START + ctx + IMG_END
                text += " " + self.others_text(row.get("other_cavs") or [])
            text = f"{images}\n{text} {self.config.task_prompt}"
        if self.config.chat_template:
            messages = [{"role": "user", "content": text}]
            text = str(
                self.tokenizer.apply_chat_template(messages, add_generation_prompt=True, tokenize=False)
            )
        return text

    def answer(self, row: dict[str, Any]) -> str:
        """The target text of one row; checks that the named partner can be parsed back."""
        text = str(row["commentary"]).strip()
        if not self.config.cooperative:
            return text
        communication = str(row.get("communication") or "").strip() or NO_COMMUNICATION
        text = f"{text} {COMMUNICATION_PREFIX} {communication}"
        label = int(row.get("partner_label", -1))
        if parse_partner(text) != label:
            raise ValueError(f"communication {communication!r} does not name partner_label {label}")
        return text

    def encode(self, row: dict[str, Any], with_answer: bool) -> tuple[list[int], list[int]]:
        """Prompt token ids and answer token ids (``</s>`` last; empty without the answer) of one row."""
        return self.encode_rows([row], with_answer)[0]

    def encode_rows(
        self, rows: Sequence[dict[str, Any]], with_answer: bool
    ) -> list[tuple[list[int], list[int]]]:
        """:meth:`encode` of every row; one tokenizer call for all prompts (one for all answers)."""
        prompts = self.tokenizer([self.prompt(r) for r in rows], add_special_tokens=False)["input_ids"]
        expected = self.tokens_per_image * self.config.n_images
        for ids, row in zip(prompts, rows, strict=True):
            if ids.count(self.image_token_id) != expected or ids.count(self.target_point_token_id) != 2:
                raise ValueError("the prompt's image / target-point placeholders did not tokenize one to one")
            if self.config.cav_tokens and self.config.cooperative:
                if ids.count(self.cav_point_token_id) != len(self.listed_cavs(row.get("other_cavs") or [])):
                    raise ValueError("the prompt's CAV placeholders did not tokenize one to one")
            if self.ego_path and ids.count(self.image_start_id) != 2:
                raise ValueError(f"the prompt's {IMG_START} markers did not tokenize one to one")
        if not with_answer:
            return [(list(ids), []) for ids in prompts]
        lead = "" if self.config.chat_template else " "
        answers = self.tokenizer([lead + self.answer(r) for r in rows], add_special_tokens=False)["input_ids"]
        cut = self.config.max_answer_tokens - 1
        return [(list(p), [*a[:cut], self.eos_token_id]) for p, a in zip(prompts, answers, strict=True)]

    # ---- batch --------------------------------------------------------------------------------------
    def __call__(self, rows: Sequence[dict[str, Any]], with_answer: bool | None = None) -> VLABatch:
        """Batch ``rows``; ``with_answer`` (default: when the rows carry ``commentary``) adds the answer
        tokens, labels and waypoint targets (training), else the batch is a prompt for :meth:`predict`."""
        import torch

        if not rows:
            raise ValueError("no rows")
        if with_answer is None:
            with_answer = "commentary" in rows[0]
        encoded = self.encode_rows(rows, with_answer)
        length = max(len(ids) for ids, _ in encoded)
        input_ids = torch.full((len(rows), length), self.pad_token_id, dtype=torch.long)
        mask = torch.zeros((len(rows), length), dtype=torch.long)
        for i, (ids, _) in enumerate(encoded):  # left padding: every prompt ends at position L
            input_ids[i, length - len(ids) :] = torch.tensor(ids)
            mask[i, length - len(ids) :] = 1
        batch = VLABatch(
            pixel_values=torch.from_numpy(_normalise(np.stack([self._tiles_uint8(r) for r in rows]))),
            input_ids=input_ids,
            attention_mask=mask,
            target_points=_stack(rows, "target_points", (2, 2)),
        )
        if self.ego_path:  # the ego's part of each prompt: from its first token to the merged image's <img>
            start = (input_ids == self.image_start_id).long().cumsum(-1)
            batch.ego_mask = mask.bool() & (start < 2)
        if self.config.cav_tokens and self.config.cooperative:
            poses = [c[1:4] for r in rows for c in self.listed_cavs(r.get("other_cavs") or [])]
            batch.cav_poses = torch.from_numpy(np.asarray(poses, np.float32).reshape(-1, 3))
        if with_answer:
            width = max(len(a) for _, a in encoded)
            answer_ids = torch.full((len(rows), width), self.pad_token_id, dtype=torch.long)
            labels = torch.full((len(rows), width), IGNORE_INDEX, dtype=torch.long)
            for i, (_, answer) in enumerate(encoded):  # right padding
                answer_ids[i, : len(answer)] = labels[i, : len(answer)] = torch.tensor(answer)
            batch.answer_ids, batch.labels = answer_ids, labels
            batch.path = _stack(rows, "path", (self.config.n_path, 2))
            batch.speed_waypoints = _stack(rows, "speed_waypoints", (self.config.n_speed, 2))
            batch.partner_label = torch.tensor([int(r.get("partner_label", -1)) for r in rows])
            if self.config.speed_query:
                batch.target_speed, batch.stop = speed_labels(rows)
        return batch


STANDING_STEP = 0.5  # [s] the prompt's standing time is rounded down to this
STANDING_CAP = 30.0  # [s] and capped here: a longer stand reads as this one


def standing_text(standing: float) -> str:
    """The prompt's standing clause for a row's ``standing`` [s]: "" while the CAV moves (negative),
    else "Stopped for 2.5 s. " (rounded down to ``STANDING_STEP``, at most ``STANDING_CAP``): the
    collection's 0.25 s rows and the closed loop's 0.05 s ticks read the same."""
    if standing < 0:
        return ""
    shown = min(math.floor(float(standing) / STANDING_STEP) * STANDING_STEP, STANDING_CAP)
    return f"Stopped for {shown:.1f} s. "


def speed_labels(rows: Sequence[dict[str, Any]]) -> tuple[torch.Tensor, torch.Tensor]:
    """(B,) speed-query targets [m/s] and (B,) stop labels (1.0 / 0.0) of training rows. The target is
    the expert's ``desired_speed`` (what its rules allow, not its acceleration-limited ``target_speed``:
    docs/model.md, "Go/stop"); the stop label is the expert's go/stop (``expert_stops`` of the row's
    speed and ``target_speed``), or the row's own ``stop`` where it has one (a row whose prompt dropped
    its speed keeps the label of its true speed)."""
    import torch

    target = np.array([float(r["desired_speed"]) for r in rows], np.float32)
    speed = np.array([float(r["speed"]) if r["speed"] is not None else 0.0 for r in rows], np.float32)
    stop = expert_stops(speed, np.array([float(r["target_speed"]) for r in rows], np.float32))
    given = [i for i, r in enumerate(rows) if r.get("stop") is not None]
    stop[given] = [bool(rows[i]["stop"]) for i in given]
    return torch.from_numpy(target), torch.from_numpy(stop.astype(np.float32))


def _first(value: int | Sequence[int]) -> int:
    return int(value if isinstance(value, int) else value[0])


def _stack(rows: Sequence[dict[str, Any]], key: str, shape: tuple[int, ...]) -> torch.Tensor:
    import torch

    arrays = [np.asarray(r[key], np.float32) for r in rows]
    for a in arrays:
        if a.shape != shape:
            raise ValueError(f"{key}: expected shape {shape}, got {a.shape}")
    return torch.from_numpy(np.stack(arrays))
