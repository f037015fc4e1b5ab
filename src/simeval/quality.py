"""Single-task quality: scene alignment (1-5) and task completion (0-10) from judges, over task bundles.

A task bundle is a folder:
    <root>/<task>/task.yaml        description (required), name, pipeline, ground_truth {success, progress} (optional)
    <root>/<task>/scene/*.png      the views of the initial scene (the paper uses 4), sorted by file name
    <root>/<task>/trajectory.mp4   or frames/*.png: the trajectory, from which `n_frames` are sampled evenly
                                   (first and last included) in order
Unreadable parts are a per-task error: the other tasks are still judged and the failures are reported.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from simeval.judges.prompts import PromptTemplate
from simeval.judges.providers import Image
from simeval.judges.runner import JudgeItem, ScoreRecord
from simeval.errors import UserError

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


def read_video_frames(path: Path, n_frames: int) -> list[np.ndarray]:
    """The sampled frames of a video, decoded as a stream: one pass counts the frames, a second keeps only the
    sampled ones, so memory holds `n_frames` frames however long the trajectory is."""
    import imageio.v3 as iio

    try:
        total = sum(1 for _ in iio.imiter(path))
        wanted = set(sample_frame_indices(total, n_frames))
        return [frame for i, frame in enumerate(iio.imiter(path)) if i in wanted]
    except BundleError:
        raise
    except Exception as e:  # imageio raises many types for a damaged video; all mean the same to the user
        raise BundleError(f"unreadable video {path}: {type(e).__name__}: {e}") from e


def load_bundles(root: str | os.PathLike) -> tuple[list[TaskBundle], dict[str, str]]:
    """(bundles, errors by folder name). A missing root is an error; a bad bundle is reported and skipped."""
    root = Path(root).expanduser()
    if not root.is_dir():
        raise FileNotFoundError(f"bundles_dir {root} does not exist (expected <root>/<task>/task.yaml)")
    bundles, errors = [], {}
    for d in sorted(p for p in root.iterdir() if p.is_dir()):
        meta_path = d / "task.yaml"
        try:
            meta = yaml.safe_load(meta_path.read_text(encoding="utf-8")) if meta_path.is_file() else None
            if not isinstance(meta, dict) or not isinstance(meta.get("description"), str):
                raise BundleError(f"{meta_path}: needs a mapping with a `description` string")
        except (yaml.YAMLError, BundleError, UnicodeDecodeError) as e:
            errors[d.name] = str(e)
            continue
        bundles.append(TaskBundle(str(meta.get("name", d.name)), d, meta["description"], meta.get("pipeline"),
                                  meta.get("ground_truth"), meta))
    if not bundles and not errors:
        raise FileNotFoundError(f"{root}: no task bundles (<task>/task.yaml) found")
    return bundles, errors


def completion_items(bundles: list[TaskBundle], template: PromptTemplate, n_frames: int = 8
                     ) -> tuple[list[JudgeItem], dict[str, str]]:
    items, errors = [], {}
    for b in bundles:
        try:
            frames = b.trajectory_frames(n_frames)
        except BundleError as e:
            errors[b.name] = str(e)
            continue
        items.append(JudgeItem(b.name, "task_completion", template, {"description": b.description}, frames,
                               SCALES["task_completion"], b.pipeline))
    return items, errors


def alignment_items(bundles: list[TaskBundle], template: PromptTemplate,
                    captions: dict[str, list[str]] | None = None) -> tuple[list[JudgeItem], dict[str, str]]:
    """VLM path (images in the request), or caption path (`captions[task]` = one caption per view, no images)."""
    items, errors = [], {}
    for b in bundles:
        try:
            if captions is None:
                items.append(JudgeItem(b.name, "scene_alignment", template, {"description": b.description},
                                       b.scene_images(), SCALES["scene_alignment"], b.pipeline))
            else:
                if b.name not in captions:
                    raise BundleError(f"{b.name}: no captions")
                text = "\n".join(f"View {i + 1}: {c}" for i, c in enumerate(captions[b.name]))
                items.append(JudgeItem(b.name, "scene_alignment", template,
                                       {"description": b.description, "captions": text}, [], SCALES["scene_alignment"],
                                       b.pipeline))
        except BundleError as e:
            errors[b.name] = str(e)
    return items, errors


def caption_items(bundles: list[TaskBundle], template: PromptTemplate) -> tuple[list[JudgeItem], dict[str, str]]:
    """One captioning request per scene view; the reply is free text (scale unused: any text is valid)."""
    items, errors = [], {}
    for b in bundles:
        try:
            for v, im in enumerate(b.scene_images()):
                items.append(JudgeItem(f"{b.name}#view{v}", "caption", template, {"description": b.description},
                                       [im], None, b.pipeline))
        except BundleError as e:
            errors[b.name] = str(e)
    return items, errors


def oracle_completion(bundles: list[TaskBundle]) -> dict[str, dict]:
    """Completion 0-10 from simulator ground truth: 10 x progress (partial reward in [0, 1]), else 10 x success."""
    out = {}
    for b in bundles:
        gt = b.ground_truth or {}
        if "progress" in gt:
            score = 10.0 * float(np.clip(float(gt["progress"]), 0.0, 1.0))
        elif "success" in gt:
            score = 10.0 if gt["success"] else 0.0
        else:
            continue
        out[b.name] = {"mean": score, "var": 0.0, "n_valid": 1, "n_invalid": 0, "scores": [score]}
    return out


def summarize(records: list[ScoreRecord]) -> dict[str, dict[str, dict]]:
    """{metric: {item: {mean, var (sample, ddof=1, as the paper's parentheses), n_valid, n_invalid, scores}}}.
    (The 5-repeat variances of the paper's tables match ddof=1, e.g. scores 0,0,0,0,2 give its "0.40 (0.80)".)"""
    out: dict[str, dict[str, dict]] = {}
    for rec in records:
        entry = out.setdefault(rec.metric, {}).setdefault(rec.item, {"scores": [], "n_invalid": 0})
        if rec.valid:
            entry["scores"].append(rec.score)
        else:
            entry["n_invalid"] += 1
    for per_item in out.values():
        for entry in per_item.values():
            s = np.asarray(entry["scores"], dtype=float)
            entry["n_valid"] = int(len(s))
            entry["mean"] = float(s.mean()) if len(s) else None
            entry["var"] = float(s.var(ddof=1)) if len(s) >= 2 else (0.0 if len(s) == 1 else None)
    return out


def evaluate_quality(bundles: list[TaskBundle], *, metric: str, mode: str, provider, templates: dict,
                     cache, ledger, settings, captioner=None, caption_settings=None, n_frames: int = 8,
                     dry: bool = False) -> dict:
    """Judge the bundles. Returns {"records": [ScoreRecord], "summary": summarize(...), "errors": {task: msg},
    "captions": {task: [..]}} or, with `dry`, {"dry_run": {...}, "errors": ...}."""
    from simeval.judges.runner import dry_run, run_judge

    if metric not in (*METRICS, "all"):
        raise ValueError(f"metric={metric!r}: expected scene_alignment, task_completion or all")
    if mode not in ("vlm", "caption"):
        raise ValueError(f"scene_alignment_mode={mode!r}: expected vlm or caption")
    wanted = METRICS if metric == "all" else (metric,)
    items, errors, captions, records = [], {}, None, []
    if "scene_alignment" in wanted and mode == "caption":
        if captioner is None:
            raise ValueError("scene_alignment_mode=caption needs a captioner (captioner=openai or captioner=hf)")
        cap_items, cap_errors = caption_items(bundles, templates["caption"])
        errors.update(cap_errors)
        if dry:
            plan = dry_run(cap_items, captioner, cache, ledger, caption_settings)
            return {"dry_run": {"captions": plan, "note": "judge calls on captions follow the captions"},
                    "errors": errors}
        cap_records = run_judge(cap_items, captioner, cache, ledger, caption_settings)
        captions = {}
        for rec in cap_records:
            task = rec.item.split("#view")[0]
            if rec.text is None:
                errors[task] = f"captioner gave no caption for {rec.item}"
                continue
            captions.setdefault(task, []).append(rec.text)
        captions = {t: c for t, c in captions.items() if t not in errors}
        records += cap_records
        al, al_err = alignment_items([b for b in bundles if b.name in captions], templates["scene_alignment_captions"],
                                     captions)
        items += al
        errors.update(al_err)
    elif "scene_alignment" in wanted:
        al, al_err = alignment_items(bundles, templates["scene_alignment_vlm"])
        items += al
        errors.update(al_err)
    if "task_completion" in wanted:
        tc, tc_err = completion_items(bundles, templates["task_completion"], n_frames)
        items += tc
        errors.update({k: (errors[k] + "; " + v if k in errors else v) for k, v in tc_err.items()})
    if dry:
        return {"dry_run": dry_run(items, provider, cache, ledger, settings), "errors": errors}
    records += run_judge(items, provider, cache, ledger, settings)
    summary = summarize([r for r in records if r.metric != "caption"])
    return {"records": records, "summary": summary, "errors": errors, "captions": captions}


def judge_reliability(records: list[ScoreRecord]) -> dict[str, dict]:
    """Per metric, agreement of the judge with itself across repeats: Krippendorff's alpha (interval; invalid
    replies are missing values) and ICC(1,1) on complete items. None where undefined (e.g. constant scores)."""
    from simeval.metrics.agreement import icc_1_1, krippendorff_alpha_interval

    out = {}
    for metric in dict.fromkeys(r.metric for r in records if r.metric != "caption"):
        recs = [r for r in records if r.metric == metric]
        items = list(dict.fromkeys(r.item for r in recs))
        repeats = max(r.repeat for r in recs) + 1
        x = np.full((len(items), repeats), np.nan)
        for r in recs:
            if r.score is not None:
                x[items.index(r.item), r.repeat] = r.score
        out[metric] = {"krippendorff_alpha": krippendorff_alpha_interval(x), "icc_1_1": icc_1_1(x),
                       "items": len(items), "repeats": repeats}
    return out


def resolve_bundles_dir(bundles_dir: str | None, episodes: dict, out_dir: Path) -> Path:
    """The bundles to judge: `bundles_dir`, or the episodes of a store (`episodes["store"]`) exported as bundles
    into `<out_dir>/bundles` (the other `episodes` keys go to export_bundles)."""
    if episodes.get("store"):
        from simeval.episodes.bundles import export_bundles

        target = Path(out_dir) / "bundles"
        export_bundles(episodes["store"], target, **{k: v for k, v in episodes.items() if k != "store"})
        return target
    if not bundles_dir:
        raise ValueError("set bundles_dir=DIR (or env SIMEVAL_BUNDLES), or episodes.store=DIR (an episode store)")
    return Path(bundles_dir)


def write_scores(path: Path, records: list[ScoreRecord]) -> Path:
    """Per-item provenance, one JSON line per (task, metric, repeat): model, template and image hashes, every
    raw reply with its parse and latency, the accepted score."""
    import dataclasses
    import json

    from simeval.results import atomic_write_text

    lines = [json.dumps(dataclasses.asdict(r) | {"valid": r.valid}) for r in records]
    return atomic_write_text(path, "\n".join(lines) + "\n")
