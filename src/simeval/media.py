"""Videos written beside a run's results: mp4 files from (T, H, W, 3) uint8 frames, and panels side by side.

`write_video` encodes with imageio-ffmpeg (pinned in requirements.txt; it ships its own ffmpeg binary), so a run
folder holds the same videos whatever logger is chosen, and the W&B logger logs those files (wandb.Video of a path
needs no encoder; of an array it would need moviepy, which is not installed).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np


def write_video(frames: np.ndarray, path: str | os.PathLike, fps: int = 15) -> Path:
    """(T, H, W, 3) uint8 -> an H.264 mp4 at `path`, written to a temp name and renamed (a killed run leaves no half
    file). An odd height or width is padded by one edge row/column: yuv420p needs even sizes."""
    import imageio.v2 as imageio

    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or len(frames) == 0:
        raise ValueError(f"expected (T, H, W, 3) uint8 frames with T >= 1, got {frames.dtype} {frames.shape}")
    pad_h, pad_w = frames.shape[1] % 2, frames.shape[2] % 2
    if pad_h or pad_w:
        frames = np.pad(frames, ((0, 0), (0, pad_h), (0, pad_w), (0, 0)), mode="edge")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    try:
        with imageio.get_writer(tmp, fps=fps, macro_block_size=1) as w:
            for f in frames:
                w.append_data(f)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def side_by_side(panels: Sequence[np.ndarray], gap: int = 2, gap_colors: np.ndarray | None = None) -> np.ndarray:
    """Videos of the same (T, H) put next to each other: (T, H, sum(W) + gap * (n - 1), 3) uint8. The gap columns
    are white, or per frame `gap_colors[t]` (an RGB triple), e.g. to mark which frames were imagined."""
    panels = [np.asarray(p, dtype=np.uint8) for p in panels]
    t, h = panels[0].shape[:2]
    if any(p.shape[:2] != (t, h) or p.ndim != 4 for p in panels):
        raise ValueError(f"panels must share (T, H): {[p.shape for p in panels]}")
    width = sum(p.shape[2] for p in panels) + gap * (len(panels) - 1)
    out = np.empty((t, h, width, 3), np.uint8)
    colors = np.full((t, 3), 255, np.uint8) if gap_colors is None else np.asarray(gap_colors, np.uint8)
    x = 0
    for i, p in enumerate(panels):
        out[:, :, x:x + p.shape[2]] = p
        x += p.shape[2]
        if i < len(panels) - 1:
            out[:, :, x:x + gap] = colors[:, None, None, :]
            x += gap
    return out
