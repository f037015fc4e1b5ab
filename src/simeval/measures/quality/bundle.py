"""The task-bundle format: what a quality judge reads, and its checks (imports nothing else of simeval but its
error type and the judges' image type).

A task bundle is a folder:
    <root>/<task>/task.yaml        description (required), name, pipeline, ground_truth {success, progress} (optional)
    <root>/<task>/scene/*.png      the views of the initial scene (the paper uses 4), sorted by file name
    <root>/<task>/trajectory.mp4   or frames/*.png: the trajectory, from which `n_frames` are sampled evenly
                                   (first and last included) in order
A task's name (task.yaml `name:`, else the folder name) is its identity: two bundles with one name are an error.
Ground truth is validated (success: true/false; progress: a number in [0, 1]). Unreadable parts and bad ground
truth are a per-task error: the other tasks are still judged and the failures are reported. A task with no valid
score at all (every reply unparseable, or nothing readable) is a failed task; a run where every task failed has
status "failed".
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from simeval.errors import UserError
from simeval.judges.providers import Image

log = logging.getLogger(__name__)
SCALES = {"scene_alignment": (1.0, 5.0), "task_completion": (0.0, 10.0)}
METRICS = tuple(SCALES)


class BundleError(UserError):
    pass


@dataclass
class TaskBundle:
    name: str
    path: Path
    description: str
    pipeline: str | None = None
    ground_truth: dict | None = None
    meta: dict = field(default_factory=dict)

    def scene_images(self) -> list[Image]:
        views = sorted((self.path / "scene").glob("*.png"))
        if not views:
            raise BundleError(f"{self.path / 'scene'}: no scene views (*.png)")
        return [_read_png(p) for p in views]

    def trajectory_frames(self, n_frames: int) -> list[Image]:
        frames_dir, video = self.path / "frames", self.path / "trajectory.mp4"
        if frames_dir.is_dir() and any(frames_dir.glob("*.png")):
            files = sorted(frames_dir.glob("*.png"))
            return [_read_png(files[i]) for i in sample_frame_indices(len(files), n_frames)]
        if video.is_file():
            return [Image.from_array(f) for f in read_video_frames(video, n_frames)]
        raise BundleError(f"{self.path}: no trajectory (trajectory.mp4 or frames/*.png)")


def _read_png(path: Path) -> Image:
    from PIL import Image as PILImage, UnidentifiedImageError

    try:
        with PILImage.open(path) as im:
            im.verify()  # catches truncated or non-image files before a paid call is made
    except (UnidentifiedImageError, OSError, SyntaxError) as e:
        raise BundleError(f"unreadable image {path}: {e}") from e
    return Image.from_png(path.read_bytes())


def sample_frame_indices(n_total: int, n_frames: int) -> list[int]:
    """`n_frames` indices spread evenly over [0, n_total - 1], first and last included, in order."""
    if n_total < 1:
        raise BundleError("trajectory has no frames")
    if n_frames < 2:
        raise ValueError(f"n_frames must be >= 2 (first and last), got {n_frames}")
    return sorted(set(np.linspace(0, n_total - 1, min(n_frames, n_total)).round().astype(int).tolist()))


def count_video_frames(path: Path) -> int | None:
    """Frames of the first video stream, counted from its packets (ffmpeg `-c copy -f framecrc` lists one line
    per packet; nothing is decoded); None when ffmpeg is missing or cannot tell."""
    import subprocess

    try:
        import imageio_ffmpeg

        res = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-nostdin", "-v", "error", "-i", str(path), "-map",
                              "0:v:0", "-c", "copy", "-f", "framecrc", "-"], capture_output=True, timeout=120)
    except (ImportError, OSError, RuntimeError, subprocess.SubprocessError):
        return None
    if res.returncode != 0:
        return None
    return sum(1 for line in res.stdout.decode(errors="ignore").splitlines() if line and not line.startswith("#"))


def read_video_frames(path: Path, n_frames: int) -> list[np.ndarray]:
    """The sampled frames of a video, decoded once as a stream that keeps only the sampled frames (memory holds
    `n_frames` frames however long the trajectory is). The frame count comes from the container's packets (no
    decoding); should the decoded count differ from it, the video is decoded a second time with the true count."""
    import imageio.v3 as iio

    try:
        total = count_video_frames(path)
        if total:
            wanted = set(sample_frame_indices(total, n_frames))
            kept, decoded = {}, 0
            for i, frame in enumerate(iio.imiter(path)):
                decoded = i + 1
                if i in wanted:
                    kept[i] = frame
            if decoded == total:
                return [kept[i] for i in sorted(kept)]
            log.warning("%s: the container lists %d frames but %d were decoded; decoding again", path, total, decoded)
        total = sum(1 for _ in iio.imiter(path))
        wanted = set(sample_frame_indices(total, n_frames))
        return [frame for i, frame in enumerate(iio.imiter(path)) if i in wanted]
    except BundleError:
        raise
    except Exception as e:  # imageio raises many types for a damaged video; all mean the same to the user
        raise BundleError(f"unreadable video {path}: {type(e).__name__}: {e}") from e


def validate_ground_truth(gt, where: str) -> dict:
    """task.yaml's `ground_truth`, checked: {success: bool, progress: float in [0, 1]}, either optional (null is
    unknown). Raises BundleError naming `where`, the key and the value."""
    if gt is None:
        return {}
    if not isinstance(gt, dict):
        raise BundleError(f"{where}: ground_truth must be a mapping like {{success: true, progress: 0.7}}, "
                          f"got {type(gt).__name__} {gt!r}")
    unknown = sorted(str(k) for k in gt if k not in ("success", "progress"))
    if unknown:
        raise BundleError(f"{where}: ground_truth has unknown key(s) {unknown}; valid: success, progress")
    out = {}
    if gt.get("success") is not None:
        if not isinstance(gt["success"], bool):
            raise BundleError(f"{where}: ground_truth.success must be true or false, got {gt['success']!r} "
                              f"({type(gt['success']).__name__})")
        out["success"] = gt["success"]
    if gt.get("progress") is not None:
        p = gt["progress"]
        if isinstance(p, bool) or not isinstance(p, (int, float)) or not math.isfinite(p) or not 0 <= p <= 1:
            raise BundleError(f"{where}: ground_truth.progress must be a number in [0, 1], got {p!r} "
                              f"({type(p).__name__})")
        out["progress"] = float(p)
    return out


def check_unique_names(bundles: list[TaskBundle], where: str) -> None:
    """A task's name is its identity in result.json: two bundles with one name would be merged. Raises a
    BundleError naming every folder (or episode file) that shares a name."""
    by_name: dict[str, list[str]] = {}
    for b in bundles:
        by_name.setdefault(b.name, []).append(str(b.path))
    dups = {n: paths for n, paths in by_name.items() if len(paths) > 1}
    if dups:
        name, paths = next(iter(sorted(dups.items())))
        more = f" (and {len(dups) - 1} more shared name(s))" if len(dups) > 1 else ""
        raise BundleError(f"{where}: task name {name!r} is used by {len(paths)} bundles: {' and '.join(paths)}; "
                          f"a task's name (task.yaml `name:`, else its folder name) must be unique{more}")


def load_bundles(root: str | os.PathLike) -> tuple[list[TaskBundle], dict[str, str]]:
    """(bundles, errors by folder name). A missing root, or two bundles with one task name, is an error; a bad
    bundle (task.yaml unreadable, no description, bad ground truth) is reported and skipped."""
    root = Path(root).expanduser()
    if not root.is_dir():
        raise BundleError(f"bundles_dir {root} does not exist (expected <root>/<task>/task.yaml)")
    bundles, errors = [], {}
    for d in sorted(p for p in root.iterdir() if p.is_dir()):
        meta_path = d / "task.yaml"
        try:
            meta = yaml.safe_load(meta_path.read_text(encoding="utf-8")) if meta_path.is_file() else None
            if not isinstance(meta, dict) or not isinstance(meta.get("description"), str):
                raise BundleError(f"{meta_path}: needs a mapping with a `description` string")
            for key in ("name", "pipeline"):
                if meta.get(key) is not None and not isinstance(meta[key], (str, int)):
                    raise BundleError(f"{meta_path}: `{key}` must be a string, got {meta[key]!r}")
            truth = validate_ground_truth(meta.get("ground_truth"), str(meta_path))
        except BundleError as e:
            errors[d.name] = str(e)
            continue
        except (yaml.YAMLError, UnicodeDecodeError) as e:
            errors[d.name] = f"{meta_path}: not readable YAML ({' '.join(str(e).split())})"
            continue
        pipeline = None if meta.get("pipeline") is None else str(meta["pipeline"])
        bundles.append(TaskBundle(str(meta.get("name", d.name)), d, meta["description"], pipeline, truth, meta))
    if not bundles and not errors:
        raise BundleError(f"{root}: no task bundles (<task>/task.yaml) found")
    check_unique_names(bundles, str(root))
    return bundles, errors
