"""V2V-VLA: SimLingo's model (InternVL2: InternViT + MLP projector + Qwen2, LoRA on the LLM) with the
merged-BEV image, the other CAVs in the prompt and a communication sentence (the paper, Sec. 4).

Reads top to bottom:

1. the backbone (:mod:`cmudrive.model.backbone`): ``transformers.InternVLForConditionalGeneration``
   (vision tower, pixel-shuffle + ``InternVLMultiModalProjector``, ``Qwen2Model`` language model, LM
   head), randomly initialised from the config's sizes or read from a local directory; peft LoRA;
2. the driving heads: the target-point MLP and the waypoint heads (per-step deltas, summed);
3. :class:`V2VVLA`: embedding (tokens, image features, target points, waypoint queries), one pass of
   the language model over prompt, queries and answer, the loss (smooth-L1 waypoints + answer-only
   cross-entropy), ``predict`` (waypoints from one pass over prompt + queries, then, when asked, greedy
   text on the KV cache) and ``save_pretrained``/``from_pretrained``.

The sequence is ``prompt, waypoint queries, answer``: the queries see the prompt only, the answer sees
both. SimLingo appends its queries after the text, with the commentary an optional chain of thought
before them (``reference/MODEL_AND_EXPERT.md``); here the waypoints never wait for language, so the
closed loop drives every tick from one pass over ~150 positions per CAV and decodes language only at
its lower rate, and the communication sentence (which picks the next tick's partner) is read after the
waypoints of the same tick. The cost: the commentary is not a chain of thought for the waypoints
(docs/model.md, "Layout").

Shapes: B rows, L prompt tokens, Q = n_path + n_speed waypoint queries, A answer tokens, H the LLM
hidden size, V the vocabulary, N = n_images tiles per row of side S, T visual tokens per tile.
"""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import torch
import torch.nn.functional as F
from safetensors.torch import load_model, save_model
from torch import nn
from transformers import (
    InternVLConfig,
    InternVLForConditionalGeneration,
    InternVLVisionConfig,
    PreTrainedTokenizerBase,
    Qwen2Config,
)
from transformers.utils import ModelOutput

from cmudrive.model.backbone import add_lora, build_backbone, size_mismatch
from cmudrive.model.config import ModelConfig
from cmudrive.model.processor import IGNORE_INDEX, VLABatch, VLAProcessor, parse_partner
from cmudrive.model.tokenizer import load_tokenizer

FORMAT_VERSION = 1
WEIGHTS_FILE = "model.safetensors"
CONFIG_FILE = "vla_config.json"
BACKBONE_DIR = "backbone"  # the InternVL config (config.json) of the backbone
TOKENIZER_DIR = "tokenizer"


# ---- 2. driving heads -------------------------------------------------------------------------------
def relu_mlp(in_size: int, hidden: tuple[int, ...], out_size: int) -> nn.Sequential:
    """in -> hidden[0] -> ... -> out, ReLU between the linear layers."""
    sizes = [in_size, *hidden]
    layers: list[nn.Module] = []
    for a, b in itertools.pairwise(sizes):
        layers += [nn.Linear(a, b), nn.ReLU()]
    return nn.Sequential(*layers, nn.Linear(sizes[-1], out_size))


class TargetPointEncoder(nn.Module):
    """MLP (x, y) -> LLM embedding, 2 -> hidden[0] -> ... -> H with ReLU (SimLingo: 2 -> 256 -> 512 -> H)."""

    def __init__(self, hidden: tuple[int, ...], out_size: int, scale: float) -> None:
        super().__init__()
        self.mlp = relu_mlp(2, hidden, out_size)
        self.scale = scale  # [m]

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        return self.mlp(points / self.scale)  # (B, 2, 2) [m] -> (B, 2, H)


class CavPoseEncoder(nn.Module):
    """MLP of another CAV's pose -> LLM embedding: (x / scale, y / scale, cos yaw, sin yaw) -> hidden ->
    H, ReLU; one embedding per ``<CAV_POINT>`` of the prompt (``cav_tokens``)."""

    def __init__(self, hidden: tuple[int, ...], out_size: int, scale: float) -> None:
        super().__init__()
        self.mlp = relu_mlp(4, hidden, out_size)
        self.scale = scale  # [m]

    def forward(self, poses: torch.Tensor) -> torch.Tensor:
        """(M, 3) x, y [m], yaw [rad] -> (M, H)."""
        xy, yaw = poses[:, :2] / self.scale, poses[:, 2:3]
        return self.mlp(torch.cat([xy, torch.cos(yaw), torch.sin(yaw)], dim=-1))


class SpeedHead(nn.Module):
    """The speed query's hidden state -> the target speed [m/s] (where the expert means to be in 0.5 s,
    >= 0) and the logit of stopping (SimLingo's brake rule for that target at the current speed)."""

    def __init__(self, in_size: int, hidden: int) -> None:
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(in_size, hidden), nn.ReLU(), nn.Linear(hidden, 2))

    def forward(self, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.mlp(state)  # (B, H) -> (B, 2)
        return F.softplus(out[:, 0]), out[:, 1]


class WaypointHead(nn.Module):
    """Query hidden states -> per-step (dx, dy) -> cumulative sum: waypoints in the ego frame [m]."""

    def __init__(self, in_size: int, hidden: int) -> None:
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(in_size, hidden), nn.ReLU(), nn.Linear(hidden, 2))

    def forward(self, states: torch.Tensor) -> torch.Tensor:
        return self.mlp(states).cumsum(dim=1)  # (B, n, H) -> (B, n, 2)


# ---- 3. the model -----------------------------------------------------------------------------------
@dataclass
class VLAOutput(ModelOutput):
    """``loss = lm_loss + waypoint_loss + speed_loss`` (present when the batch has targets)."""

    loss: torch.Tensor | None = None
    lm_loss: torch.Tensor | None = None  # mean cross-entropy over answer tokens
    # smooth-L1 path + smooth-L1 speed waypoints, each summed over x, y and averaged over points (SimLingo)
    waypoint_loss: torch.Tensor | None = None
    speed_loss: torch.Tensor | None = None  # smooth-L1 target speed + stop cross-entropy (0 without)
    logits: torch.Tensor | None = None  # (B, A, V): the prediction of each answer token
    path: torch.Tensor | None = None  # (B, n_path, 2) [m]
    speed_waypoints: torch.Tensor | None = None  # (B, n_speed, 2) [m]
    target_speed: torch.Tensor | None = None  # (B,) [m/s] (speed_query)
    stop_logit: torch.Tensor | None = None  # (B,) (speed_query)


@dataclass
class VLAPrediction:
    """What the closed loop reads, one entry per row."""

    path: torch.Tensor  # (B, n_path, 2) [m], ego frame
    speed_waypoints: torch.Tensor  # (B, n_speed, 2) [m], ego frame, 0.25 s apart
    text: list[str]  # generated commentary (+ communication sentence)
    partner: list[int]  # CAV named in the communication sentence, -1 for none (always -1 for the baseline)
    answer_ids: list[list[int]]  # the generated answer tokens, </s> included ([] when none was asked)
    target_speed: torch.Tensor | None = (
        None  # (B,) [m/s] to drive at (speed_query: the desired_speed), else None
    )
    stop_prob: torch.Tensor | None = None  # (B,) probability that the expert would brake (speed_query)


def answer_loss(logits: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Mean cross-entropy of the answer tokens: ``logits[:, i]`` (B, A, V) predicts ``labels[:, i]``
    (B, A); positions labelled IGNORE_INDEX (padding) do not count (0 when there are none)."""
    if not (labels != IGNORE_INDEX).any():
        return logits.sum() * 0.0
    return F.cross_entropy(logits.flatten(0, 1), labels.flatten(), ignore_index=IGNORE_INDEX)


def waypoint_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Smooth-L1 summed over (x, y) and averaged over points and rows, as SimLingo weighs it."""
    return F.smooth_l1_loss(pred, target, reduction="none").sum(-1).mean()


def speed_loss(
    target_speed: torch.Tensor, stop_logit: torch.Tensor, batch_target: torch.Tensor, batch_stop: torch.Tensor
) -> torch.Tensor:
    """Smooth-L1 of the target speed [m/s] + binary cross-entropy of the stop decision."""
    return F.smooth_l1_loss(target_speed, batch_target) + F.binary_cross_entropy_with_logits(
        stop_logit, batch_stop
    )


def positions(mask: torch.Tensor) -> torch.Tensor:
    """(B, L) position ids that skip left padding."""
    return (mask.cumsum(-1) - 1).clamp(min=0)


def ego_attention(mask: torch.Tensor, ego: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The attention mask (B, 1, N, N) bool (True: may attend) and position ids (B, N) of a sequence whose
    ``ego`` positions (B, N) bool (``path_inputs="ego"``: the prompt before its cooperative part, and the
    path queries) see only each other: causal, padding (``mask`` (B, N), 0 on padding) masked, and an ego
    position never attends to a non-ego one; every other position sees all before it. An ego position's
    id counts only the ego positions before it, so the path does not even learn how long the cooperative
    part is; the others count every position (:func:`positions`). Each position may attend to itself,
    so that a padding position gets a finite state (nothing reads it)."""
    n = mask.shape[1]
    idx = torch.arange(n, device=mask.device)
    valid = mask.bool()
    allowed = (idx[None, :] <= idx[:, None])[None] & valid[:, None, :]  # (B, N, N) causal, no padding
    allowed = allowed & (~ego[:, :, None] | ego[:, None, :])
    allowed = allowed | torch.eye(n, dtype=torch.bool, device=mask.device)[None]
    pos = torch.where(ego, positions((valid & ego).long()), positions(mask))
    return allowed[:, None], pos


def sequence_ego(
    prompt_ego: torch.Tensor | None, config: ModelConfig, answer: int = 0
) -> torch.Tensor | None:
    """(B, L+Q+A) bool: the ego positions of prompt + queries + ``answer`` tokens (the prompt's from the
    processor, then the path queries), or None when the model has no such limit."""
    if prompt_ego is None:
        return None
    b = prompt_ego.shape[0]
    first = 1 if config.speed_query else 0
    queries = torch.zeros(config.n_queries, dtype=torch.bool, device=prompt_ego.device)
    queries[first : first + config.n_path] = True
    tail = torch.zeros(answer, dtype=torch.bool, device=prompt_ego.device)
    return torch.cat([prompt_ego, torch.cat([queries, tail])[None].expand(b, -1)], dim=1)


def _kv_cache(lm: Any, out: Any) -> tuple[str, Any]:
    """The keyword under which ``lm`` takes its key/value cache and the cache ``out`` returned. Later
    transformers 5 releases call both ``cache`` and warn on every call under the old name
    ``past_key_values``; earlier ones only know the old name."""
    import inspect

    if "cache" in inspect.signature(lm.forward).parameters:
        return "cache", out["cache"]
    return "past_key_values", out["past_key_values"]


def query_states(
    lm: Any, embeds: torch.Tensor, mask: torch.Tensor, q: int, ego: torch.Tensor | None = None
) -> torch.Tensor:
    """(B, Q, H): the language model's (a ``Qwen2Model``) final states at the last ``q`` positions of
    ``embeds`` (B, L+Q, H), equal to ``lm(...).last_hidden_state[:, -q:]`` but with the last decoder
    layer evaluated at those positions alone.

    Only the queries' outputs are read when no text is decoded, and in the last layer nothing else
    depends on the other positions' outputs: their keys and values are needed, their queries, attention
    output and MLP are not. With ``tiny`` (2 layers, ~120 prompt positions and 30 queries per row) that
    is ~30 % of the language model's time of a closed-loop tick (``benchmarks/closed_loop.py``). The
    layers before the last run through ``lm`` itself (its masks, rotary embedding and attention
    implementation); the last one is Qwen2's decoder layer written out with its own modules (norms,
    projections, rotary embedding, MLP) and PyTorch's SDPA, which transformers' ``sdpa`` path
    also calls. Tests check it against the full pass. ``ego`` (B, L+Q) bool: the positions that see only
    each other (:func:`ego_attention`)."""
    from transformers.models.qwen2.modeling_qwen2 import repeat_kv, rotate_half

    layers, norm = lm.layers, lm.norm
    last = layers[-1]
    attn = last.self_attn
    if getattr(attn, "sliding_window", None) is not None:
        raise ValueError("query_states does not handle sliding-window attention")
    full: torch.Tensor | None = None
    if ego is None:
        pos, lm_mask = positions(mask), mask
    else:
        full, pos = ego_attention(mask, ego)
        lm_mask = full
    try:  # the layers before the last, as lm runs them; restored whatever happens
        lm.layers, lm.norm = nn.ModuleList(list(layers)[:-1]), nn.Identity()
        hidden = lm(inputs_embeds=embeds, attention_mask=lm_mask, position_ids=pos, use_cache=False)
    finally:
        lm.layers, lm.norm = layers, norm
    h = hidden.last_hidden_state  # (B, L+Q, H)
    b, n, _ = h.shape
    cos, sin = lm.rotary_emb(h, pos)
    x = last.input_layernorm(h)
    d = attn.head_dim
    query = attn.q_proj(x[:, -q:]).view(b, q, -1, d).transpose(1, 2)  # (B, heads, Q, d)
    key = attn.k_proj(x).view(b, n, -1, d).transpose(1, 2)  # (B, kv heads, L+Q, d)
    value = attn.v_proj(x).view(b, n, -1, d).transpose(1, 2)
    cos, sin = cos[:, None], sin[:, None]  # (B, 1, L+Q, d): as apply_rotary_pos_emb broadcasts them
    query = query * cos[:, :, -q:] + rotate_half(query) * sin[:, :, -q:]
    key = key * cos + rotate_half(key) * sin
    key, value = repeat_kv(key, attn.num_key_value_groups), repeat_kv(value, attn.num_key_value_groups)
    if full is None:
        rows = torch.arange(n - q, n, device=mask.device)
        allowed = (torch.arange(n, device=mask.device)[None, :] <= rows[:, None]) & mask.bool()[:, None, :]
        allowed = allowed[:, None]
    else:
        allowed = full[:, :, -q:]
    out = F.scaled_dot_product_attention(query, key, value, attn_mask=allowed, scale=attn.scaling)
    h = h[:, -q:] + attn.o_proj(out.transpose(1, 2).reshape(b, q, -1))
    h = h + last.mlp(last.post_attention_layernorm(h))
    return cast(torch.Tensor, norm(h))


class V2VVLA(nn.Module):
    """V2V-VLA (``config.cooperative``) or the non-cooperative SimLingo-style baseline."""

    def __init__(
        self,
        config: ModelConfig,
        backbone: InternVLForConditionalGeneration,
        tokenizer: PreTrainedTokenizerBase,
    ) -> None:
        super().__init__()
        self.config = config
        self.backbone = backbone
        add_lora(config, backbone)
        vision = cast(InternVLVisionConfig, backbone.config.vision_config)
        side = vision.image_size if isinstance(vision.image_size, int) else vision.image_size[0]
        self.processor = VLAProcessor(config, tokenizer, side, int(backbone.config.image_seq_length))
        hidden = cast(Qwen2Config, backbone.config.text_config).hidden_size
        self.target_point_encoder = TargetPointEncoder(
            config.target_point_hidden, hidden, config.target_point_scale
        )
        self.cav_encoder = (
            CavPoseEncoder(config.target_point_hidden, hidden, config.target_point_scale)
            if config.cav_tokens
            else None
        )
        self.waypoint_queries = nn.Parameter(torch.randn(config.n_queries, hidden) * 0.02)  # (Q, H)
        self.path_head = WaypointHead(hidden, config.waypoint_head_hidden)
        self.speed_head = WaypointHead(hidden, config.waypoint_head_hidden)
        self.target_speed_head = (
            SpeedHead(hidden, config.waypoint_head_hidden) if config.speed_query else None
        )
        self._set_trainable()
        self.train()  # from_pretrained leaves the backbone in eval mode; a new module trains

    @classmethod
    def from_config(cls, config: ModelConfig) -> V2VVLA:
        """A new model: random backbone of the config's sizes, or the pretrained one (``pretrained_path``)."""
        tokenizer = load_tokenizer(config.tokenizer_path or config.pretrained_path)
        return cls(config, build_backbone(config, tokenizer), tokenizer)

    def _set_trainable(self) -> None:
        """Everything trains except the LLM base weights under "lora"/"frozen" (embeddings per config)."""
        for p in self.parameters():
            p.requires_grad_(True)
        if self.config.llm_training == "full":
            return
        for name, p in self.backbone.model.language_model.named_parameters():
            p.requires_grad_("lora_" in name)
        emb = self.config.train_embeddings
        self.backbone.get_input_embeddings().weight.requires_grad_(emb)
        self.backbone.lm_head.weight.requires_grad_(emb)  # the same tensor when tied

    @property
    def tokenizer(self) -> PreTrainedTokenizerBase:
        return self.processor.tokenizer

    # ---- embedding ----------------------------------------------------------------------------------
    def embed(self, batch: VLABatch) -> torch.Tensor:
        """(B, L, H): token embeddings with image features and target-point embeddings scattered in."""
        ids = batch.input_ids  # (B, L)
        embeds = self.backbone.get_input_embeddings()(ids)  # (B, L, H)
        tiles = batch.pixel_values.flatten(0, 1).to(embeds.dtype)  # (B*N, 3, S, S)
        image = self.backbone.model.get_image_features(pixel_values=tiles).pooler_output  # (B*N, T, H)
        image_mask = (ids == self.processor.image_token_id).unsqueeze(-1)  # (B, L, 1), B*N*T of them
        if int(image_mask.sum()) != image.shape[0] * image.shape[1]:
            raise ValueError(
                f"{int(image_mask.sum())} image tokens for {image.shape[0]} tiles of {image.shape[1]}"
            )
        embeds = embeds.masked_scatter(image_mask, image.to(embeds.dtype))
        # the encoders' outputs back to the embeddings' dtype: under mixed precision (bf16 autocast on a
        # GPU) a Linear returns bf16 while the embedding table's lookup stays fp32
        points = self.target_point_encoder(batch.target_points.to(embeds.dtype)).to(embeds.dtype)  # (B, 2, H)
        point_mask = (ids == self.processor.target_point_token_id).unsqueeze(-1)  # (B, L, 1), 2 per row
        embeds = embeds.masked_scatter(point_mask, points)
        if self.cav_encoder is not None and batch.cav_poses is not None and len(batch.cav_poses):
            cavs = self.cav_encoder(batch.cav_poses.to(embeds.dtype)).to(embeds.dtype)  # (M, H), prompt order
            cav_mask = (ids == self.processor.cav_point_token_id).unsqueeze(-1)  # (B, L, 1), M in all
            embeds = embeds.masked_scatter(cav_mask, cavs)
        return embeds

    def queries(self, batch_size: int) -> torch.Tensor:
        return self.waypoint_queries.unsqueeze(0).expand(batch_size, -1, -1)  # (B, Q, H)

    def waypoints(self, query_states: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, Q, H) -> path (B, n_path, 2), speed waypoints (B, n_speed, 2)."""
        first = 1 if self.config.speed_query else 0  # the speed query comes first
        n = first + self.config.n_path
        return self.path_head(query_states[:, first:n]), self.speed_head(
            query_states[:, n : n + self.config.n_speed]
        )

    def speeds(self, query_states: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
        """(B, Q, H) -> target speed (B,) [m/s] and stop logit (B,) from the speed query (``speed_query``).
        It is the first query: the last one's state also predicts the answer's first token."""
        if self.target_speed_head is None:
            return None
        return cast(tuple[torch.Tensor, torch.Tensor], self.target_speed_head(query_states[:, 0]))

    # ---- training forward ---------------------------------------------------------------------------
    def forward(self, batch: VLABatch) -> VLAOutput:
        """One pass over prompt + waypoint queries + answer (teacher forcing; the answer when the batch has
        one). The answer's i-th token is predicted at the position before it: the last query for the
        first token."""
        b, length = batch.input_ids.shape
        q = self.waypoint_queries.shape[0]
        parts = [self.embed(batch), self.queries(b)]
        masks = [batch.attention_mask, batch.attention_mask.new_ones(b, q)]
        if batch.answer_ids is not None:  # padding (label IGNORE_INDEX) masked out
            parts.append(self.backbone.get_input_embeddings()(batch.answer_ids))
            masks.append(
                torch.ones_like(batch.answer_ids)
                if batch.labels is None
                else (batch.labels != IGNORE_INDEX).long()
            )
        embeds, mask = torch.cat(parts, dim=1), torch.cat(masks, dim=1)  # (B, L+Q+A, H), (B, L+Q+A)
        lm = self.backbone.model.language_model
        attend, pos = self._attention(batch, mask)
        states = lm(inputs_embeds=embeds, attention_mask=attend, position_ids=pos).last_hidden_state
        path, speed = self.waypoints(states[:, length : length + q])  # (B, n_path, 2), (B, n_speed, 2)
        out = VLAOutput(path=path, speed_waypoints=speed)
        speeds = self.speeds(states[:, length : length + q])
        if speeds is not None:
            out.target_speed, out.stop_logit = speeds
        if batch.answer_ids is not None:
            out.logits = self.backbone.lm_head(states[:, length + q - 1 : -1])  # (B, A, V)
        if batch.labels is not None and batch.path is not None and batch.speed_waypoints is not None:
            assert out.logits is not None
            out.lm_loss = answer_loss(out.logits, batch.labels)
            out.waypoint_loss = waypoint_loss(path, batch.path) + waypoint_loss(speed, batch.speed_waypoints)
            out.speed_loss = out.waypoint_loss.new_zeros(())
            if out.target_speed is not None and out.stop_logit is not None:
                if batch.target_speed is None or batch.stop is None:
                    raise ValueError("a model with speed_query trains on rows with target_speed")
                out.speed_loss = speed_loss(out.target_speed, out.stop_logit, batch.target_speed, batch.stop)
            out.loss = out.lm_loss + out.waypoint_loss + out.speed_loss
        return out

    def _attention(self, batch: VLABatch, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(attention mask, position ids) of prompt + queries (+ answer) with padding mask ``mask``: the 2D
        mask as it is, or with ``path_inputs="ego"`` the 4D mask of :func:`ego_attention`."""
        answer = mask.shape[1] - batch.input_ids.shape[1] - self.config.n_queries
        ego = sequence_ego(batch.ego_mask, self.config, answer)
        if ego is None:
            return mask, positions(mask)
        return ego_attention(mask, ego)

    # ---- closed-loop inference ----------------------------------------------------------------------
    @torch.no_grad()
    def predict(
        self, batch: VLABatch | list[dict[str, Any]], max_new_tokens: int | None = None
    ) -> VLAPrediction:
        """The waypoints of every row from one pass over prompt + queries (all CAVs of a tick in one
        batch), then greedy text on the same KV cache until ``</s>`` or ``max_new_tokens`` (default
        ``config.max_answer_tokens``). ``max_new_tokens=0``: waypoints only, no decoding (the closed loop's
        ticks between two language ticks), the last layer at the queries alone (:func:`query_states`);
        the waypoints do not depend on it."""
        was_training = self.training
        self.eval()
        try:
            return self._predict(
                batch, self.config.max_answer_tokens if max_new_tokens is None else max_new_tokens
            )
        finally:
            self.train(was_training)

    def _predict(self, batch: VLABatch | list[dict[str, Any]], max_new_tokens: int) -> VLAPrediction:
        device = self.waypoint_queries.device
        batch = (self.processor(batch, with_answer=False) if isinstance(batch, list) else batch).to(device)
        if batch.answer_ids is not None:
            raise ValueError("predict takes prompts: batch the rows with processor(rows, with_answer=False)")
        b, q = len(batch), self.waypoint_queries.shape[0]
        mask = torch.cat([batch.attention_mask, batch.attention_mask.new_ones(b, q)], dim=1)  # (B, L+Q)
        embeds = torch.cat([self.embed(batch), self.queries(b)], dim=1)  # (B, L+Q, H)
        lm = self.backbone.model.language_model
        answer_ids: list[list[int]] = [[] for _ in range(b)]
        if max_new_tokens == 0:  # waypoints only: the last layer at the query positions alone
            states = query_states(lm, embeds, mask, q, sequence_ego(batch.ego_mask, self.config))
        else:
            attend, pos = self._attention(batch, mask)
            out = lm(inputs_embeds=embeds, attention_mask=attend, position_ids=pos, use_cache=True)
            states = out.last_hidden_state[:, -q:]
        path, speed = self.waypoints(states)
        speeds = self.speeds(states)
        if max_new_tokens:
            answer, keep = self._greedy(out, mask, max_new_tokens)
            answer_ids = [row[k].tolist() for row, k in zip(answer.cpu(), keep.cpu(), strict=True)]
        text = [str(self.tokenizer.decode(a, skip_special_tokens=True)).strip() for a in answer_ids]
        partner = [parse_partner(t) if self.config.cooperative else -1 for t in text]
        return VLAPrediction(
            path=path,
            speed_waypoints=speed,
            text=text,
            partner=partner,
            answer_ids=answer_ids,
            target_speed=None if speeds is None else speeds[0],
            stop_prob=None if speeds is None else torch.sigmoid(speeds[1]),
        )

    def _greedy(self, out: Any, mask: torch.Tensor, max_new_tokens: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Greedy decoding after the prefill ``out`` (prompt + queries, with its KV cache) of attention mask
        ``mask`` (B, L+Q), feeding each token at once. Returns the answer ids (B, n) (pad after a row's
        ``</s>``; ``</s>`` forced after ``max_new_tokens``) and which of them belong to the answer (B, n)."""
        lm, head = self.backbone.model.language_model, self.backbone.lm_head
        embed = self.backbone.get_input_embeddings()
        eos, pad = self.processor.eos_token_id, self.processor.pad_token_id
        cache_arg, cache = _kv_cache(lm, out)
        alive = torch.ones(mask.shape[0], dtype=torch.bool, device=mask.device)  # no </s> yet
        tokens, keep = [], []
        for step in range(max_new_tokens + 1):
            logits = head(out.last_hidden_state[:, -1])  # (B, V)
            best = (
                logits.argmax(-1) if step < max_new_tokens else torch.full_like(alive, eos, dtype=torch.long)
            )
            token = torch.where(alive, best, pad)  # (B,)
            tokens.append(token)
            keep.append(alive.clone())
            alive = alive & (token != eos)
            if not alive.any():
                break
            mask = torch.cat([mask, keep[-1].long()[:, None]], dim=1)
            out = lm(
                inputs_embeds=embed(token[:, None]),
                attention_mask=mask,
                position_ids=positions(mask)[:, -1:],
                use_cache=True,
                **{cache_arg: cache},
            )
        return torch.stack(tokens, dim=1), torch.stack(keep, dim=1)

    # ---- persistence ----------------------------------------------------------------------------------
    def save_pretrained(self, directory: str | Path) -> None:
        """``vla_config.json``, ``backbone/config.json``, ``tokenizer/``, ``model.safetensors`` (all weights:
        backbone, LoRA adapters, heads); loading needs nothing else."""
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        meta = {"format_version": FORMAT_VERSION, "config": self.config.to_dict()}
        (out / CONFIG_FILE).write_text(json.dumps(meta, indent=2) + "\n")
        self.backbone.config.save_pretrained(str(out / BACKBONE_DIR))
        self.tokenizer.save_pretrained(str(out / TOKENIZER_DIR))
        save_model(self, str(out / WEIGHTS_FILE))

    @classmethod
    def from_pretrained(cls, directory: str | Path, device: torch.device | str = "cpu") -> V2VVLA:
        """A model saved by :meth:`save_pretrained` (never the base InternVL directory: use
        :meth:`from_config` with ``pretrained_path`` for that)."""
        src = Path(directory)
        meta = json.loads((src / CONFIG_FILE).read_text())
        if meta.get("format_version") != FORMAT_VERSION:
            raise ValueError(f"{src}: format_version {meta.get('format_version')}, expected {FORMAT_VERSION}")
        config = ModelConfig.from_dict(meta["config"])
        backbone_cfg = InternVLConfig.from_pretrained(str(src / BACKBONE_DIR))
        mismatch = size_mismatch(config, backbone_cfg)
        if mismatch:
            raise ValueError(
                f"{src / CONFIG_FILE} does not describe the weights in {src}: {mismatch} (a config from "
                "another model size; save the checkpoint again with save_pretrained)"
            )
        backbone = InternVLForConditionalGeneration(backbone_cfg)
        backbone.set_attn_implementation(config.attn_implementation)
        model = cls(config, backbone, load_tokenizer(src / TOKENIZER_DIR, add=()))
        load_model(model, str(src / WEIGHTS_FILE), strict=True, device=str(device))
        return model.to(device)

    def parameter_counts(self) -> dict[str, int]:
        """Parameters per part (tied embeddings counted once)."""

        def count(module: nn.Module) -> int:
            return sum(p.numel() for p in module.parameters())

        lm = self.backbone.model.language_model
        lora = sum(p.numel() for n, p in lm.named_parameters() if "lora_" in n)
        heads = sum(
            count(m)
            for m in (
                self.target_point_encoder,
                self.cav_encoder,
                self.path_head,
                self.speed_head,
                self.target_speed_head,
            )
            if m is not None
        )
        head = self.backbone.lm_head.weight
        untied = head is not self.backbone.get_input_embeddings().weight
        return {
            "vision": count(self.backbone.model.vision_tower),
            "projector": count(self.backbone.model.multi_modal_projector),
            "language_model": count(lm) - lora,
            "lm_head": head.numel() if untied else 0,  # 0 when tied to the token embeddings
            "lora": lora,
            "driving_heads": heads + self.waypoint_queries.numel(),
            "total": count(self),
            "trainable": sum(p.numel() for p in self.parameters() if p.requires_grad),
        }
