"""Per-task view of a quality run, from its result.json and its task bundles: what the judge saw and what it said.

Shared by the HTML report's gallery (simeval.report.html) and the loggers' table of per-task scores
(simeval.measures.quality.run.log_task_table). Bundles are found from the record's `config.bundles_dir` (absolute, or
relative to the working directory) or the `<run>/bundles` export of an episode-store run. Frames are sampled exactly as
simeval.measures.quality.run samples them for the completion judge (`n_frames` evenly, first and last included).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from simeval.errors import UserError
from simeval.measures.quality.bundle import SCALES, BundleError, load_bundles, read_video_frames, sample_frame_indices


@dataclass
class JudgedMedia:
    """What the judge saw of one task. A frame is (path, None) for a frames/*.png bundle, (None, HxWx3 array)
    for a frame decoded from trajectory.mp4; `video` is that mp4."""
    scene: list[Path] = field(default_factory=list)
    frames: list[tuple[Path | None, object]] = field(default_factory=list)
    n_total_frames: int | None = None
    video: Path | None = None
    error: str | None = None


def bundle_roots(rec: dict) -> list[Path]:
    cfg = rec.get("config") or {}
    roots = []
    if cfg.get("bundles_dir"):
        roots.append(Path(str(cfg["bundles_dir"])).expanduser())
    roots.append(Path(rec["path"]).parent / "bundles")  # episode-store runs with a model judge export them here
    return [r for r in roots if r.is_dir()]


def find_bundles(rec: dict) -> tuple[dict[str, object], str | None]:
    """{task name: TaskBundle} for a quality record (with its `path`), and a note when they cannot be found."""
    roots = bundle_roots(rec)
    if not roots:
        where = (rec.get("config") or {}).get("bundles_dir")
        return {}, (f"bundles_dir {where!r} is not there any more: scores and replies only" if where else
                    "no task bundles (ground truth read from an episode store): scores only")
    try:
        bundles, _ = load_bundles(roots[0])
    except UserError as e:
        return {}, f"bundles at {roots[0]} unreadable: {e}"
    return {b.name: b for b in bundles}, None


def judged_media(bundle, n_frames: int) -> JudgedMedia:
    """The scene views and the sampled trajectory frames of a bundle; an unreadable video is `error`, not raised."""
    media = JudgedMedia(scene=sorted((bundle.path / "scene").glob("*.png")))
    frames_dir, video = bundle.path / "frames", bundle.path / "trajectory.mp4"
    files = sorted(frames_dir.glob("*.png")) if frames_dir.is_dir() else []
    try:
        if files:
            media.frames = [(files[i], None) for i in sample_frame_indices(len(files), n_frames)]
            media.n_total_frames = len(files)
        elif video.is_file():
            media.frames = [(None, a) for a in read_video_frames(video, n_frames)]
            media.video = video
    except BundleError as e:
        media.error = str(e)
    return media


def normalized(metric: str, mean):
    """A score on its metric's scale mapped to [0, 1] (None stays None), so the two metrics compare."""
    lo, hi = SCALES[metric]
    return None if mean is None else (mean - lo) / (hi - lo)


def ordered_tasks(rec: dict) -> list[str]:
    """Every task of a quality record, those with no valid score first, then by their lowest normalized score."""
    values = rec.get("values") or {}
    tasks = set(rec.get("tasks") or {}) | set(rec.get("errors") or {}) | {t for v in values.values() for t in v}

    def key(task):
        scores = [normalized(m, ((values.get(m) or {}).get(task) or {}).get("mean")) for m in SCALES]
        known = [s for s in scores if s is not None]
        return (1 if known else 0, min(known) if known else 0.0, task)

    return sorted(tasks, key=key)


TABLE_COLUMNS = ["task", "pipeline", "description", "scene_alignment", "scene_alignment_var", "task_completion",
                 "task_completion_var", "ground_truth_progress", "ground_truth_success", "error", "scene", "frames"]


def quality_task_table(rec: dict) -> tuple[list[str], list[list]]:
    """(columns, rows) of per-task scores for a logger's `log_table`, lowest score first; image cells are lists of
    simeval.loggers.LogImage (scene views; the sampled trajectory frames)."""
    from simeval.loggers import LogImage

    values = rec.get("values") or {}
    errors = rec.get("errors") or {}
    bundles, _ = find_bundles(rec)
    n_frames = int((rec.get("config") or {}).get("n_frames") or 8)
    rows = []
    for task in ordered_tasks(rec):
        per = {m: (values.get(m) or {}).get(task) or {} for m in SCALES}
        b = bundles.get(task)
        truth = (b.ground_truth or {}) if b is not None else {}
        scene, frames = [], []
        if b is not None:
            media = judged_media(b, n_frames)
            scene = [LogImage(str(p), f"{task} {p.stem}") for p in media.scene]
            frames = [LogImage(str(p) if p is not None else None, f"{task} frame {i}", array=a)
                      for i, (p, a) in enumerate(media.frames)]
        pipeline = ((rec.get("tasks") or {}).get(task) or {}).get("pipeline")
        rows.append([task, pipeline, b.description if b is not None else None,
                     per["scene_alignment"].get("mean"), per["scene_alignment"].get("var"),
                     per["task_completion"].get("mean"), per["task_completion"].get("var"),
                     truth.get("progress"), truth.get("success"), errors.get(task), scene, frames])
    return list(TABLE_COLUMNS), rows
