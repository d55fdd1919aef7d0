"""Write frames (RGB uint8 arrays) as a video: ``.mp4`` (H.264 through imageio's ffmpeg plugin, streamed
frame by frame) or ``.gif`` (Pillow). Used by the BEV demo and route replays."""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np
from PIL import Image

VIDEO_SUFFIXES = (".mp4", ".gif")
MP4_QUALITY = 8  # imageio's 0-10 scale (default 5 blurs thin lane markings)


def write_video(frames: Iterable[np.ndarray], path: str | Path, fps: float = 20.0) -> Path:
    """Write RGB frames (H, W, 3) uint8 to ``path``, chosen by suffix, and return the path.

    ``.mp4``: H.264 (yuv420p) through imageio's ffmpeg plugin (packages ``imageio`` and
    ``imageio-ffmpeg``), streamed frame by frame; a frame of odd width or height is padded by one pixel,
    as yuv420p needs even sizes. ``.gif``: Pillow, looping, each frame reduced to its own 256-colour
    palette; Pillow merges identical consecutive frames into one longer frame.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise ValueError(f"cannot write video {path}: unknown suffix {suffix!r}; use one of {VIDEO_SUFFIXES}")
    if fps <= 0:
        raise ValueError(f"cannot write video {path}: fps must be positive, got {fps}")
    checked = iter(_checked(frames, path))
    if suffix == ".gif":
        first = Image.fromarray(next(checked))  # raises on no frames before a file is opened
        path.parent.mkdir(parents=True, exist_ok=True)
        rest = (Image.fromarray(frame) for frame in checked)
        first.save(path, save_all=True, append_images=rest, duration=1000.0 / fps, loop=0)
        return path
    try:
        import imageio.v2 as iio
        import imageio_ffmpeg  # noqa: F401  (the plugin imageio's FFMPEG format runs on)
    except ImportError as exc:
        raise ImportError(
            f"writing video {path} needs the packages 'imageio' and 'imageio-ffmpeg' ({exc}); "
            "pip install imageio imageio-ffmpeg"
        ) from None
    first_frame = next(checked)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = iio.get_writer(
        path,
        format="FFMPEG",
        mode="I",
        fps=fps,
        codec="libx264",
        pixelformat="yuv420p",
        quality=MP4_QUALITY,
        macro_block_size=1,
    )
    try:
        for frame in itertools.chain([first_frame], checked):
            h, w = frame.shape[:2]
            writer.append_data(np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge"))
    finally:
        writer.close()
    return path


def _checked(frames: Iterable[np.ndarray], path: Path) -> Iterator[np.ndarray]:
    """The frames, each checked to be (H, W, 3) uint8 of the first frame's size."""
    shape: tuple[int, ...] | None = None
    count = 0
    for i, frame in enumerate(frames):
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(
                f"video {path}: frame {i} is {frame.dtype} {frame.shape}, expected (H, W, 3) uint8"
            )
        if shape is None:
            shape = frame.shape
        elif frame.shape != shape:
            raise ValueError(f"video {path}: frame {i} is {frame.shape}, the first frame was {shape}")
        count += 1
        yield frame
    if count == 0:
        raise ValueError(f"video {path}: no frames to write")
