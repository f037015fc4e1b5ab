"""The episode store: `<root>/<pipeline>/<task>/episode_<seed:06d>.h5`, one HDF5 file per episode.

Why HDF5 per episode: a worker writes its episode to a temp file and renames it into place, so a killed writer
never leaves a file a reader accepts, parallel workers never contend for one file, and "resume" is "skip the
files that exist". HDF5 gives chunked, compressed arrays that can be sliced without loading the episode (windows
for world models read only what they need) and is readable from any language.

Per step (T steps; datasets under the file root):
  obs/rgb/<camera>   uint8  (T, H, W, 3)   each recorded camera, chunked per frame, gzip
  obs/state          float32 (T, D)        proprioception (D may be 0 when a source has none)
  action             float32 (T, A)        low-level action
  reward             float32 (T,)          reward; `progress` float32 (T,) partial progress in [0, 1]
                                           (zeros, with attrs progress_known=False, when the source has none)
  is_first, is_terminal  bool (T,)
Per episode:
  high_level/action  float32 (H, K)        high-level actions (e.g. pick and place poses, 14-d)
  high_level/step    int64  (H,)           low-level index where each starts
  scene_views        uint8  (V, h, w, 3)   views of the initial scene for the judges (optional)
  attrs: schema, pipeline, task, description, group, seed, success, success_known, progress_known, total_reward,
         n_steps, cameras, control_hz, source, complete
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simeval.episodes.episode import Episode, EpisodeFormatError
from simeval.errors import UserError
from simeval.results import umask_file_mode

log = logging.getLogger(__name__)

SCHEMA = 1
STEP_KEYS = ("obs/state", "action", "reward", "progress", "is_first", "is_terminal")


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("_") or "task"


def write_episode(path: str | os.PathLike, ep: Episode, compression: str | None = "gzip") -> Path:
    """Write atomically: a temp file in the same folder, marked complete, then renamed into place."""
    import h5py

    ep.validate()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".tmp")
    os.fchmod(fd, umask_file_mode())  # mkstemp makes 0600 files; a shared store needs the mode others' files get
    os.close(fd)
    try:
        with h5py.File(tmp, "w") as f:
            for cam, frames in ep.rgb.items():
                f.create_dataset(f"obs/rgb/{cam}", data=frames, chunks=(1, *frames.shape[1:]) if len(frames) else None,
                                 compression=compression)
            f.create_dataset("obs/state", data=np.asarray(ep.state, np.float32).reshape(ep.n_steps, -1))
            f.create_dataset("action", data=np.asarray(ep.action, np.float32).reshape(ep.n_steps, -1))
            f.create_dataset("reward", data=np.asarray(ep.reward, np.float32))
            progress = ep.progress if ep.progress is not None else np.zeros(ep.n_steps, np.float32)
            f.create_dataset("progress", data=np.asarray(progress, np.float32))
            f.create_dataset("is_first", data=np.asarray(ep.is_first, bool))
            f.create_dataset("is_terminal", data=np.asarray(ep.is_terminal, bool))
            if ep.high_level_action is not None:
                f.create_dataset("high_level/action", data=np.asarray(ep.high_level_action, np.float32))
                f.create_dataset("high_level/step", data=np.asarray(ep.high_level_step, np.int64))
            if ep.scene_views is not None:
                f.create_dataset("scene_views", data=np.asarray(ep.scene_views, np.uint8), compression=compression)
            if ep.final_view is not None:
                f.create_dataset("final_view", data=np.asarray(ep.final_view, np.uint8), compression=compression)
            f.attrs.update({
                "schema": SCHEMA, "pipeline": ep.pipeline, "task": ep.task, "description": ep.description,
                "group": ep.group, "seed": int(ep.seed), "success": bool(ep.success),
                "success_known": bool(ep.success_known), "progress_known": ep.progress is not None,
                "total_reward": float(np.sum(ep.reward)), "n_steps": ep.n_steps,
                "cameras": json.dumps(sorted(ep.rgb)), "control_hz": float(ep.control_hz or 0.0),
                "source": ep.source, "extra": json.dumps(ep.extra, default=str),
            })
            f.attrs["complete"] = True  # written last: a file without it was cut short
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _open(path: Path):
    import h5py

    if not path.is_file():
        raise EpisodeFormatError(f"episode file not found: {path}")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise EpisodeFormatError(f"{path}: not a readable HDF5 episode ({e})") from e
    if not f.attrs.get("complete", False) or f.attrs.get("schema") != SCHEMA:
        f.close()
        raise EpisodeFormatError(f"{path}: incomplete episode or unknown schema (a writer was interrupted?)")
    return f


def read_meta(path: str | os.PathLike) -> dict:
    with _open(Path(path)) as f:
        meta = {k: (v.item() if hasattr(v, "item") else v) for k, v in f.attrs.items()}
    meta["cameras"] = json.loads(meta["cameras"])
    meta["extra"] = json.loads(meta.get("extra", "{}"))
    meta["path"] = str(path)
    return meta


def read_episode(path: str | os.PathLike, cameras: list[str] | None = None) -> Episode:
    path = Path(path)
    try:
        with _open(path) as f:
            a = dict(f.attrs)
            cams = json.loads(a["cameras"]) if cameras is None else cameras
            hl = "high_level/action" in f
            return Episode(
                pipeline=a["pipeline"], task=a["task"], description=a["description"], group=a["group"],
                seed=int(a["seed"]), rgb={c: f[f"obs/rgb/{c}"][()] for c in cams}, state=f["obs/state"][()],
                action=f["action"][()], reward=f["reward"][()], is_first=f["is_first"][()],
                is_terminal=f["is_terminal"][()], success=bool(a["success"]),
                progress=f["progress"][()] if a.get("progress_known", True) else None,
                success_known=bool(a.get("success_known", True)),
                high_level_action=f["high_level/action"][()] if hl else None,
                high_level_step=f["high_level/step"][()] if hl else None,
                scene_views=f["scene_views"][()] if "scene_views" in f else None,
                final_view=f["final_view"][()] if "final_view" in f else None,
                control_hz=float(a["control_hz"]) or None, source=a["source"], extra=json.loads(a.get("extra", "{}")))
    except (KeyError, OSError) as e:
        raise EpisodeFormatError(f"{path}: damaged episode ({type(e).__name__}: {e})") from e


class EpisodeStore:
    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root).expanduser()

    def path_for(self, pipeline: str, task: str, seed: int) -> Path:
        return self.root / _safe(pipeline) / _safe(task) / f"episode_{int(seed):06d}.h5"

    def exists(self, pipeline: str, task: str, seed: int) -> bool:
        return self.path_for(pipeline, task, seed).is_file()

    def exists_intact(self, pipeline: str, task: str, seed: int) -> bool:
        """Whether a readable episode is stored. An unreadable file at the path (0 bytes, damaged, another
        format) is moved aside as `<name>.corrupt-<time>` with a warning, so the episode is made again instead
        of blocking every later run; the bytes are kept for inspection."""
        path = self.path_for(pipeline, task, seed)
        if not path.is_file():
            return False
        try:
            read_meta(path)
            return True
        except EpisodeFormatError as e:
            self.move_aside(path, str(e))
            return False

    def move_aside(self, path: Path, why: str) -> Path:
        import time

        aside = path.with_name(f"{path.name}.corrupt-{time.strftime('%Y%m%dT%H%M%S')}-{os.getpid()}")
        try:
            os.replace(path, aside)
        except FileNotFoundError:  # another run on the same store moved it first
            return aside
        log.warning("%s: unreadable episode moved aside to %s; it will be made again (%s)", path, aside.name, why)
        return aside

    def write(self, ep: Episode) -> Path:
        return write_episode(self.path_for(ep.pipeline, ep.task, ep.seed), ep)

    def remove_stale_temp_files(self, older_than_s: float = 600.0) -> int:
        """Delete temp files that killed writers left behind (readers never see them; they only take space).
        Only old ones: a concurrent writer's fresh temp file is left alone."""
        import time

        removed = 0
        if self.root.is_dir():
            for tmp in self.root.glob("*/*/.episode_*.tmp"):
                if time.time() - tmp.stat().st_mtime > older_than_s:
                    tmp.unlink(missing_ok=True)
                    removed += 1
        return removed

    def paths(self, pipeline: str | None = None, task: str | None = None) -> list[Path]:
        base = self.root / _safe(pipeline) if pipeline else self.root
        pattern = f"{_safe(task)}/episode_*.h5" if task else ("*/episode_*.h5" if pipeline else "*/*/episode_*.h5")
        return sorted(base.glob(pattern))

    def index(self, pipeline: str | None = None, group: str | None = None) -> list[dict]:
        """Metadata of every complete episode (damaged files are an error naming the file)."""
        metas = [read_meta(p) for p in self.paths(pipeline)]
        return [m for m in metas if group in (None, "all", m["group"])]

    def first_k_per_task(self, k: int, pipeline: str | None = None, group: str | None = None) -> list[dict]:
        """The protocol of the paper's 10/20/40 episodes: the first k episodes of each task, by seed."""
        if k < 1:
            raise UserError(f"episodes per task must be >= 1, got {k}")
        by_task: dict[str, list[dict]] = {}
        for m in self.index(pipeline, group):
            by_task.setdefault(m["task"], []).append(m)
        out = []
        for task, metas in sorted(by_task.items()):
            metas.sort(key=lambda m: m["seed"])
            if len(metas) < k:
                raise UserError(f"task '{task}' has {len(metas)} episodes, fewer than the {k} asked for")
            out += metas[:k]
        return out


@contextlib.contextmanager
def _damage_names(path: Path) -> Iterator[None]:
    """h5py reports a damaged dataset or chunk as KeyError/OSError without the file name; add it."""
    try:
        yield
    except (KeyError, OSError) as e:
        raise EpisodeFormatError(f"{path}: damaged episode ({type(e).__name__}: {e})") from e


@dataclass
class WindowSpec:
    length: int
    stride: int | None = None  # default: non-overlapping windows (stride = length)
    cross_episodes: bool = False  # the authors' loaders concatenate episodes; off by default


def iter_windows(paths: list[str | os.PathLike], spec: WindowSpec, camera: str | None = None,
                 keys: tuple[str, ...] = STEP_KEYS) -> Iterator[dict[str, np.ndarray]]:
    """Fixed-length windows {key: (L, ...)} (+ "rgb" (L, H, W, 3) if `camera`). Without cross_episodes a window
    never spans two episodes (an episode shorter than L yields nothing); with it, episodes are read as one
    stream in order, as the DreamerV3 loaders of the paper's authors do, and `is_first` marks the seams."""

    stride = spec.stride or spec.length
    if spec.length < 1 or stride < 1:
        raise UserError(f"window length and stride must be >= 1, got {spec.length}, {stride}")
    buffer: dict[str, list[np.ndarray]] = {}
    for p in paths:
        p = Path(p)
        with _open(p) as f:  # a damaged or incomplete file is a clear error naming it
            if camera is not None and f"obs/rgb/{camera}" not in f:
                raise EpisodeFormatError(f"{p}: no camera '{camera}' (has {json.loads(f.attrs['cameras'])})")
            with _damage_names(p):
                data = {k: f[k] for k in keys}
                if camera is not None:
                    data["rgb"] = f[f"obs/rgb/{camera}"]
                n = len(data["action"])
            if not spec.cross_episodes:
                for start in range(0, n - spec.length + 1, stride):
                    with _damage_names(p):  # slices are read lazily; a damaged chunk is reported with its file
                        window = {k: v[start : start + spec.length] for k, v in data.items()}
                    yield window
                continue
            with _damage_names(p):
                for k, v in data.items():
                    buffer.setdefault(k, []).append(v[()])
        if spec.cross_episodes:
            stream = {k: np.concatenate(v) for k, v in buffer.items()}
            total = len(stream["action"])
            start = 0
            while start + spec.length <= total:
                yield {k: v[start : start + spec.length] for k, v in stream.items()}
                start += stride
            keep = start  # what no window has consumed yet stays for the next episode
            buffer = {k: [v[keep:]] for k, v in stream.items()}
