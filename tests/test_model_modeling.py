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
from cmudrive.model.modeling import answer_loss
from cmudrive.model.processor import IGNORE_INDEX
from tests.model_rows import make_row, rows

torch.set_num_threads(1)


def tiny(**overrides: object) -> V2VVLA:
    torch.manual_seed(0)
    return V2VVLA.from_config(get_config("tiny", **overrides)).eval()


@pytest.fixture(scope="module")
def model() -> V2VVLA:
    return tiny()


def test_tiny_has_a_few_million_parameters(model: V2VVLA) -> None:
    counts = model.parameter_counts()
    assert 1_000_000 < counts["total"] < 5_000_000
    assert counts["trainable"] == counts["total"]  # tiny trains its randomly initialised LLM fully
    assert counts["lora"] == 0


def test_forward_shapes_and_loss(model: V2VVLA) -> None:
    batch = model.processor(rows(3))
    out = model(batch)
    b, length = batch.input_ids.shape
    assert out.logits is not None and out.logits.shape == (b, length, len(model.tokenizer))
    assert out.path is not None and out.path.shape == (3, 20, 2)
    assert out.speed_waypoints is not None and out.speed_waypoints.shape == (3, 10, 2)
    assert out.loss is not None and torch.isfinite(out.loss)
    assert torch.allclose(out.loss, out.lm_loss + out.waypoint_loss)  # type: ignore[operator]
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
    batch = model.processor(rows(2))
    labels = batch.labels
    assert labels is not None
    logits = torch.randn(*batch.input_ids.shape, 50)
    labels = labels.clamp(max=49).where(labels == IGNORE_INDEX, labels % 50)
    base = answer_loss(logits, labels)
    predicts_answer = torch.zeros_like(labels, dtype=torch.bool)
    predicts_answer[:, :-1] = labels[:, 1:] != IGNORE_INDEX  # position t predicts token t+1
    noisy = logits.clone()
    noisy[~predicts_answer] += 10 * torch.randn_like(noisy[~predicts_answer])
    assert torch.allclose(answer_loss(noisy, labels), base)  # prompt/image/pad positions are ignored
    noisy[predicts_answer] += 10 * torch.randn_like(noisy[predicts_answer])
    assert not torch.allclose(answer_loss(noisy, labels), base)
    manual = torch.nn.functional.cross_entropy(
        logits[predicts_answer], labels[:, 1:][labels[:, 1:] != IGNORE_INDEX]
    )
    assert torch.allclose(base, manual)


def test_model_loss_is_the_cross_entropy_of_the_answer_tokens(model: V2VVLA) -> None:
    batch = model.processor(rows(2))
    assert batch.labels is not None
    out = model(batch)
    assert out.logits is not None and out.lm_loss is not None
    answer = batch.labels[:, 1:] != IGNORE_INDEX  # (B, L-1): targets of positions 0..L-2
    manual = torch.nn.functional.cross_entropy(out.logits[:, :-1][answer], batch.input_ids[:, 1:][answer])
    assert torch.allclose(out.lm_loss, manual)
    prompt = batch.labels == IGNORE_INDEX
    unmasked = VLABatch(**{**batch.__dict__, "labels": torch.where(prompt, batch.input_ids, batch.labels)})
    assert model(unmasked).lm_loss.item() != pytest.approx(
        out.lm_loss.item()
    )  # masking is what excludes them


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


def test_baseline_ignores_bev_and_other_cavs() -> None:
    model = tiny(cooperative=False)
    row = make_row(1)
    batch = model.processor([row])
    assert batch.pixel_values.shape[1] == 2
    changed = model.processor([{**row, "merged_bev": None, "other_cavs": [[4, 20.0, 3.0, 0.0]]}])
    assert torch.equal(model(batch).path, model(changed).path)  # type: ignore[arg-type]
    assert model.predict([row], max_new_tokens=3).partner == [-1]


def test_predict_matches_teacher_forced_forward(model: V2VVLA) -> None:
    """The KV-cache decoding + queries equal one forward pass over prompt + generated answer + </s>."""
    prompts = [{k: v for k, v in r.items() if k != "commentary"} for r in rows(3)]
    pred = model.predict(prompts, max_new_tokens=6)
    assert pred.path.shape == (3, 20, 2) and pred.speed_waypoints.shape == (3, 10, 2)
    assert len(pred.text) == 3 and all(a[-1] == model.processor.eos_token_id for a in pred.answer_ids)
    assert all(1 <= len(a) <= 7 for a in pred.answer_ids)
    for i, row in enumerate(prompts):
        prompt = model.processor([row])
        ids = torch.cat([prompt.input_ids, torch.tensor([pred.answer_ids[i]])], dim=1)
        full = VLABatch(**{**prompt.__dict__, "input_ids": ids, "attention_mask": torch.ones_like(ids)})
        out = model(full)
        assert torch.allclose(out.path[0], pred.path[i], atol=1e-4)  # type: ignore[index]
        assert torch.allclose(out.speed_waypoints[0], pred.speed_waypoints[i], atol=1e-4)  # type: ignore[index]
        greedy = out.logits[0, prompt.input_ids.shape[1] - 1 : -2].argmax(-1)  # type: ignore[index]
        generated = torch.tensor(pred.answer_ids[i][:-1])
        assert torch.equal(greedy[: len(generated)], generated)


def test_predict_without_text_puts_queries_after_eos(model: V2VVLA) -> None:
    pred = model.predict([make_row(0), make_row(1)], max_new_tokens=0)
    assert pred.text == ["", ""] and pred.answer_ids == [[model.processor.eos_token_id]] * 2


def test_lora_adapts_every_linear_layer_of_the_llm_only() -> None:
    model = tiny(llm_training="lora", lora={"r": 4, "alpha": 8})
    lm = model.backbone.model.language_model
    adapted = {n.rsplit(".lora_A", 1)[0] for n, _ in lm.named_parameters() if ".lora_A" in n}
    linear = {n for n, m in lm.named_modules() if isinstance(m, torch.nn.Linear) and "lora_" not in n}
    assert {n.removesuffix(".base_layer") for n in linear} == adapted  # no plain nn.Linear left in the LLM
    assert len(adapted) == 7 * 4  # q, k, v, o, gate, up, down in each of the 4 layers
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


def test_predict_with_given_answers_equals_the_decoding_that_produced_them(model: V2VVLA) -> None:
    """The closed loop's low-rate language: queries after an earlier answer, in one pass, give the
    waypoints the decoding gave (rows with answers of different lengths in one batch)."""
    prompts = [{k: v for k, v in r.items() if k != "commentary"} for r in rows(3)]
    pred = model.predict(prompts, max_new_tokens=5)
    answers = [
        pred.answer_ids[0],
        [*pred.answer_ids[1][:2], model.processor.eos_token_id],
        pred.answer_ids[2],
    ]
    again = model.predict(prompts, answers=answers)
    assert again.answer_ids == answers
    assert torch.allclose(again.path[0], pred.path[0], atol=1e-4)
    assert torch.allclose(again.speed_waypoints[2], pred.speed_waypoints[2], atol=1e-4)
    assert not torch.allclose(again.path[1], pred.path[1], atol=1e-4) or len(pred.answer_ids[1]) <= 3
    with pytest.raises(ValueError, match="answers for"):
        model.predict(prompts, answers=answers[:2])
