"""The processor: rows (dicts) to tiles, left-padded token ids, answer-only labels and targets."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

pytest.importorskip("torch", reason="the model needs the 'model' extra (torch, transformers, peft)")
pytest.importorskip("transformers", reason="the model needs the 'model' extra (torch, transformers, peft)")

import torch

from cmudrive.model import VLAProcessor, get_config, parse_partner
from cmudrive.model.processor import IGNORE_INDEX, IMAGE_MEAN, IMAGE_STD, _normalise
from tests.model_rows import make_row, rows


@pytest.fixture(scope="module")
def coop() -> VLAProcessor:
    return VLAProcessor.from_config(get_config("tiny"))


@pytest.fixture(scope="module")
def legacy() -> VLAProcessor:
    """The committed checkpoints' inputs: 64 px tiles, bonnet crop, padded BEV, 4 CAVs spelt out."""
    config = get_config(
        "tiny", vision={"image_size": 64, "patch_size": 8}, bonnet_crop=4.8 / 16, bev_fit="pad"
    ).replace(max_other_cavs=4, cav_tokens=False, speed_query=False)
    return VLAProcessor.from_config(config)


@pytest.fixture(scope="module")
def baseline() -> VLAProcessor:
    return VLAProcessor.from_config(get_config("tiny", cooperative=False))


def test_batch_shapes_and_left_padding(coop: VLAProcessor) -> None:
    batch = coop(rows(3))
    b = batch.input_ids.shape[0]
    assert batch.pixel_values.shape == (3, 3, 3, 128, 128)  # 2 camera tiles + 1 BEV tile of 128 px
    assert coop.tokens_per_image == 16  # (128 / 16)^2 patches, pixel shuffle 0.5 -> 16
    assert batch.target_points.shape == (3, 2, 2)
    assert batch.path is not None and batch.path.shape == (3, 20, 2)
    assert batch.speed_waypoints is not None and batch.speed_waypoints.shape == (3, 10, 2)
    assert batch.partner_label is not None and batch.partner_label.tolist() == [-1, 3, -1]
    for i in range(b):
        n_pad = int((batch.attention_mask[i] == 0).sum())
        assert (batch.attention_mask[i, n_pad:] == 1).all()  # padding only on the left
        assert (batch.input_ids[i, :n_pad] == coop.pad_token_id).all()
        assert int((batch.input_ids[i] == coop.image_token_id).sum()) == 3 * 16
        assert int((batch.input_ids[i] == coop.target_point_token_id).sum()) == 2
    # one <CAV_POINT> per listed CAV (rows list 1, 2, 3 CAVs; CAV 7 at 95 m is out of range)
    assert [int((batch.input_ids[i] == coop.cav_point_token_id).sum()) for i in range(b)] == [1, 1, 2]
    assert batch.cav_poses is not None and np.allclose(
        batch.cav_poses.numpy(), [[12.0, -3.5, 0.1], [12.0, -3.5, 0.1], [-6.0, 1.0, 3.1], [12.0, -3.5, 0.1]]
    )  # row order, nearest first within a row
    # speed labels: the query learns the desired speed; rows 0 and 2 go (the expert's target speed 2.5 + i
    # m/s above their 2 + i m/s), row 1 stops (target 0)
    assert batch.target_speed is not None and batch.target_speed.tolist() == [8.0, 0.0, 10.0]
    assert batch.stop is not None and batch.stop.tolist() == [0.0, 1.0, 0.0]
    assert batch.answer_ids is not None and batch.labels is not None
    for i in range(b):  # answers apart, right-padded, each ending with its </s>
        n = int((batch.labels[i] != IGNORE_INDEX).sum())
        assert batch.answer_ids[i, n - 1] == coop.eos_token_id
        assert (batch.answer_ids[i, n:] == coop.pad_token_id).all()
        assert (batch.labels[i, :n] == batch.answer_ids[i, :n]).all()


def test_labels_cover_exactly_the_answer(coop: VLAProcessor) -> None:
    batch = coop([make_row(1)])
    assert batch.labels is not None and batch.answer_ids is not None
    assert torch.equal(batch.labels[0], batch.answer_ids[0])  # one row: no padding, every token counts
    assert batch.labels[0, -1] == coop.eos_token_id
    text = coop.tokenizer.decode(batch.answer_ids[0].tolist(), skip_special_tokens=True)
    assert (
        text == " Turn left. Stop now because of the red light. Communication: CAV 3 can see the pedestrian."
    )
    prompt = coop.tokenizer.decode(batch.input_ids[0].tolist(), skip_special_tokens=True)
    # CAV 7 at 95 m is beyond the 70 m range; target points and CAV poses are embeddings, not text
    assert prompt.endswith(
        "\nCurrent speed: 3.0 m/s. Target waypoint: . Other CAVs: 3. What should the ego do next?"
    )


def test_prompt_only_batch_for_prediction(coop: VLAProcessor) -> None:
    row = {k: v for k, v in make_row(0).items() if k not in ("path", "speed_waypoints", "commentary")}
    batch = coop([row])
    assert batch.labels is None and batch.answer_ids is None and batch.path is None
    assert coop.tokenizer.decode(batch.input_ids[0, -3:]).endswith("next?")


def test_camera_is_two_128_px_tiles_left_and_right_uncropped_unresized(coop: VLAProcessor) -> None:
    """Our renderer draws no bonnet: tiny keeps the whole 256 x 128 camera, pixel for pixel."""
    image = np.random.default_rng(0).integers(0, 256, (128, 256, 3), dtype=np.uint8)
    tiles = coop.camera_tiles(image)
    assert tiles.shape == (2, 3, 128, 128)
    pixel = tiles * IMAGE_STD[None, :, None, None] + IMAGE_MEAN[None, :, None, None]  # back to [0, 1]
    assert np.allclose(pixel[0].transpose(1, 2, 0) * 255, image[:, :128], atol=1e-3)
    assert np.allclose(pixel[1].transpose(1, 2, 0) * 255, image[:, 128:], atol=1e-3)


def test_legacy_camera_tiles_crop_the_bonnet_and_split_left_right(legacy: VLAProcessor) -> None:
    image = np.zeros((128, 256, 3), np.uint8)
    image[:, :128] = (255, 0, 0)  # left half red
    image[:, 128:] = (0, 0, 255)  # right half blue
    image[90:] = (255, 255, 255)  # bottom 38 rows (the bonnet, 4.8/16 of 128) white
    tiles = legacy.camera_tiles(image)
    assert tiles.shape == (2, 3, 64, 64)
    pixel = tiles * IMAGE_STD[None, :, None, None] + IMAGE_MEAN[None, :, None, None]  # back to [0, 1]
    assert np.allclose(pixel[0, :, 4:-4, 4:-4].mean(axis=(1, 2)), [1, 0, 0], atol=0.02)
    assert np.allclose(pixel[1, :, 4:-4, 4:-4].mean(axis=(1, 2)), [0, 0, 1], atol=0.02)
    assert pixel[:, 1, 60:].max() < 0.05  # no white (green channel) from the cropped rows


def test_every_level_of_every_channel_is_normalised_as_imagenet() -> None:
    """Four 64 x 64 tiles whose rows hold the 256 uint8 levels: (level / 255 - mean) / std per channel,
    channels first."""
    level = np.arange(256, dtype=np.uint8).reshape(4, 64, 1, 1)
    tiles = np.ascontiguousarray(np.broadcast_to(level, (4, 64, 64, 3)))  # (N, S, S, 3)
    out = _normalise(tiles)
    assert out.shape == (4, 3, 64, 64) and out.dtype == np.float32
    expected = (tiles.astype(np.float32) / np.float32(255.0) - IMAGE_MEAN) / IMAGE_STD  # (N, S, S, 3)
    assert np.allclose(out, expected.transpose(0, 3, 1, 2), rtol=0, atol=1e-6)


def test_bev_fills_the_tile_half_a_metre_across_three_quarters_along(coop: VLAProcessor) -> None:
    """The 64 m x 96 m grid (128 x 192 cells of 0.5 m) stretched to 128 x 128 px, no padding: 0.5 m per
    pixel across, 0.75 m along the driving direction; a 1.5 m (3-cell) band becomes 2 px tall."""
    bev = np.zeros((192, 128, 3), np.uint8)
    bev[96:99] = 255  # a white band 3 cells tall across the grid, starting 48 m from the top
    bev[:, :2] = (0, 255, 0)  # a green edge column
    tile = coop.bev_tile(bev)[0] * IMAGE_STD[:, None, None] + IMAGE_MEAN[:, None, None]
    assert tile.shape == (3, 128, 128)
    white = np.flatnonzero(tile[2].mean(axis=1) > 0.5)  # blue channel: only the band has it
    assert white.min() >= 63 and white.max() <= 66  # 48 m / 0.75 m per px = row 64
    assert tile[1, :, 0].min() > 0.9  # the grid's edge column is the tile's: no black margin


def test_legacy_bev_is_padded_to_a_square_not_stretched(legacy: VLAProcessor) -> None:
    bev = Image.new("RGB", (128, 192), (255, 255, 255))  # 128 wide, 192 tall: ego driving up
    tile = legacy.bev_tile(bev)[0] * IMAGE_STD[:, None, None] + IMAGE_MEAN[:, None, None]
    assert tile.shape == (3, 64, 64)
    assert tile[:, :, 24:40].min() > 0.95  # the 128 px wide grid covers the middle 2/3
    assert tile[:, :, :8].max() < 0.05 and tile[:, :, -8:].max() < 0.05  # black margins left and right


def test_other_cavs_in_range_nearest_first(coop: VLAProcessor, legacy: VLAProcessor) -> None:
    others = [[5, 40.2, 0.4, 0.0], [9, 3.0, -4.2, 0.0], [1, 0.0, 71.0, 0.0]]
    assert coop.others_text(others) == "Other CAVs: 9<CAV_POINT> 5<CAV_POINT>."  # CAV 1 is beyond 70 m
    assert legacy.others_text(others) == "Other CAVs: CAV 9 at (3, -4), CAV 5 at (40, 0)."
    assert coop.others_text([]) == "Other CAVs: none." == legacy.others_text([])
    many = [[k, float(k + 1), 0.0, 0.0] for k in range(12)]
    assert coop.config.max_other_cavs == 8  # tiny lists the 8 nearest, about 3 tokens each
    assert coop.others_text(many).count("<CAV_POINT>") == 8 and " 7<CAV_POINT>." in coop.others_text(many)
    assert legacy.others_text(many).count("CAV ") == 4 and "CAV 4 " not in legacy.others_text(many)


def test_speed_is_stated_unless_the_configuration_or_a_dropped_row_leaves_it_out(coop: VLAProcessor) -> None:
    row = {**make_row(1), "speed": 4.24}
    assert "Current speed: 4.2 m/s. Target waypoint:" in coop.prompt(row)
    assert "speed" not in coop.prompt({**row, "speed": None})  # speed dropout in training
    blind = VLAProcessor.from_config(get_config("tiny", speed_in_prompt=False))
    assert "speed" not in blind.prompt(row) and "Target waypoint:" in blind.prompt(row)
    # same prompt at any speed: nothing of the speed reaches the model
    assert torch.equal(blind([row]).input_ids, blind([{**row, "speed": 0.0}]).input_ids)


def test_standing_time_is_stated_while_the_cav_stands_rounded_down_to_half_seconds() -> None:
    clocked = VLAProcessor.from_config(get_config("tiny", speed_in_prompt=False, standing_in_prompt=True))
    row = make_row(1)
    assert "Stopped" not in clocked.prompt(row)  # standing -1: it moves, and nothing says how fast
    assert "\nStopped for 0.0 s. Target waypoint:" in clocked.prompt({**row, "standing": 0.0})
    assert "Stopped for 2.5 s. " in clocked.prompt({**row, "standing": 2.74})  # 4 Hz rows and 20 Hz ticks
    assert "Stopped for 2.5 s. " in clocked.prompt({**row, "standing": 2.5})  # read alike
    assert "Stopped for 30.0 s. " in clocked.prompt({**row, "standing": 95.0})  # capped
    assert "Stopped" not in VLAProcessor.from_config(get_config("tiny")).prompt({**row, "standing": 3.0})
    with pytest.raises(ValueError, match="needs 'standing'"):
        clocked.prompt({k: v for k, v in row.items() if k != "standing"})


def test_baseline_takes_no_bev_no_other_cavs_no_communication(baseline: VLAProcessor) -> None:
    row = make_row(1)
    batch = baseline([row])
    assert batch.pixel_values.shape == (1, 2, 3, 128, 128)  # camera tiles only
    text = baseline.tokenizer.decode(batch.input_ids[0], skip_special_tokens=True)
    assert "CAV" not in text and "Communication" not in text
    changed = {**row, "merged_bev": None, "other_cavs": [[1, 5.0, 5.0, 0.0]], "communication": "x"}
    again = baseline([changed])
    assert torch.equal(again.input_ids, batch.input_ids) and torch.equal(
        again.pixel_values, batch.pixel_values
    )


def test_communication_must_name_the_partner_label(coop: VLAProcessor) -> None:
    with pytest.raises(ValueError, match="partner_label 4"):
        coop([{**make_row(1), "partner_label": 4}])
    with pytest.raises(ValueError, match="shape"):
        coop([{**make_row(0), "path": np.zeros((19, 2))}])


def test_parse_partner() -> None:
    assert parse_partner("Stop now. Communication: CAV 12 can see the pedestrian.") == 12
    assert parse_partner("Stop now. Communication: none.") == -1
    assert parse_partner("Follow CAV 2. Communication: none.") == -1  # only the communication sentence counts
    assert parse_partner("Follow the route.") == -1


def test_rows_read_back_from_a_hugging_face_dataset(coop: VLAProcessor) -> None:
    """Image columns come back as PIL images, arrays as nested lists: the processor takes them as they are."""
    datasets = pytest.importorskip("datasets", reason="needs the datasets package")
    built = rows(2)
    for r in built:
        r["path"], r["speed_waypoints"] = r["path"].tolist(), r["speed_waypoints"].tolist()
    ds = datasets.Dataset.from_list(built).cast_column("camera", datasets.Image())
    read = list(ds)
    assert isinstance(read[0]["camera"], Image.Image) and isinstance(read[0]["path"], list)
    a, b = coop(built), coop(read)
    assert torch.equal(a.input_ids, b.input_ids) and torch.equal(a.pixel_values, b.pixel_values)
    assert torch.equal(a.path, b.path)  # type: ignore[arg-type]


def test_processor_is_a_dataloader_collate_fn(coop: VLAProcessor) -> None:
    from torch.utils.data import DataLoader

    batches = list(DataLoader(rows(4), batch_size=2, collate_fn=coop))
    assert [b.input_ids.shape[0] for b in batches] == [2, 2]
    assert torch.equal(batches[1].path, coop(rows(4)[2:]).path)  # type: ignore[arg-type]
