"""Task bundles for the quality judges (the folder layout documented in simeval/quality.py) exported from the
episode store: the description, the ground truth (success, final progress) for judge=oracle, the scene views,
and up to `max_frames` trajectory frames of one camera spread evenly over the episode (first and last kept)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import yaml

from simeval.episodes.store import EpisodeStore, read_episode
from simeval.results import atomic_write_text


def export_bundles(store_root: str | os.PathLike, out_dir: str | os.PathLike, *, pipeline: str | None = None,
                   group: str | None = None, per_task: int = 1, camera: str | None = None,
                   max_frames: int = 64) -> list[Path]:
    from PIL import Image

    store = EpisodeStore(store_root)
    metas = store.first_k_per_task(per_task, pipeline, group)
    if not metas:
        raise FileNotFoundError(f"no episodes in {store_root} (pipeline={pipeline}, group={group})")
    out, written = Path(out_dir), []
    for meta in metas:
        ep = read_episode(meta["path"])
        cam = camera or next(iter(ep.rgb))
        if cam not in ep.rgb:
            raise ValueError(f"{meta['path']}: no camera '{cam}' (has {sorted(ep.rgb)})")
        d = out / f"{ep.task.replace('/', '_')}__seed{ep.seed}"
        (d / "scene").mkdir(parents=True, exist_ok=True)
        (d / "frames").mkdir(exist_ok=True)
        views = ep.scene_views if ep.scene_views is not None else ep.rgb[cam][:1]
        for i, v in enumerate(views):
            Image.fromarray(v).save(d / "scene" / f"view{i}.png")
        frames = ep.rgb[cam]
        for k, i in enumerate(np.unique(np.linspace(0, len(frames) - 1, min(max_frames, len(frames))).round().astype(int))):
            Image.fromarray(frames[i]).save(d / "frames" / f"{k:05d}.png")
        truth = {}  # only what the source recorded: judge=oracle must not score an unknown as a failure
        if ep.success_known:
            truth["success"] = bool(ep.success)
        if ep.progress is not None:
            truth["progress"] = float(ep.progress[-1])
        atomic_write_text(d / "task.yaml", yaml.safe_dump({
            "name": f"{ep.task}#{ep.seed}", "description": ep.description, "pipeline": ep.pipeline,
            "group": ep.group, "ground_truth": truth, "episode": str(meta["path"])}, sort_keys=False))
        written.append(d)
    return written
