"""V2V-VLA on the tiny configuration: shapes, loss, answer-only masking, target points, the baseline,
the KV-cache prediction, LoRA, save -> load."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("torch", reason="the model needs the 'model' extra (torch, transformers, peft)")
pytest.importorskip("transformers", reason="the model needs the 'model' extra (torch, transformers, peft)")
pytest.importorskip("peft", reason="the model needs the 'model' extra (torch, transformers, peft)")

import torch

from cmudrive.model import V2VVLA, VLABatch, get_config
from cmudrive.model.modeling import answer_loss, query_states, sequence_ego
from cmudrive.model.processor import IGNORE_INDEX
from tests.model_rows import make_row, rows

torch.set_num_threads(1)

# transformers' deprecation warnings (e.g. the KV cache's old keyword) would print on every closed-loop
# tick of an evaluation: the model must use the names of the installed release.
pytestmark = pytest.mark.filterwarnings("error::FutureWarning")


def tiny(**overrides: object) -> V2VVLA:
    torch.manual_seed(0)
    return V2VVLA.from_config(get_config("tiny", **overrides)).eval()


@pytest.fixture(scope="module")
def model() -> V2VVLA:
    return tiny()


def test_tiny_is_sized_for_the_closed_loop_budget(model: V2VVLA) -> None:
    """0.66 M parameters: 16 CAVs per 50 ms tick on a 2-core CPU sets the size (docs/model.md)."""
    counts = model.parameter_counts()
    assert 500_000 < counts["total"] < 2_000_000
    assert counts["trainable"] == counts["total"]  # tiny trains its randomly initialised LLM fully
    assert counts["lora"] == 0


def test_forward_shapes_and_loss(model: V2VVLA) -> None:
    batch = model.processor(rows(3))
    out = model(batch)
    assert batch.answer_ids is not None
    b, length = batch.answer_ids.shape
    assert out.logits is not None and out.logits.shape == (
        b,
        length,
        len(model.tokenizer),
    )  # one per answer token
    assert out.path is not None and out.path.shape == (3, 20, 2)
    assert out.speed_waypoints is not None and out.speed_waypoints.shape == (3, 10, 2)
    assert out.loss is not None and torch.isfinite(out.loss)
    assert out.target_speed is not None and out.target_speed.shape == (3,) and (out.target_speed >= 0).all()
    assert out.stop_logit is not None and out.stop_logit.shape == (3,)
    assert torch.allclose(out.loss, out.lm_loss + out.waypoint_loss + out.speed_loss)  # type: ignore[operator]
    assert abs(out.lm_loss.item() - float(torch.log(torch.tensor(len(model.tokenizer))))) < 1.0  # ~uniform


def test_overfits_four_samples() -> None:
    model = tiny().train()
    batch = model.processor(rows(4))
    opt = torch.optim.AdamW(model.parameters(), lr=2e-3)
    losses = []
    for _ in range(30):
        out = model(batch)
        assert out.loss is not None
        opt.zero_grad()
        out.loss.backward()
        opt.step()
        losses.append(out.loss.item())
    assert losses[-1] < 0.3 * losses[0], losses


def test_loss_reads_answer_tokens_only(model: V2VVLA) -> None:
    batch = model.processor(rows(2))  # answers of different lengths: the shorter one is padded
    labels = batch.labels
    assert labels is not None and (labels == IGNORE_INDEX).any()
    logits = torch.randn(*labels.shape, 50)
    labels = labels.where(labels == IGNORE_INDEX, labels % 50)
    base = answer_loss(logits, labels)
    counted = labels != IGNORE_INDEX  # logits[:, i] predicts labels[:, i]
    noisy = logits.clone()
    noisy[~counted] += 10 * torch.randn_like(noisy[~counted])
    assert torch.allclose(answer_loss(noisy, labels), base)  # padding is ignored
    noisy[counted] += 10 * torch.randn_like(noisy[counted])
    assert not torch.allclose(answer_loss(noisy, labels), base)
    assert torch.allclose(base, torch.nn.functional.cross_entropy(logits[counted], labels[counted]))


def test_model_loss_is_the_cross_entropy_of_the_answer_tokens(model: V2VVLA) -> None:
    batch = model.processor(rows(2))
    assert batch.labels is not None and batch.answer_ids is not None
    out = model(batch)
    assert out.logits is not None and out.lm_loss is not None
    answer = batch.labels != IGNORE_INDEX
    manual = torch.nn.functional.cross_entropy(out.logits[answer], batch.answer_ids[answer])
    assert torch.allclose(out.lm_loss, manual)
    unmasked = VLABatch(**{**batch.__dict__, "labels": batch.answer_ids})  # padding counted as a target
    assert model(unmasked).lm_loss.item() != pytest.approx(out.lm_loss.item())


def test_target_points_reach_the_waypoints(model: V2VVLA) -> None:
    batch = model.processor([make_row(0)])
    moved = VLABatch(**{**batch.__dict__, "target_points": batch.target_points + torch.tensor([0.0, 8.0])})
    a, b, again = model(batch), model(moved), model(batch)
    assert torch.equal(a.path, again.path)  # type: ignore[arg-type]
    assert not torch.allclose(a.path, b.path)  # type: ignore[arg-type]
    assert not torch.allclose(a.speed_waypoints, b.speed_waypoints)  # type: ignore[arg-type]


def test_cooperative_model_reads_the_bev_and_the_other_cavs(model: V2VVLA) -> None:
    row = make_row(0)
    base = model(model.processor([row])).path
    other_bev = model(model.processor([{**row, "merged_bev": make_row(5)["merged_bev"]}])).path
    other_cavs = model(model.processor([{**row, "other_cavs": [[4, 20.0, 3.0, 0.0]]}])).path
    assert not torch.allclose(base, other_bev) and not torch.allclose(base, other_cavs)  # type: ignore[arg-type]


def test_another_cavs_pose_reaches_the_waypoints_through_its_embedding(model: V2VVLA) -> None:
    """cav_tokens: the prompt says only "4<CAV_POINT>"; where CAV 4 is and how it heads come in through the
    pose MLP, so moving or turning it changes the outputs while the tokens stay the same."""
    row = {**make_row(0), "other_cavs": [[4, 20.0, 3.0, 0.0]]}
    batch = model.processor([row])
    moved = model.processor([{**row, "other_cavs": [[4, 20.0, -3.0, 0.0]]}])
    turned = model.processor([{**row, "other_cavs": [[4, 20.0, 3.0, 3.0]]}])
    assert torch.equal(batch.input_ids, moved.input_ids) and torch.equal(batch.input_ids, turned.input_ids)
    base = model(batch).path
    assert not torch.allclose(base, model(moved).path) and not torch.allclose(base, model(turned).path)  # type: ignore[arg-type]


def test_predict_gives_the_speed_querys_target_speed_and_stop_probability(model: V2VVLA) -> None:
    prompts = [{k: v for k, v in r.items() if k != "commentary"} for r in rows(3)]
    silent, talking = model.predict(prompts, max_new_tokens=0), model.predict(prompts, max_new_tokens=4)
    out = model(model.processor(prompts))
    assert silent.target_speed is not None and silent.stop_prob is not None
    assert torch.allclose(silent.target_speed, out.target_speed, atol=1e-5)  # type: ignore[arg-type]
    assert torch.allclose(silent.stop_prob, torch.sigmoid(out.stop_logit), atol=1e-5)  # type: ignore[arg-type]
    assert torch.allclose(silent.target_speed, talking.target_speed, atol=1e-5)  # type: ignore[arg-type]
    legacy = tiny(speed_query=False).predict(prompts, max_new_tokens=0)
    assert legacy.target_speed is None and legacy.stop_prob is None


def test_the_speed_loss_is_smooth_l1_of_the_target_speed_plus_the_stop_cross_entropy(model: V2VVLA) -> None:
    """It reads the first query (the last one also predicts the answer's first token) and trains it."""
    batch = model.processor(rows(4))
    out = model(batch)
    expected = torch.nn.functional.smooth_l1_loss(out.target_speed, batch.target_speed)  # type: ignore[arg-type]
    expected = expected + torch.nn.functional.binary_cross_entropy_with_logits(out.stop_logit, batch.stop)  # type: ignore[arg-type]
    assert torch.allclose(out.speed_loss, expected)  # type: ignore[arg-type]
    model.zero_grad()
    out.speed_loss.backward()  # type: ignore[union-attr]
    grad = model.waypoint_queries.grad
    assert grad is not None and grad[0].abs().sum() > 0  # the speed query
    assert grad[1:].abs().sum() == 0  # the speed loss reaches no waypoint query directly
    model.zero_grad()


def test_baseline_ignores_bev_and_other_cavs() -> None:
    model = tiny(cooperative=False)
    row = make_row(1)
    batch = model.processor([row])
    assert batch.pixel_values.shape[1] == 2
    changed = model.processor([{**row, "merged_bev": None, "other_cavs": [[4, 20.0, 3.0, 0.0]]}])
    assert torch.equal(model(batch).path, model(changed).path)  # type: ignore[arg-type]
    assert model.predict([row], max_new_tokens=3).partner == [-1]


def test_predict_matches_teacher_forced_forward(model: V2VVLA) -> None:
    """Waypoints from the prompt + queries pass, then KV-cache decoding, equal one forward pass over
    prompt + queries + the generated answer."""
    prompts = [{k: v for k, v in r.items() if k != "commentary"} for r in rows(3)]
    pred = model.predict(prompts, max_new_tokens=6)
    assert pred.path.shape == (3, 20, 2) and pred.speed_waypoints.shape == (3, 10, 2)
    assert len(pred.text) == 3 and all(a[-1] == model.processor.eos_token_id for a in pred.answer_ids)
    assert all(1 <= len(a) <= 7 for a in pred.answer_ids)
    for i, row in enumerate(prompts):
        prompt = model.processor([row])
        full = VLABatch(**{**prompt.__dict__, "answer_ids": torch.tensor([pred.answer_ids[i]])})
        out = model(full)
        assert torch.allclose(out.path[0], pred.path[i], atol=1e-4)  # type: ignore[index]
        assert torch.allclose(out.speed_waypoints[0], pred.speed_waypoints[i], atol=1e-4)  # type: ignore[index]
        greedy = out.logits[0].argmax(-1)  # type: ignore[index]
        generated = torch.tensor(pred.answer_ids[i][:-1])  # the last token may be the forced </s>
        assert torch.equal(greedy[: len(generated)], generated)


def test_waypoints_do_not_wait_for_language(model: V2VVLA) -> None:
    """max_new_tokens=0 (the closed loop's silent ticks) gives the talking ticks' waypoints, no text."""
    batch = [make_row(0), make_row(1)]
    silent, talking = model.predict(batch, max_new_tokens=0), model.predict(batch, max_new_tokens=5)
    assert silent.text == ["", ""] and silent.answer_ids == [[], []] and silent.partner == [-1, -1]
    assert torch.allclose(silent.path, talking.path, atol=1e-5)
    assert torch.allclose(silent.speed_waypoints, talking.speed_waypoints, atol=1e-5)


@pytest.mark.parametrize(
    "overrides",
    [
        {},
        {"text": {"num_layers": 3, "num_heads": 4, "num_kv_heads": 1}},
        {"llm_training": "lora"},
        {"path_inputs": "ego"},
    ],
    ids=["tiny", "3-layer-gqa", "lora", "ego-path"],
)
def test_query_states_equal_the_full_pass_at_the_queries(overrides: dict[str, object]) -> None:
    """The silent ticks' pass (the last layer at the queries alone) gives the full pass's final states at
    the query positions, for rows of different prompt lengths (left padding), grouped-query attention,
    LoRA adapters (made non-zero, so that skipping them would show) and the ego path's attention mask."""
    model = tiny(**overrides)
    with torch.no_grad():
        for name, p in model.named_parameters():
            if "lora_B" in name:
                p.normal_(0.0, 0.05)
    prompts = [{k: v for k, v in r.items() if k != "commentary"} for r in rows(3)]
    batch = model.processor(prompts, with_answer=False)
    q = model.waypoint_queries.shape[0]
    mask = torch.cat([batch.attention_mask, batch.attention_mask.new_ones(3, q)], dim=1)
    assert (batch.attention_mask == 0).any()  # the rows are padded to a common length
    lm = model.backbone.model.language_model
    layers = lm.layers
    with torch.no_grad():
        embeds = torch.cat([model.embed(batch), model.queries(3)], dim=1)
        attend, pos = model._attention(batch, mask)
        full = lm(inputs_embeds=embeds, attention_mask=attend, position_ids=pos).last_hidden_state
        fast = query_states(lm, embeds, mask, q, sequence_ego(batch.ego_mask, model.config))
    assert fast.shape == (3, q, full.shape[-1])
    assert torch.allclose(fast, full[:, -q:], atol=1e-5)
    assert lm.layers is layers and not isinstance(lm.norm, torch.nn.Identity)  # the model is put back


def test_lora_adapts_every_linear_layer_of_the_llm_only() -> None:
    model = tiny(llm_training="lora", lora={"r": 4, "alpha": 8})
    lm = model.backbone.model.language_model
    adapted = {n.rsplit(".lora_A", 1)[0] for n, _ in lm.named_parameters() if ".lora_A" in n}
    linear = {n for n, m in lm.named_modules() if isinstance(m, torch.nn.Linear) and "lora_" not in n}
    assert {n.removesuffix(".base_layer") for n in linear} == adapted  # no plain nn.Linear left in the LLM
    assert model.config.text is not None
    assert len(adapted) == 7 * model.config.text.num_layers  # q, k, v, o, gate, up, down in each layer
    assert not any("lora_" in n for n, _ in model.backbone.model.vision_tower.named_parameters())
    trainable_lm = {n for n, p in lm.named_parameters() if p.requires_grad}
    assert trainable_lm and all("lora_" in n for n in trainable_lm)
    assert all(p.requires_grad for p in model.backbone.model.vision_tower.parameters())
    assert not model.backbone.get_input_embeddings().weight.requires_grad


def test_save_load_gives_identical_outputs(tmp_path: Path) -> None:
    model = tiny(llm_training="lora", lora={"r": 4, "alpha": 8})
    with torch.no_grad():  # non-zero adapters, so that losing them on load would show
        for name, p in model.named_parameters():
            if "lora_B" in name:
                p.normal_(0.0, 0.05)
    model.save_pretrained(tmp_path)
    loaded = V2VVLA.from_pretrained(tmp_path).eval()
    assert loaded.config == model.config
    batch = model.processor(rows(2))
    a, b = model(batch), loaded(batch)
    assert torch.equal(a.logits, b.logits) and torch.equal(a.path, b.path)  # type: ignore[arg-type]
    prompts = [{k: v for k, v in r.items() if k != "commentary"} for r in rows(2)]
    assert model.predict(prompts, 4).text == loaded.predict(prompts, 4).text
    assert (tmp_path / "model.safetensors").stat().st_size < 20e6


def test_a_batch_whose_image_tokens_do_not_match_its_tiles_is_rejected(model: V2VVLA) -> None:
    batch = model.processor([make_row(0)])
    ids = batch.input_ids.clone()
    ids[ids == model.processor.image_token_id] = model.processor.pad_token_id
    with pytest.raises(ValueError, match="image tokens"):
        model(VLABatch(**{**batch.__dict__, "input_ids": ids}))


def test_predict_refuses_a_training_batch(model: V2VVLA) -> None:
    with pytest.raises(ValueError, match="with_answer=False"):
        model.predict(model.processor(rows(1)))


def test_a_batch_predicts_what_its_rows_predict_alone(model: V2VVLA) -> None:
    """Left padding does not leak: three CAVs with prompts of different lengths in one batch get the
    waypoints and text each gets alone."""
    prompts = [{k: v for k, v in r.items() if k != "commentary"} for r in rows(3)]
    together = model.predict(prompts, max_new_tokens=5)
    for i, row in enumerate(prompts):
        alone = model.predict([row], max_new_tokens=5)
        assert torch.allclose(alone.path[0], together.path[i], atol=1e-4)
        assert alone.answer_ids[0] == together.answer_ids[i]
    silent = model.predict(prompts, max_new_tokens=0)  # the waypoints-only pass pads the same way
    for i, row in enumerate(prompts):
        alone_silent = model.predict([row], max_new_tokens=0)
        assert torch.allclose(alone_silent.speed_waypoints[0], silent.speed_waypoints[i], atol=1e-4)


@pytest.mark.parametrize("cooperative", [True, False])
def test_a_forward_pass_under_bf16_autocast_gives_the_fp32_loss(cooperative: bool) -> None:
    """Mixed precision (``cmudrive train`` on a GPU: bf16 autocast over fp32 weights; here the CPU's
    autocast, which casts the same layers) runs the whole model and keeps the loss within bf16's error."""
    model = tiny(cooperative=cooperative)
    batch = model.processor(rows(3))
    with torch.no_grad():
        exact = model(batch)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            mixed = model(batch)
    assert mixed.loss is not None and exact.loss is not None and torch.isfinite(mixed.loss)
    assert abs(float(mixed.loss) - float(exact.loss)) < 0.05 * float(exact.loss)
    assert torch.allclose(mixed.path.float(), exact.path, atol=0.05, rtol=0.05)  # type: ignore[union-attr]


def test_an_ego_path_does_not_depend_on_the_cooperative_inputs() -> None:
    """path_inputs="ego": the same rows with another merged image and other CAVs listed (a different
    number of them, so the prompt's length changes too) give the same path, in training's pass, in the
    waypoints-only pass and in the pass that also decodes language; the speed waypoints, which read the
    cooperative inputs, change."""
    model = tiny(path_inputs="ego")
    a = rows(3)
    b = [{**r, "merged_bev": make_row(9, seed=5)["merged_bev"], "other_cavs": [[5, 20.0, 1.0, 0.0]] * (3 - i)}
         for i, r in enumerate(a)]  # fmt: skip
    assert [len(r["other_cavs"]) for r in a] != [len(r["other_cavs"]) for r in b]
    with torch.no_grad():
        out_a, out_b = model(model.processor(a)), model(model.processor(b))
        pred_a = [model.predict(a, max_new_tokens=n) for n in (0, 3)]
        pred_b = [model.predict(b, max_new_tokens=n) for n in (0, 3)]
    assert out_a.path is not None and out_b.path is not None
    assert torch.allclose(out_a.path, out_b.path, atol=1e-5)
    assert not torch.allclose(out_a.speed_waypoints, out_b.speed_waypoints, atol=1e-3)
    for pa, pb in zip(pred_a, pred_b, strict=True):
        assert torch.allclose(pa.path, pb.path, atol=1e-5)
        assert torch.allclose(pa.path, out_a.path, atol=1e-5)  # the prompt's pass = training's
        assert not torch.allclose(pa.speed_waypoints, pb.speed_waypoints, atol=1e-3)
    plain = tiny()  # every input reaches the path of the paper's model
    with torch.no_grad():
        assert not torch.allclose(plain.predict(a, 0).path, plain.predict(b, 0).path, atol=1e-3)


def test_an_ego_path_prompt_puts_the_cooperative_part_last() -> None:
    """The ego's part of the prompt is the baseline's prompt; the merged image and the other CAVs follow,
    and the batch marks where they start."""
    model, baseline = tiny(path_inputs="ego"), tiny(cooperative=False)
    r = make_row(1)
    ego, base = model.processor.prompt(r), baseline.processor.prompt(r)
    assert ego.startswith(base) and "Other CAVs: 3" in ego[len(base) :]
    batch = model.processor(rows(3), with_answer=False)
    assert batch.ego_mask is not None
    for ids, ego_mask, mask in zip(batch.input_ids, batch.ego_mask, batch.attention_mask, strict=True):
        first = int(torch.nonzero(mask)[0])
        n = int(ego_mask.sum())
        assert ego_mask[first : first + n].all()  # one run from the prompt's first token ...
        assert ids[first + n] == model.processor.image_start_id  # ... to the merged image's <img>
    with pytest.raises(ValueError, match="path_inputs"):
        get_config("tiny", path_inputs="ego", cooperative=False)
