"""Training V2V-VLA on synthetic shards: route-level split, camera-rotation augmentation (image and labels
moved together), exact resumption, logs, the CLI and the baseline flag."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

pytest.importorskip("torch", reason="training needs the 'model' extra (torch, transformers, accelerate)")
pytest.importorskip("accelerate", reason="training needs the 'model' extra (torch, transformers, accelerate)")

import torch
from PIL import Image
from safetensors.torch import load_file
from typer.testing import CliRunner

from cmudrive.cli import app
from cmudrive.data.schema import packed_to_rgb
from cmudrive.data.synthetic import write_synthetic_shards
from cmudrive.model import V2VVLA
from cmudrive.model.augment import YawAugment, rotate_camera, rotate_sample, rotated_frame
from cmudrive.model.dataset import (
    BUCKETS,
    BucketSampler,
    DrivingDataset,
    communication_rows,
    keep_rows,
    load_split,
    recovery_rows,
    repeat_rows,
    sampling_buckets,
    split_routes,
)
from cmudrive.model.train import TrainConfig, train
from cmudrive.sensors.camera import CameraConfig

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("shards")
    write_synthetic_shards(out, routes=3, rows_per_route=12, seed=0)
    return out


# ---- split ------------------------------------------------------------------------------------------
def test_validation_holds_out_whole_routes(data: Path) -> None:
    train_rows, val_rows, val_routes = load_split(TrainConfig(data=str(data), out="unused", val_fraction=0.3))
    assert len(val_routes) == 1 and len(train_rows) == 24 and len(val_rows) == 12
    assert set(val_rows["route_id"]) == set(val_routes)
    assert not set(train_rows["route_id"]) & set(val_routes)
    assert split_routes(["a"], 0.5, 0) == []  # a single route trains
    assert len(split_routes([str(i) for i in range(20)], 0.1, 0)) == 2


def test_recovery_views_train_but_validation_reads_only_the_cavs_own_views(tmp_path: Path) -> None:
    """Every third row seen from 1 m aside: all rows of the training routes train, the validation route
    keeps its 8 own rows; shards from before recovery views (no ``view`` column) still load."""
    from cmudrive.data.schema import COLUMNS, features
    from cmudrive.data.shards import ShardWriter
    from cmudrive.data.synthetic import synthetic_row

    for k in range(3):
        rng = np.random.default_rng([0, k])
        rows = [synthetic_row(f"synthetic_{k}", i, rng) for i in range(12)]
        for i in range(0, 12, 3):
            rows[i]["view"] = [0.0, 1.0, 0.0]
        writer = ShardWriter(tmp_path, f"synthetic_{k}", features().arrow_schema)
        writer.write({c: [r[c] for r in rows] for c in COLUMNS})
        writer.close()
    train_rows, val_rows, _ = load_split(TrainConfig(data=str(tmp_path), out="unused", val_fraction=0.3))
    assert len(train_rows) == 24 and len(val_rows) == 8
    assert np.abs(np.asarray(val_rows["view"])).sum() == 0.0
    assert recovery_rows(train_rows).sum() == 8
    old = tmp_path / "old"
    old.mkdir()
    for f in tmp_path.glob("*.parquet"):  # the same shards without the column
        pq.write_table(pq.read_table(f).drop_columns(["view"]), old / f.name)
    _, old_val, _ = load_split(TrainConfig(data=str(old), out="unused", val_fraction=0.3))
    assert len(old_val) == 12 and "view" not in old_val.column_names


def test_closed_loop_rows_from_another_folder_train_but_never_validate(tmp_path: Path) -> None:
    """An expert collection from before views and drivers, and a closed-loop one on the same routes
    (another driver, every row): together, every closed-loop row of the training routes trains, the
    validation route keeps only its expert rows, and each folder's CAVs keep their own standing clocks."""
    from cmudrive.data.schema import COLUMNS, features
    from cmudrive.data.shards import ShardWriter
    from cmudrive.data.synthetic import synthetic_row
    from cmudrive.model.dataset import closed_loop_rows, load_rows

    expert, learner = tmp_path / "expert", tmp_path / "learner"
    for folder, driver in ((expert, "expert"), (learner, "v2v-vla")):
        folder.mkdir()
        for k in range(3):
            rng = np.random.default_rng([0, k])
            rows = [synthetic_row(f"synthetic_{k}", i, rng) for i in range(12)]
            for r in rows:
                r["driver"] = driver
            writer = ShardWriter(folder, f"synthetic_{k}", features().arrow_schema)
            writer.write({c: [r[c] for r in rows] for c in COLUMNS})
            writer.close()
    for f in expert.glob("*.parquet"):  # an older expert collection: no view, no driver
        pq.write_table(pq.read_table(f).drop_columns(["view", "driver"]), f)
    both = f"{expert},{learner}"
    rows = load_rows(both)
    assert len(rows) == 72 and closed_loop_rows(rows).sum() == 36
    assert np.abs(np.asarray(rows["view"])).sum() == 0.0
    alone = load_rows(str(learner))  # the same standing clocks as the folder read alone
    np.testing.assert_array_equal(np.asarray(rows["standing"])[36:], np.asarray(alone["standing"]))
    train_rows, val_rows, val_routes = load_split(TrainConfig(data=both, out="unused", val_fraction=0.3))
    assert len(train_rows) == 48 and closed_loop_rows(train_rows).sum() == 24
    assert len(val_rows) == 12 and set(val_rows["driver"]) == {"expert"}
    assert set(val_rows["route_id"]) == set(val_routes)


def test_standing_rows_are_thinned_and_every_moving_or_starting_row_kept() -> None:
    """standing_keep=0.25: a quarter of the rows standing still for 2.5 s, all others."""
    import datasets

    n = 1000
    speed = np.r_[np.zeros(400), np.zeros(100), np.full(500, 5.0)]  # stays, starts, moves
    steps = np.r_[np.zeros(400), np.full(100, 0.3), np.full(500, 1.25)]  # [m] per 0.25 s
    waypoints = np.stack([np.outer(steps, np.arange(1, 11)), np.zeros((n, 10))], axis=-1).astype(np.float32)
    ds = datasets.Dataset.from_dict({"speed": speed, "speed_waypoints": waypoints.tolist()})
    keep = keep_rows(ds, 0.25, seed=0)
    assert keep[400:].all()  # starting (3 m in 2.5 s) and moving rows all stay
    assert 60 <= keep[:400].sum() <= 140  # ~100 of the 400 standing rows
    assert np.array_equal(keep, keep_rows(ds, 0.25, seed=0)) and keep_rows(ds, 1.0, seed=0).all()
    with pytest.raises(ValueError, match="standing_keep"):
        TrainConfig(data="d", out="o", standing_keep=0.0)


def test_communication_rows_repeat_in_training_not_in_validation(data: Path) -> None:
    base = TrainConfig(data=str(data), out="unused", val_fraction=0.3)
    train_rows, val_rows, _ = load_split(base)
    talk = int(communication_rows(train_rows).sum())
    assert 0 < talk < len(train_rows)  # the synthetic shards label ~10 % of the rows with a partner
    more_train, more_val, _ = load_split(dataclasses.replace(base, communication_repeat=4))
    assert len(more_train) == len(train_rows) + 3 * talk and communication_rows(more_train).sum() == 4 * talk
    assert len(more_val) == len(val_rows)  # validation measures the collection as it is
    assert repeat_rows(np.array([7, 8, 9]), np.array([False, True, False]), 3).tolist() == [7, 8, 8, 8, 9]
    with pytest.raises(ValueError, match="communication_repeat"):
        TrainConfig(data="d", out="o", communication_repeat=0)


def test_cooperative_dropout_shows_a_share_of_rows_without_the_other_cavs(data: Path) -> None:
    train_rows, _, _ = load_split(TrainConfig(data=str(data), out="unused", val_fraction=0.0))
    full = DrivingDataset(train_rows, None, seed=1)
    alone = DrivingDataset(train_rows, None, seed=1, cooperative_dropout=0.5)
    empty = packed_to_rgb(np.zeros((192, 128), np.uint8))  # the default 0.5 m grid, 96 x 64 m
    dropped = []
    for i in range(len(train_rows)):
        row, seen = alone[i], full[i]
        assert seen["other_cavs"]  # every synthetic row has other CAVs
        assert np.array_equal(row["path"], seen["path"]) and row["commentary"] == seen["commentary"]
        if row["other_cavs"]:  # left as it was
            assert row["other_cavs"] == seen["other_cavs"] and row["partner_label"] == seen["partner_label"]
            assert np.array_equal(np.asarray(row["merged_bev"]), np.asarray(seen["merged_bev"]))
        else:  # what only the other CAVs give is gone, the partner label with it
            assert np.array_equal(np.asarray(row["merged_bev"]), empty)
            assert row["partner_label"] == -1 and row["communication"] == ""
        dropped.append(not row["other_cavs"])
    assert 0.25 < np.mean(dropped) < 0.75
    assert dropped == [not alone[i]["other_cavs"] for i in range(len(train_rows))]  # the same every time
    with pytest.raises(ValueError, match="cooperative_dropout"):
        TrainConfig(data="d", out="o", cooperative_dropout=1.0)
    with pytest.raises(ValueError, match="cooperative model"):
        TrainConfig(data="d", out="o", cooperative_dropout=0.5, cooperative=False)


def test_speed_dropout_hides_a_share_of_the_speeds_the_same_way_every_time(data: Path) -> None:
    train_rows, _, _ = load_split(TrainConfig(data=str(data), out="unused", val_fraction=0.0))
    aug = YawAugment(prob=1.0)
    dropped = DrivingDataset(train_rows, aug, seed=1, speed_dropout=0.5)
    hidden = [dropped[i]["speed"] is None for i in range(len(train_rows))]
    assert 0.25 < np.mean(hidden) < 0.75
    assert hidden == [dropped[i]["speed"] is None for i in range(len(train_rows))]
    kept = DrivingDataset(train_rows, aug, seed=1)  # the augmentation does not change with the dropout
    assert all(np.array_equal(kept[i]["path"], dropped[i]["path"]) for i in range(5))
    assert all(kept[i]["speed"] is not None for i in range(len(train_rows)))
    with pytest.raises(ValueError, match="speed_dropout"):
        TrainConfig(data="d", out="o", speed_dropout=1.0)
    with pytest.raises(ValueError, match="speed_input"):
        TrainConfig(data="d", out="o", speed_dropout=0.5, speed_input=False)
    blind = TrainConfig(data="d", out="o", speed_input=False).model_config()
    assert not blind.speed_in_prompt and TrainConfig(data="d", out="o").model_config().speed_in_prompt


# ---- bucketed sampling ------------------------------------------------------------------------------
def test_rows_fall_into_the_go_stop_and_driving_buckets() -> None:
    import datasets

    straight = np.stack([np.arange(1.0, 21.0), np.zeros(20)], axis=1)
    turning = np.stack([np.arange(1.0, 21.0), np.linspace(0.0, 6.0, 20)], axis=1)  # 6 m left at 20 m
    cases = [  # (speed [m/s], expert's target speed [m/s], reason, path) -> bucket
        (0.0, 1.2, "NONE", straight, "starts"),  # pulls away: 1.2 m/s in 0.5 s
        (0.0, 0.1, "RED_LIGHT", straight, "stands"),
        (6.0, 4.0, "LEADING_VEHICLE", straight, "stops"),  # 6 m/s > 1.1 x 4 m/s: SimLingo brakes
        (6.0, 6.0, "NONE", turning, "turns"),
        (6.0, 5.8, "PEDESTRIAN", straight, "follows"),
        (6.0, 6.2, "ROAD", straight, "slows"),
        (8.0, 8.0, "NONE", straight, "cruises"),
    ]
    ds = datasets.Dataset.from_dict(
        {
            "speed": [c[0] for c in cases],
            "target_speed": [c[1] for c in cases],
            "reason": [c[2] for c in cases],
            "path": [c[3].tolist() for c in cases],
        }
    )
    assert [BUCKETS[b] for b in sampling_buckets(ds)] == [c[4] for c in cases]
    picked = ds.select([6, 0, 2])  # a selection (as load_split makes): its rows, in its order
    assert [BUCKETS[b] for b in sampling_buckets(picked)] == ["cruises", "starts", "stops"]


def test_bucket_shares_follow_the_power_of_their_sizes_and_repeat_per_epoch() -> None:
    buckets = np.r_[np.zeros(900, np.int64), np.ones(100, np.int64)]  # 900 standing, 100 starting rows
    as_collected = BucketSampler(buckets, seed=0, power=1.0)
    drawn = list(as_collected)
    assert len(drawn) == len(as_collected) == 1000 and sorted(drawn) == list(range(1000))  # a permutation
    sqrt = BucketSampler(buckets, seed=0, power=0.5)  # 30 : 10 -> 750 : 250
    rows = np.array(list(sqrt))
    assert len(rows) == 1000 and (rows >= 900).sum() == 250
    assert len(set(rows[rows >= 900].tolist())) == 100  # each starting row 2-3 times, all of them
    assert len(set(rows[rows < 900].tolist())) == 750  # no standing row twice while others wait
    equal = np.array(list(BucketSampler(buckets, seed=0, power=0.0)))
    assert (equal >= 900).sum() == 500
    again = BucketSampler(buckets, seed=0, power=0.5)
    assert list(again) == rows.tolist()  # a function of (seed, epoch)
    again.set_epoch(1)
    assert list(again) != rows.tolist()
    with pytest.raises(ValueError, match="bucket_power"):
        TrainConfig(data="d", out="o", bucket_power=1.5)


def test_batched_reads_give_the_rows_that_datasets_decodes(data: Path) -> None:
    """DrivingDataset reads a batch with one Arrow take and decodes the images itself: the same values
    and pixels as datasets' own row access, rotated or not."""
    train_rows, _, _ = load_split(TrainConfig(data=str(data), out="unused", val_fraction=0.0))
    plain = DrivingDataset(train_rows)
    batch = plain.__getitems__([5, 0, 7])
    for row, i in zip(batch, [5, 0, 7], strict=True):
        reference = train_rows[i]
        assert np.array_equal(np.asarray(row["camera"]), np.asarray(reference["camera"].convert("RGB")))
        assert np.array_equal(np.asarray(row["merged_bev"]), np.asarray(reference["merged_bev"]))
        assert np.allclose(row["path"], reference["path"]) and row["commentary"] == reference["commentary"]
    turned = DrivingDataset(train_rows, YawAugment(prob=1.0), seed=3)
    one_by_one = [turned[i] for i in (5, 0, 7)]
    for a, b in zip(turned.__getitems__([5, 0, 7]), one_by_one, strict=True):
        assert np.array_equal(np.asarray(a["camera"]), np.asarray(b["camera"]))
        assert np.array_equal(np.asarray(a["merged_bev"]), np.asarray(b["merged_bev"]))
        assert np.allclose(a["target_points"], b["target_points"])


# ---- augmentation -----------------------------------------------------------------------------------
def test_a_rotated_camera_sees_the_point_ahead_f_tan_dyaw_to_the_right() -> None:
    cam = CameraConfig()
    image = np.zeros((cam.height, cam.width, 3), np.uint8)
    image[:, cam.width // 2 - 1 : cam.width // 2 + 1] = 255  # a vertical line straight ahead
    dyaw = math.radians(12.0)  # turned left
    out = np.asarray(rotate_camera(Image.fromarray(image), dyaw, cam.fov_deg))
    cols = np.flatnonzero(out[cam.height // 2, :, 0] > 100)
    expected = cam.width / 2 + cam.focal * math.tan(dyaw)
    assert abs(cols.mean() + 0.5 - expected) < 1.0
    assert out[:, :5].max() == 0  # the columns the old camera did not see are black (left edge here)
    same = np.asarray(rotate_camera(Image.fromarray(image), 0.0, cam.fov_deg))
    assert np.abs(same.astype(int) - image).max() <= 1


def test_labels_move_with_the_rotation_about_the_camera() -> None:
    """Turned 10 deg left about the camera (1.5 m behind the centre): the straight path ahead now runs
    to the right at -10 deg, and starts 1.5 m x (1 - cos, -sin) off the new origin."""
    dyaw = math.radians(10.0)
    s = np.arange(20.0)
    row = {
        "camera": Image.new("RGB", (256, 128)),
        "merged_bev": Image.fromarray(packed_to_rgb(np.zeros((192, 128), np.uint8))),
        "merged_occupancy": np.zeros((192, 128), np.uint8),
        "path": np.stack([s, np.zeros(20)], axis=1),
        "speed_waypoints": np.stack([np.arange(1, 11.0), np.zeros(10)], axis=1),
        "target_points": [[30.0, 0.0], [60.0, 0.0]],
        "other_cavs": [[3.0, 10.0, 0.0, 0.0]],
        "speed": 4.0,
        "commentary": "Stay on the route.",
    }
    out = rotate_sample(row, dyaw)
    path = np.asarray(out["path"])
    heading = np.arctan2(*(path[-1] - path[0])[::-1])
    assert heading == pytest.approx(-dyaw, abs=1e-5)
    np.testing.assert_allclose(np.diff(path, axis=0).sum(-1) ** 0, 1.0)
    assert np.linalg.norm(np.diff(path, axis=0), axis=1) == pytest.approx(np.ones(19), abs=1e-5)
    pose = rotated_frame(dyaw, -1.5)
    assert pose[:2] == pytest.approx([-1.5 + 1.5 * math.cos(dyaw), 1.5 * math.sin(dyaw)])
    # every point keeps its distance from the camera, which stays at (-1.5, 0) in both frames
    for key in ("path", "speed_waypoints", "target_points"):
        before = np.linalg.norm(np.asarray(row[key], float) - [-1.5, 0.0], axis=1)
        after = np.linalg.norm(np.asarray(out[key], float) - [-1.5, 0.0], axis=1)
        assert after == pytest.approx(before, abs=1e-4)
    cav, x, y, yaw = out["other_cavs"][0]
    assert cav == 3 and x == pytest.approx(11.5 * math.cos(dyaw) - 1.5, abs=1e-6) and y < 0
    assert yaw == pytest.approx(-dyaw)
    assert out["speed"] == 4.0 and out["commentary"] == row["commentary"]
    assert rotate_sample(row, 0.0) is row


def test_the_bev_is_redrawn_in_the_rotated_frame() -> None:
    """The stored grid is warped (not the image's colours) and drawn again; the ego box stays upright, and
    what the old box covered stays hidden."""
    packed = np.zeros((192, 128), np.uint8)
    packed[87:89, 63:65] = 1  # a vehicle ~20 m straight ahead (rows from 64 m ahead, 0.5 m cells)
    packed[87:89, 20:22] = 0b1010  # a pedestrian on a static cell, to the left: both classes move
    packed[126:130, 62:66] = 1  # under the ego box (the partner sees the ego): never drawn
    bev = Image.fromarray(packed_to_rgb(packed))
    dyaw = math.radians(10.0)
    row = {"camera": Image.new("RGB", (256, 128)), "merged_bev": bev, "merged_occupancy": packed}
    out = rotate_sample(row, dyaw)
    grid = out["merged_occupancy"]
    rows, cols = np.nonzero(grid == 1)
    x, y = 64.0 - (rows.mean() + 0.5) * 0.5, 32.0 - (cols.mean() + 0.5) * 0.5  # cell centres, ego frame
    assert math.degrees(math.atan2(y, x + 1.5)) == pytest.approx(-10.0, abs=2.0)  # seen from the camera
    assert (grid == 0b1010).sum() >= 2 and set(np.unique(grid)) == {0, 1, 0b1010}
    image = np.asarray(out["merged_bev"])
    assert np.array_equal(image, packed_to_rgb(grid))  # drawn with the one palette
    assert np.array_equal(image[124:133, 62:66], np.asarray(bev)[124:133, 62:66])  # the ego box, upright
    with pytest.raises(ValueError, match="merged_occupancy"):
        rotate_sample({"camera": row["camera"], "merged_bev": bev}, dyaw)


def test_augmentation_is_a_function_of_seed_epoch_and_index(data: Path) -> None:
    train_rows, _, _ = load_split(TrainConfig(data=str(data), out="unused", val_fraction=0.0))
    aug = YawAugment(prob=1.0)
    a, b = DrivingDataset(train_rows, aug, seed=1), DrivingDataset(train_rows, aug, seed=1)
    assert np.array_equal(a[5]["path"], b[5]["path"])
    b.set_epoch(1)
    assert not np.array_equal(a[5]["path"], b[5]["path"])
    plain = DrivingDataset(train_rows)[5]
    assert np.array_equal(np.asarray(plain["path"]), np.asarray(train_rows[5]["path"]))


# ---- training ---------------------------------------------------------------------------------------
def config(data: Path, out: Path, **kw: object) -> TrainConfig:
    # fp32 on a GPU too: these tests compare runs to 1e-6 (mixed precision: tests/test_model_cuda.py)
    base: dict = dict(
        data=str(data),
        out=str(out),
        batch_size=4,
        max_steps=7,
        save_every=2,
        log_every=1,
        mixed_precision="no",
    )
    return TrainConfig(**{**base, **kw, "val_fraction": 0.3})


def test_resuming_from_a_checkpoint_gives_the_same_weights_and_losses(data: Path, tmp_path: Path) -> None:
    """7 steps of 4 rows over 24 training rows (6 steps per epoch: the resumed part starts mid-epoch and
    crosses an epoch): a run resumed from step 4 ends with the uninterrupted run's weights and losses."""
    cfg = config(data, tmp_path / "run")
    train(cfg, progress=False)
    whole = load_file(str(tmp_path / "run" / "model" / "model.safetensors"))
    log = [json.loads(ln) for ln in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    losses = {r["step"]: r["loss"] for r in log if r["split"] == "train"}
    assert sorted(losses) == list(range(1, 8))
    for step in (6, 7):  # the run "stopped" after the checkpoint of step 4
        shutil.rmtree(tmp_path / "run" / "checkpoints" / f"step_{step:06d}", ignore_errors=True)
    shutil.rmtree(tmp_path / "run" / "model")
    train(cfg, resume=True, progress=False)
    resumed = load_file(str(tmp_path / "run" / "model" / "model.safetensors"))
    assert max(float((whole[k] - resumed[k]).abs().max()) for k in whole) < 1e-6
    log = [json.loads(ln) for ln in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    again = {r["step"]: r["loss"] for r in log if r["split"] == "train"}
    assert sorted(again) == list(range(1, 8))  # the lines after step 4 of the first run were replaced
    assert again == pytest.approx(losses, rel=1e-6)
    first = load_file(str(tmp_path / "run" / "checkpoints" / "step_000004" / "model" / "model.safetensors"))
    assert max(float((whole[k] - first[k]).abs().max()) for k in whole) > 1e-4  # steps 5-7 did change it


def test_a_run_writes_logs_checkpoints_and_a_loadable_model(data: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    metrics = train(config(data, out, max_steps=4, keep_checkpoints=1), progress=False)
    assert set(metrics) == {
        "loss",
        "lm_loss",
        "waypoint_loss",
        "path_l2_m",
        "speed_l2_m",
        "speed_loss",
        "target_speed_err_mps",
        "go_stop_agree",
    }
    assert 0.0 <= metrics["go_stop_agree"] <= 1.0
    log = [json.loads(ln) for ln in (out / "metrics.jsonl").read_text().splitlines()]
    train_lines = [r for r in log if r["split"] == "train"]
    assert [r["step"] for r in train_lines] == [1, 2, 3, 4]
    lrs = [r["lr"] for r in train_lines]
    assert max(lrs) <= 1e-3 + 1e-12 and lrs[-1] < lrs[1]  # one cycle: up to the peak, then down
    assert all(r["grad_norm"] > 0 and math.isfinite(r["loss"]) for r in train_lines)
    assert [r["step"] for r in log if r["split"] == "val"] == [2, 4]
    assert list((out / "tensorboard").glob("events.out.tfevents.*"))
    assert [p.name for p in (out / "checkpoints").iterdir()] == ["step_000004"]  # keep_checkpoints=1
    model = V2VVLA.from_pretrained(out / "model")
    assert model.config.cooperative and model.config.name == "tiny"
    with pytest.raises(FileExistsError, match="--resume"):
        train(config(data, out, max_steps=4), progress=False)
    with pytest.raises(
        ValueError, match=r"(?s)different configuration:\n.*  max_steps: 4 \(then\) -> 5 \(now\)"
    ):
        train(config(data, out, max_steps=5), resume=True, progress=False)
    # a run begun before a setting existed ran on its default: resuming it with that default is no change
    saved = out / "train_config.json"
    newer = ("init_from", "standing_input")
    older = {k: v for k, v in json.loads(saved.read_text()).items() if k not in newer}
    saved.write_text(json.dumps(older))
    with pytest.raises(ValueError, match=r"(?s)different configuration:\n  standing_input: false \(then\)"):
        train(
            config(data, out, max_steps=4, keep_checkpoints=1, standing_input=True),
            resume=True,
            progress=False,
        )


def test_cli_trains_the_baseline(data: Path, tmp_path: Path) -> None:
    out = tmp_path / "baseline"
    args = ["train", "--data", str(data), "--out", str(out), "--baseline", "--max-steps", "2"]
    result = CliRunner().invoke(app, [*args, "--batch-size", "2", "--save-every", "2"])
    assert result.exit_code == 0, result.output
    assert not V2VVLA.from_pretrained(out / "model").config.cooperative
    none = ["train", "--data", str(tmp_path / "none"), "--out", str(tmp_path / "x")]
    missing = CliRunner().invoke(app, none)
    assert missing.exit_code == 1 and "no .parquet shard" in " ".join(missing.output.split())


# ---- corrupt inputs ---------------------------------------------------------------------------------
def _flip_camera_byte(shard: Path) -> None:
    """Flip one bit in the middle of the shard's camera image data (a page the statistics never read)."""
    import pyarrow.parquet as pq

    group = pq.read_metadata(shard).row_group(0)
    camera = next(
        group.column(i) for i in range(group.num_columns) if group.column(i).path_in_schema == "camera.bytes"
    )
    data = bytearray(shard.read_bytes())
    data[camera.data_page_offset + camera.total_compressed_size // 2] ^= 0x04
    shard.write_bytes(bytes(data))


def test_a_bit_flipped_shard_is_named_by_data_stats_and_train(data: Path, tmp_path: Path) -> None:
    """`data stats` counted a bit-flipped shard as good samples, and `train` failed on it with a
    traceback that never named it."""
    folder = tmp_path / "flipped"
    shutil.copytree(data, folder)
    bad = sorted(folder.glob("*.parquet"))[1]
    _flip_camera_byte(bad)
    stats = CliRunner().invoke(app, ["data", "stats", str(folder)])
    assert stats.exit_code == 1 and f"{bad.name}:corruptshard" in "".join(stats.output.split())
    run = CliRunner().invoke(
        app, ["train", "--data", str(folder), "--out", str(tmp_path / "run"), "--max-steps", "1"]
    )
    assert run.exit_code == 1 and f"{bad.name}:corruptshard" in "".join(run.output.split())
    assert "Traceback" not in run.output


def test_resume_refuses_pickled_optimizer_state_with_a_message(data: Path, tmp_path: Path) -> None:
    """A checkpoint whose optimizer state pickles an arbitrary object is refused by torch's safe loader;
    `train --resume` says so, naming the checkpoint, instead of a traceback (and runs nothing from it)."""
    from cmudrive.model.train import TrainState

    out = tmp_path / "run"
    train(config(data, out, max_steps=2, batch_size=2), progress=False)
    checkpoint = out / "checkpoints" / "step_000002"
    optimizer = (checkpoint / "optimizer.bin").read_bytes()
    torch.save({"state": TrainState(step=2)}, checkpoint / "optimizer.bin")  # a class: needs full pickle
    with pytest.raises(ValueError, match=r"step_000002: --resume refused this checkpoint: .*pickled objects"):
        train(config(data, out, max_steps=2, batch_size=2), resume=True, progress=False)
    (checkpoint / "optimizer.bin").write_bytes(optimizer)
    (checkpoint / "state.json").write_text('{"step": "two"}')
    with pytest.raises(ValueError, match=r"step_000002/state\.json: step, epoch and batch_in_epoch must be"):
        train(config(data, out, max_steps=2, batch_size=2), resume=True, progress=False)


@pytest.mark.slow
def test_a_compiled_run_trains_the_same_weights_under_the_same_names(data: Path, tmp_path: Path) -> None:
    """--compile compiles the language model in place: the saved weights keep their names (a compiled
    checkpoint loads like any other) and 3 steps end within float tolerance of the eager run's."""
    train(config(data, tmp_path / "eager", max_steps=3, save_every=3), progress=False)
    train(config(data, tmp_path / "compiled", max_steps=3, save_every=3, compile=True), progress=False)
    eager = load_file(str(tmp_path / "eager" / "model" / "model.safetensors"))
    compiled = load_file(str(tmp_path / "compiled" / "model" / "model.safetensors"))
    assert set(compiled) == set(eager)
    assert max(float((eager[k] - compiled[k]).abs().max()) for k in eager) < 1e-4


def test_fine_tuning_starts_from_saved_weights_and_may_add_standing_time(data: Path, tmp_path: Path) -> None:
    from cmudrive.model.train import init_weights

    first = tmp_path / "first"
    train(config(data, first, max_steps=2, keep_checkpoints=1), progress=False)
    saved = V2VVLA.from_pretrained(first / "model")
    tuned = V2VVLA.from_config(config(data, tmp_path / "x", standing_input=True).model_config())
    init_weights(tuned, first / "model")
    assert tuned.config.standing_in_prompt and not saved.config.standing_in_prompt
    for name, tensor in saved.state_dict().items():
        assert torch.equal(tuned.state_dict()[name], tensor), name
    args = ["train", "--data", str(data), "--max-steps", "1", "--batch-size", "2", "--no-speed-input"]
    start = ["--init-from", str(first / "model")]
    ok = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "tuned"), *start])
    assert ok.exit_code == 0, ok.output
    refused = CliRunner().invoke(app, [*args, "--baseline", "--out", str(tmp_path / "b"), *start])
    assert refused.exit_code == 1
    assert f"--init-from {first / 'model'}: a cooperative model" in " ".join(refused.output.split())


def test_a_cooperative_model_may_start_from_the_baselines_weights(data: Path, tmp_path: Path) -> None:
    """The warm start of docs/model.md: every tensor of the baseline's model lands in the cooperative one."""
    from cmudrive.model.train import init_weights

    base = tmp_path / "base"
    train(config(data, base, max_steps=1, keep_checkpoints=1, cooperative=False), progress=False)
    saved = V2VVLA.from_pretrained(base / "model")
    coop = V2VVLA.from_config(config(data, tmp_path / "x").model_config())
    assert coop.config.cooperative and not saved.config.cooperative
    init_weights(coop, base / "model")
    for name, tensor in saved.state_dict().items():
        assert torch.equal(coop.state_dict()[name], tensor), name


def test_one_process_trains_in_fp32_and_then_in_bf16(data: Path, tmp_path: Path) -> None:
    """accelerate keeps one precision per process; a second run with another (on a GPU, ``auto`` after
    the tests' fp32) used to stop with "AcceleratorState has already been initialized"."""
    train(config(data, tmp_path / "fp32", max_steps=1, save_every=1), progress=False)
    train(config(data, tmp_path / "bf16", max_steps=1, save_every=1, mixed_precision="bf16"), progress=False)
    assert (tmp_path / "bf16" / "model" / "model.safetensors").is_file()
