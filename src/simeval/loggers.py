"""Run loggers, chosen by the `logger` config group: none, csv, wandb. All are context managers so that
`finish()` runs even when the run fails.

Every logger has `log_metrics(mapping, step)` (nested mappings are flattened to `a/b/c` keys),
`log_table(name, columns, rows)`, where a cell may be a `LogImage` (a PNG path or an array, with a caption): W&B
gets a `wandb.Table` with images, the CSV logger a `<name>.csv` holding the image paths, the null logger nothing;
and `log_video(name, video, fps, caption)`, where video is an mp4/gif/webm/ogg file or (T, H, W, 3) uint8 frames
(written first to `<run_dir>/videos/<name>.mp4`): W&B gets a `wandb.Video` of the file (which needs no encoder),
the CSV logger a row of `videos.csv` (name, path, caption), the null logger nothing.
`wants_tables` says whether a logger keeps tables (csv, wandb), so a run skips building a table (reading images)
for the null logger. Loggers only log: the tables themselves are built by the runs (e.g. a quality run's per-task
scores with its images, simeval.measures.quality.run.log_task_table).

W&B runs are grouped and tagged so a dashboard is built by grouping: group `<metric>/<pipeline>` (the Hydra job
name, e.g. `quality/gensim`), tags `<config group>=<choice>` for every config choice plus `git=<sha>`, unless
`logger.group` / `logger.tags` say otherwise (given tags are kept and the derived ones added).
"""

from __future__ import annotations

import csv
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from simeval.results import redact_secrets


def _flatten(d: Mapping, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten(v, f"{key}/"))
        elif isinstance(v, (int, float, str, bool)) or v is None:
            out[key] = v
    return out


WANDB_TAG_MAX = 64  # W&B refuses longer tags
UNTAGGED_GROUPS = ("hydra", "logger")  # the same in every W&B run: a tag that groups nothing


@dataclass(frozen=True)
class LogImage:
    """An image cell of a logged table: a file on disk (`path`) or an HxWx3 uint8 array (`array`, e.g. a frame
    decoded from a video), and a caption."""
    path: str | None
    caption: str = ""
    array: Any = None

    def source(self) -> Any:
        return self.path if self.path is not None else self.array


class NullLogger:
    wants_tables = False  # runs skip building tables (which read images) for a logger that drops them

    def __init__(self, **_: Any) -> None:
        pass

    def log_metrics(self, metrics: Mapping, step: int | None = None) -> None:
        pass

    def log_table(self, name: str, columns: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
        pass

    def log_video(self, name: str, video: Any, fps: int = 15, caption: str = "") -> None:
        pass

    def _video_file(self, name: str, video: Any, fps: int) -> Path:
        """The file of a logged video: `video` itself when it is a path, else its frames written to
        `<run_dir>/videos/<name>.mp4` (slashes in the name become `_`)."""
        if isinstance(video, (str, os.PathLike)):
            path = Path(video)
            if not path.is_file():
                raise FileNotFoundError(f"video {name!r}: no file {path}")
            return path
        from simeval.media import write_video

        return write_video(video, Path(self.run_dir) / "videos" / f"{name.replace('/', '_')}.mp4", fps=fps)

    def finish(self, exit_code: int = 0) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.finish(exit_code=0 if exc_type is None else 1)


class CsvLogger(NullLogger):
    """Appends one row per `log_metrics` call to `<run_dir>/metrics.csv` (long format: step, key, value)."""
    wants_tables = True

    def __init__(self, run_dir: str, filename: str = "metrics.csv", **_: Any) -> None:
        self.run_dir = run_dir
        self.path = Path(run_dir) / filename
        self.path.parent.mkdir(parents=True, exist_ok=True)

    def log_metrics(self, metrics: Mapping, step: int | None = None) -> None:
        new = not self.path.exists()
        with self.path.open("a", newline="") as f:
            w = csv.writer(f)
            if new:
                w.writerow(["step", "key", "value"])
            for k, v in _flatten(metrics).items():
                w.writerow([step, k, v])

    def log_table(self, name: str, columns: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
        """`<run_dir>/<name>.csv` (slashes in the name become `_`); an image cell is written as its path, several
        images as paths joined by `;`."""
        def cell(v):
            if isinstance(v, LogImage):
                return v.path or "(decoded frame)"
            if isinstance(v, (list, tuple)) and v and all(isinstance(x, LogImage) for x in v):
                return ";".join(x.path or "(decoded frame)" for x in v)
            return v

        path = self.path.parent / f"{name.replace('/', '_')}.csv"
        with path.open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(list(columns))
            w.writerows([[cell(v) for v in r] for r in rows])

    def log_video(self, name: str, video: Any, fps: int = 15, caption: str = "") -> None:
        """A row (name, path, caption) of `<run_dir>/videos.csv`; frames are first written to an mp4."""
        path = self._video_file(name, video, fps)
        index = self.path.parent / "videos.csv"
        new = not index.exists()
        with index.open("a", newline="") as f:
            w = csv.writer(f)
            if new:
                w.writerow(["name", "path", "caption"])
            w.writerow([name, str(path), caption])


def image_strip(images: Sequence[LogImage], height: int = 128, gap: int = 4):
    """The readable images side by side at a common height (aspect kept), on white, as an HxWx3 uint8 array; None
    when none is readable."""
    import numpy as np
    from PIL import Image as PILImage

    tiles = []
    for im in images:
        try:
            pil = PILImage.open(im.path).convert("RGB") if im.path is not None else PILImage.fromarray(
                np.asarray(im.array, dtype=np.uint8)).convert("RGB")
        except (OSError, ValueError, TypeError):  # an unreadable view (the judge skipped it too) is left out
            continue
        w = max(1, round(pil.width * height / pil.height))
        tiles.append(np.asarray(pil.resize((w, height), PILImage.NEAREST)))
    if not tiles:
        return None
    width = sum(t.shape[1] for t in tiles) + gap * (len(tiles) - 1)
    strip = np.full((height, width, 3), 255, dtype=np.uint8)
    x = 0
    for t in tiles:
        strip[:, x:x + t.shape[1]] = t
        x += t.shape[1] + gap
    return strip


def run_context() -> tuple[str | None, dict[str, str]]:
    """(metric, config choices) of the current Hydra job: the job name (the entrypoint, e.g. `quality`) and the
    choice made in every config group except Hydra's own; (None, {}) outside Hydra."""
    try:
        from hydra.core.hydra_config import HydraConfig

        hc = HydraConfig.get()
    except (ImportError, ValueError):
        return None, {}
    from omegaconf import OmegaConf

    choices = OmegaConf.to_container(hc.runtime.choices)
    return hc.job.name, {k: str(v) for k, v in choices.items() if not k.startswith("hydra/") and v is not None}


def run_pipeline(run_config: Mapping, choices: Mapping) -> str:
    """The pipeline a run is about: the `pipeline` config (its name), an episode store's pipeline filter, a
    quality run's label, else `any` (e.g. agreement, which covers every pipeline of its tables)."""
    pipeline = run_config.get("pipeline")
    if isinstance(pipeline, Mapping) and pipeline.get("name"):
        return str(pipeline["name"])
    if choices.get("pipeline"):
        return str(choices["pipeline"])
    episodes = run_config.get("episodes")
    if isinstance(episodes, Mapping) and episodes.get("pipeline"):
        return str(episodes["pipeline"])
    return str(run_config.get("label") or "any")


def run_tags(choices: Mapping, sha: str | None) -> list[str]:
    """`group=choice` for each config choice (sorted; not hydra or logger) and `git=<12 hex>[-dirty]`, each cut to
    W&B's tag limit. A choice is what was picked in the group: `debug=tiny` may still shrink that node's values."""
    tags = [f"{k}={v}" for k, v in sorted(choices.items()) if k not in UNTAGGED_GROUPS]
    if sha:
        tags.append(f"git={sha[:12]}" + ("-dirty" if sha.endswith("-dirty") else ""))
    return [t[:WANDB_TAG_MAX] for t in tags]


class WandbLogger(NullLogger):
    """Weights & Biases, offline unless `mode=online`. The config is redacted of secrets before upload."""
    wants_tables = True

    def __init__(
        self,
        run_dir: str,
        project: str = "simeval",
        entity: str | None = None,
        mode: str = "offline",
        name: str | None = None,
        group: str | None = None,
        tags: list[str] | None = None,
        run_config: Mapping | None = None,
        **_: Any,
    ) -> None:
        if mode not in ("offline", "online", "disabled"):
            raise ValueError(f"logger.mode={mode!r}: expected one of offline, online, disabled")
        import wandb  # lazy: importing wandb costs ~1 s

        from simeval.results import git_sha

        self.run_dir = run_dir

        os.environ.setdefault("WANDB_SILENT", "true")
        # W&B stages the files of logged tables and images under $WANDB_DATA_DIR (default ~/.local/share/wandb)
        # until `wandb sync` uploads them: keep them with the run instead, so an offline run folder is whole
        self._data_dir_set = "WANDB_DATA_DIR" not in os.environ
        if self._data_dir_set:
            os.environ["WANDB_DATA_DIR"] = str(Path(run_dir).resolve() / "wandb" / "data")
        metric, choices = run_context()
        run_config = dict(run_config or {})
        if group is None and metric is not None:
            group = f"{metric}/{run_pipeline(run_config, choices)}"
        derived = run_tags(choices, git_sha())
        tags = list(dict.fromkeys([*(tags or []), *derived]))
        self.run = wandb.init(
            project=project, entity=entity, mode=mode, name=name, group=group, tags=tags, job_type=metric,
            dir=str(run_dir), config=redact_secrets(run_config), reinit="finish_previous",
        )

    def log_metrics(self, metrics: Mapping, step: int | None = None) -> None:
        # None is "undefined" (e.g. Pearson of a constant column): left out rather than charted as a value
        self.run.log({k: v for k, v in _flatten(metrics).items() if v is not None}, step=step)

    def log_table(self, name: str, columns: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
        """A `wandb.Table`; a LogImage cell becomes a `wandb.Image`, a list of them one image of the list side by
        side (image_strip). W&B copies the pixels into the run, so the table survives the bundles moving."""
        import wandb

        def cell(v):
            if isinstance(v, LogImage):
                return wandb.Image(v.source(), caption=v.caption or None)
            if isinstance(v, (list, tuple)) and v and all(isinstance(x, LogImage) for x in v):
                # a W&B table cell holds one image: several are shown side by side as one strip
                strip = image_strip(v)
                return None if strip is None else wandb.Image(
                    strip, caption=f"{len(v)} images: {v[0].caption} ... {v[-1].caption}")
            return v

        self.run.log({name: wandb.Table(columns=list(columns), data=[[cell(v) for v in r] for r in rows])})

    def log_video(self, name: str, video: Any, fps: int = 15, caption: str = "") -> None:
        """A `wandb.Video` of the file (frames are first written to an mp4 in the run folder): W&B copies it into
        the run's `media/videos/`, so the offline run is whole for `wandb sync`. Logged from a file because W&B
        encodes arrays with moviepy, which is not a dependency; a file's own frame rate is kept (fps is for arrays)."""
        import wandb

        path = self._video_file(name, video, fps)
        self.run.log({name: wandb.Video(str(path), caption=caption or None)})

    def finish(self, exit_code: int = 0) -> None:
        if self.run is not None:
            self.run.finish(exit_code=exit_code)
            self.run = None
        if getattr(self, "_data_dir_set", False):
            os.environ.pop("WANDB_DATA_DIR", None)
            self._data_dir_set = False
