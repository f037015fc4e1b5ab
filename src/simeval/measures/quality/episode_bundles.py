"""The episode store as quality tasks.

- `store_tasks`: each episode's identity and ground truth (success, final progress), read from the store's
  metadata for judge=oracle: no frame is decoded and nothing is written.
- `export_bundles`: task bundles (the folder layout documented in simeval/measures/quality/bundle.py) for the model
judges, which
  need images: the description, the ground truth, the scene views, and up to `max_frames` trajectory frames of
  one camera spread evenly over the episode (first and last kept).

A task's identity is `<task>#<seed>`; two episodes with one identity (the same task and seed under two
pipelines, when no `pipeline` is chosen) are an error naming both files.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import yaml

from simeval.episodes.store import EpisodeStore, read_episode
from simeval.errors import UserError, require_whole
from simeval.measures.quality.bundle import BundleError, TaskBundle, validate_ground_truth
from simeval.results import atomic_write_text


def task_identity(task: str, seed: int, variation_id: str = "") -> str:
    """`task#seed`, plus `.v<id>` for a varied episode (stored beside the plain one of the same seed)."""
    return f"{task}#{seed}" + (f".v{variation_id}" if variation_id else "")


def _episodes(store_root, pipeline, group, per_task) -> list[dict]:
    require_whole("episodes.per_task", per_task)
    if not Path(store_root).is_dir():
        raise UserError(f"episodes.store={store_root}: no such folder (a store src/collect.py or src/import_data.py "
                        "wrote, e.g. outputs/episodes)")
    store = EpisodeStore(store_root)
    try:  # the first k of each task of each pipeline (a task name may exist under several pipelines)
        pipelines = [pipeline] if pipeline else sorted({m["pipeline"] for m in store.index(None, group)})
        metas = [m for p in pipelines for m in store.first_k_per_task(per_task, p, group)]
    except UserError as e:
        if "fewer than the" not in str(e):
            raise
        raise UserError(f"episodes.store={store_root}: {e} (episodes.per_task={per_task}; collect more or ask "
                        "for fewer)") from e
    if not metas:
        held = {(m["pipeline"], m["group"]) for m in store.index()}
        holds = ", ".join(f"{p} ({', '.join(sorted(g for q, g in held if q == p))})"
                          for p in sorted({p for p, _ in held})) or "nothing"
        pipeline, group = ("null" if v is None else v for v in (pipeline, group))  # as a command line writes them
        raise UserError(f"episodes.store={store_root} has no episodes of episodes.pipeline={pipeline}, "
                        f"episodes.group={group}; it holds: {holds}")
    seen: dict[str, str] = {}
    for m in metas:
        ident = task_identity(m["task"], m["seed"], m.get("variation_id", ""))
        if ident in seen:
            raise UserError(f"{store_root}: task {ident!r} is in two episodes: {seen[ident]} and {m['path']}; "
                            f"choose one pipeline (episodes.pipeline=...)")
        seen[ident] = m["path"]
    return metas


def _no_such_camera(camera: str, path, recorded) -> None:
    raise UserError(f"episodes.camera={camera}: {path} records the cameras {', '.join(recorded)}")


def store_tasks(store_root: str | os.PathLike, *, pipeline: str | None = None, group: str | None = None,
                per_task: int = 1, camera: str | None = None) -> tuple[list, dict[str, str]]:
    """(tasks, errors) for judge=oracle: TaskBundles whose `path` is the episode file and whose ground truth is
    what the episode recorded (success if `success_known`, the last progress if `progress_known`; an unknown is
    left out, never scored as 0). An episode whose recorded truth is invalid is a per-task error. The oracle looks
    at no frame, but a `camera` the episodes do not record is refused as a VLM judge would refuse it."""
    import h5py

    tasks, errors = [], {}
    for m in _episodes(store_root, pipeline, group, per_task):
        if camera is not None and camera not in m["cameras"]:
            _no_such_camera(camera, m["path"], m["cameras"])
        truth = {}
        if m.get("success_known", True):
            truth["success"] = bool(m["success"])
        if m.get("progress_known", True):
            with h5py.File(m["path"], "r") as f:
                if len(f["progress"]):
                    truth["progress"] = float(f["progress"][-1])
        ident = task_identity(m["task"], m["seed"], m.get("variation_id", ""))
        try:
            truth = validate_ground_truth(truth, m["path"])
        except BundleError as e:
            errors[ident] = str(e)
            continue
        tasks.append(TaskBundle(ident, Path(m["path"]), m["description"], m["pipeline"], truth, m))
    return tasks, errors


def export_bundles(store_root: str | os.PathLike, out_dir: str | os.PathLike, *, pipeline: str | None = None,
                   group: str | None = None, per_task: int = 1, camera: str | None = None,
                   max_frames: int = 64) -> list[Path]:
    from PIL import Image

    out, written = Path(out_dir), []
    for meta in _episodes(store_root, pipeline, group, per_task):
        ep = read_episode(meta["path"])
        cam = camera or next(iter(ep.rgb))
        if cam not in ep.rgb:
            _no_such_camera(cam, meta["path"], sorted(ep.rgb))
        vid = f".v{meta['variation_id']}" if meta.get("variation_id") else ""  # a varied episode beside the plain one
        d = out / f"{ep.task.replace('/', '_')}__seed{ep.seed}{vid}"
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
            "name": task_identity(ep.task, ep.seed, meta.get("variation_id", "")), "description": ep.description,
            "pipeline": ep.pipeline,
            "group": ep.group, "ground_truth": truth, "episode": str(meta["path"])}, sort_keys=False))
        written.append(d)
    return written
