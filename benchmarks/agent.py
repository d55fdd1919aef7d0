"""Closed-loop cost of the V2V-VLA agent per tick for 16 CAVs on the CPU, against the 50 ms budget
(16 CAVs at 20 ticks/s), and where it goes.

    python benchmarks/agent.py [--config tiny] [--cavs 16] [--threads 1] [--repeats 5] [--language-every 5]

One tick of the agent (``cmudrive.model.agent``), for a random ``tiny`` model and 16 CAVs that all see
each other (8 other CAVs listed in every prompt, the prompt's longest form): building the rows (the row
contract, ``cmudrive.model.row``: target points, merged occupancy drawn as RGB, camera through the
dataset's JPEG round trip, timed alone too), the processor (image tiles + tokens), the vision encoder
alone, ``predict`` on a
silent tick (waypoints only: one pass over prompt + queries) and on a talking tick (the same, then greedy
decoding of an answer as long as a typical commentary + communication sentence; a random model never
stops by itself, so its length is forced), and the controller. Median of ``--repeats`` after a warm-up.
The amortised tick is one talking tick and ``language_every - 1`` silent ones.
"""

from __future__ import annotations

import argparse
import os

import numpy as np
import torch
from model_speed import timed  # benchmarks/ is on sys.path when a script in it runs

from cmudrive.agents.base import CavPlan, Observations
from cmudrive.agents.control import WaypointController
from cmudrive.model import V2VVLA, get_config
from cmudrive.model.row import RowBuilder

ANSWER = (
    "Turn left at the junction ahead. Slow down behind the red car ahead on the left. "
    "Communication: CAV 3 can see the pedestrian, which is hidden from our camera."
)  # a long answer of the dataset's kind


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--config", default="tiny")
    parser.add_argument("--cavs", type=int, default=16)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--language-every", type=int, default=5)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    n = args.cavs
    model = V2VVLA.from_config(get_config(args.config)).eval()
    camera = road_images(n, rng)
    occupancy = rng.random((n, 4, 192, 128)) < 0.02
    x, y = 5.0 + 4.0 * np.arange(n), 3.0 * (np.arange(n) % 3 - 1)  # all within range of each other
    relative = np.stack([x[None, :] - x[:, None], y[None, :] - y[:, None], np.zeros((n, n))], axis=-1)
    relative[np.arange(n), np.arange(n)] = np.nan
    plan = CavPlan("cav", np.array([[0.0, 0.0], [50.0, 0.0], [100.0, 4.0]]), np.zeros(3, np.int8), np.ones(3))
    builder = RowBuilder(tuple(plan for _ in range(n)))
    tick = [0]

    def observations() -> Observations:
        tick[0] += 1  # a new tick each call: the target points are computed every time
        return Observations(
            tick=tick[0], time=0.0, cav_index=np.arange(n), x=x, y=y, yaw=np.zeros(n), speed=np.full(n, 6.0),
            accel=np.zeros(n), other_cavs=relative, camera=camera, merged_occupancy=occupancy,
        )  # fmt: skip

    def build_rows(jpeg: bool = True) -> list[dict]:
        obs = observations()
        return builder.model_rows(builder.inputs(obs, obs.merged_occupancy), jpeg=jpeg)

    rows = build_rows()
    answer = [
        *model.tokenizer(" " + ANSWER, add_special_tokens=False)["input_ids"],
        model.processor.eos_token_id,
    ]
    batch = model.processor(rows)
    tiles = batch.pixel_values.flatten(0, 1)
    ctl = WaypointController(n)
    path = np.repeat(np.stack([np.arange(1.0, 21.0), np.zeros(20)], 1)[None], n, 0)
    wp = np.repeat(np.stack([np.arange(1.0, 11.0) * 1.5, np.zeros(10)], 1)[None], n, 0)
    cav = np.arange(n)
    speed = np.full(n, 5.0)

    t_rows = timed(build_rows, args.repeats)
    t_raw = timed(lambda: build_rows(jpeg=False), args.repeats)
    t_proc = timed(lambda: model.processor(rows), args.repeats)
    with torch.no_grad():
        t_vision = timed(lambda: model.backbone.model.get_image_features(pixel_values=tiles), args.repeats)
    t_silent = timed(lambda: model.predict(batch, max_new_tokens=0), args.repeats)
    t_talk = timed(lambda: model.predict(batch, max_new_tokens=len(answer) - 1), args.repeats)
    t_ctl = timed(lambda: ctl(cav, speed, path, wp), args.repeats)
    k = args.language_every
    amortised = t_rows + t_proc + (t_talk + (k - 1) * t_silent) / k + t_ctl
    load = os.getloadavg()
    print(
        f"{args.config}, {n} CAVs, prompt {batch.input_ids.shape[1]} tokens per row, "
        f"answer {len(answer)} tokens"
    )
    print(
        f"  rows (BEV drawn, JPEG)  {t_rows * 1e3:7.1f} ms  (of which the camera's JPEG round trip "
        f"{(t_rows - t_raw) * 1e3:.1f} ms)"
    )
    print(f"  processor               {t_proc * 1e3:7.1f} ms")
    print(f"  vision encoder alone    {t_vision * 1e3:7.1f} ms  ({tiles.shape[0]} tiles)")
    print(f"  predict, silent tick    {t_silent * 1e3:7.1f} ms  (vision + one pass over prompt + queries)")
    print(
        f"  predict, talking tick   {t_talk * 1e3:7.1f} ms  (vision + prefill + {len(answer)} decoding steps)"
    )
    print(f"  controller              {t_ctl * 1e3:7.1f} ms")
    print(
        f"  amortised tick (language every {k}): {amortised * 1e3:.1f} ms = {amortised / 0.05:.1f}x the "
        f"50 ms budget; {args.threads} torch threads, load average {load[0]:.2f}"
    )
    print(f"ms_per_tick={amortised * 1e3:.1f}")


def road_images(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 128, 256, 3) uint8 camera-like frames (JPEG's cost depends on the content: noise costs several
    times a rendered frame): a sky-to-road gradient, a few flat boxes (vehicles), mild noise."""
    v = np.linspace(0.0, 1.0, 128)[:, None, None]
    out = np.repeat((np.array([0.6, 0.65, 0.8]) - np.array([0.3, 0.3, 0.5]) * v)[None] * 255, n, 0)
    out = np.repeat(out, 256, axis=2)
    for i in range(n):
        for _ in range(4):
            r, c = rng.integers(50, 100), rng.integers(10, 220)
            out[i, r : r + rng.integers(8, 25), c : c + rng.integers(10, 40)] = rng.integers(0, 256, 3)
    out += rng.normal(0.0, 2.0, out.shape)
    return np.clip(out, 0, 255).astype(np.uint8)


if __name__ == "__main__":
    main()
