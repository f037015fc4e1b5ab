"""The episode store: `<root>/<pipeline>/<task>/episode_<seed:06d>.h5`, one HDF5 file per episode.

Why HDF5 per episode: a worker writes its episode to a temp file and renames it into place, so a killed writer
never leaves a file a reader accepts, parallel workers never contend for one file, and "resume" is "skip the
files that exist". HDF5 gives chunked, compressed arrays that can be sliced without loading the episode (windows
for world models read only what they need) and is readable from any language.

The transition convention (format 2): an episode of T actions has T + 1 rows in every per-step array. Row t holds
the observation o_t and the action a_t taken after observing it; o_{t+1}, in row t + 1, is what a_t produced.
Row 0 is the observation at reset, before any action; row T is the final observation, and its action is padding
(a copy of a_{T-1}, i.e. "hold": nothing was taken there; `is_terminal` marks that row). reward[t] is what a_t
earned (progress[t+1] - progress[t]; 0 in row T) and progress[t] is the partial progress of o_t. So the
transitions for a world model are (row t, action t, row t + 1) for t < T, and a policy's training pairs are
(row t, action t) for t < T.

Per step (T + 1 rows; datasets under the file root):
  obs/rgb/<camera>   uint8  (T+1, H, W, 3)   each recorded camera, chunked per frame, gzip
  obs/depth/<camera> float32 (T+1, H, W)     depth in metres, when the source has it (optional)
  obs/robot_mask/<camera> bool (T+1, H, W)   the pixels showing the robot (arm, gripper, tool), from the same
                                             render as the frame (simeval's suites; optional: imported data has none)
  obs/state          float32 (T+1, D)        proprioception, names in attrs state_names (D may be 0)
  obs/object_poses   float32 (T+1, N, 7)     object positions + xyzw quaternions, when the source has them
                                             (simeval's suites: each body, then each of its links on a moving
                                             joint, as a drawer or a lid: the world pose of the joint's frame,
                                             so a hinged lid's row turns in place; extra.objects counts each
                                             object's bodies and links)
  obs/language       str (T+1,)              per-step language goal, when the source has one (optional)
  action             float32 (T+1, A)        the action taken at each row (row T: padding), see action_space
  reward             float32 (T+1,)          reward of the row's action; `progress` float32 (T+1,) partial
                                             progress of the row's observation in [0, 1] (zeros, with attrs
                                             progress_known=False, when the source has none)
  is_first, is_terminal  bool (T+1,)         the first row; the last row (the final observation)
Per episode:
  high_level/action  float32 (H, 14)       the primitives (Ravens' 14-d pick/place poses, simeval.sim.env)
  high_level/step    int64  (H,)           the row where each starts (the row it was chosen at)
  scene_views        uint8  (V, h, w, 3)   views of the initial scene for the judges (optional)
  attrs: schema, pipeline, task, description (task level), group, seed, success, success_known, progress_known,
         total_reward, n_steps (rows, T + 1), n_actions (T), cameras, control_hz, source, complete,
         action_space (JSON: kind, dims, units, control_hz; e.g. kind "joint_pos+suction" or "pick_place_14d"),
         high_level_space (JSON, when high_level/ exists), state_names (JSON), variation (JSON; {} = none),
         variation_id ("" = none)
A varied episode (a non-empty variation) lives at episode_<seed>.v<variation_id>.h5 beside the plain one, so
the two never collide. Readers refuse format-1 files (actions stored with the observation they had already
changed, no reset observation) with a message naming the file: re-collect or re-import them.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simeval.episodes.episode import Episode, EpisodeFormatError
from simeval.errors import UserError
from simeval.results import atomic_path

log = logging.getLogger(__name__)

SCHEMA = 2
STEP_KEYS = ("obs/state", "action", "reward", "progress", "is_first", "is_terminal")


def variation_id(variation: dict | None) -> str:
    """A short content hash of a variation ("" for none), used in episode file names."""
    if not variation:
        return ""
    return hashlib.sha1(json.dumps(variation, sort_keys=True, default=str).encode()).hexdigest()[:10]


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("_") or "task"


def write_episode(path: str | os.PathLike, ep: Episode, compression: str | None = "gzip") -> Path:
    """Write atomically: a temp file in the same folder, marked complete, then renamed into place."""
    import h5py

    ep.validate()
    path = Path(path)
    with atomic_path(path, prefix=f".{path.stem}.") as tmp:  # the umask's mode, renamed into place when complete
        with h5py.File(tmp, "w") as f:
            for cam, frames in ep.rgb.items():
                f.create_dataset(f"obs/rgb/{cam}", data=frames, chunks=(1, *frames.shape[1:]) if len(frames) else None,
                                 compression=compression)
            f.create_dataset("obs/state", data=np.asarray(ep.state, np.float32).reshape(ep.n_steps, -1))
            f.create_dataset("action", data=np.asarray(ep.action, np.float32).reshape(ep.n_steps, -1))
            f.create_dataset("reward", data=np.asarray(ep.reward, np.float32))
            for cam, d in (ep.depth or {}).items():
                f.create_dataset(f"obs/depth/{cam}", data=np.asarray(d, np.float32),
                                 chunks=(1, *np.shape(d)[1:]) if len(d) else None, compression=compression)
            for cam, m in (ep.robot_mask or {}).items():
                f.create_dataset(f"obs/robot_mask/{cam}", data=np.asarray(m, bool),
                                 chunks=(1, *np.shape(m)[1:]) if len(m) else None, compression=compression)
            if ep.object_poses is not None:
                f.create_dataset("obs/object_poses", data=np.asarray(ep.object_poses, np.float32))
            if ep.language is not None:
                f.create_dataset("obs/language", data=[str(x) for x in ep.language], dtype=h5py.string_dtype())
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
                "total_reward": float(np.sum(ep.reward)), "n_steps": ep.n_steps, "n_actions": ep.n_actions,
                "cameras": json.dumps(sorted(ep.rgb)), "control_hz": float(ep.control_hz or 0.0),
                "source": ep.source, "extra": json.dumps(ep.extra, default=str),
                "action_space": json.dumps(ep.action_space), "high_level_space": json.dumps(ep.high_level_space),
                "state_names": json.dumps(ep.state_names), "variation": json.dumps(ep.variation or {}, default=str),
                "variation_id": variation_id(ep.variation),
            })
            f.attrs["complete"] = True  # written last: a file without it was cut short
    return path


def _open(path: Path):
    import h5py

    if not path.is_file():
        raise EpisodeFormatError(f"episode file not found: {path}")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise EpisodeFormatError(f"{path}: not a readable HDF5 episode ({e})") from e
    schema = f.attrs.get("schema")
    if f.attrs.get("complete", False) and schema is not None and int(schema) < SCHEMA:
        f.close()
        raise EpisodeFormatError(f"{path}: episode format {int(schema)} (no reset observation; each action stored "
                                 f"with the observation it had already changed); this version reads format {SCHEMA}:"
                                 " re-collect it (src/collect.py) or re-import it (src/import_data.py)")
    if not f.attrs.get("complete", False) or schema != SCHEMA:
        f.close()
        raise EpisodeFormatError(f"{path}: incomplete episode or unknown schema (a writer was interrupted?)")
    return f


def read_meta(path: str | os.PathLike) -> dict:
    with _open(Path(path)) as f:
        meta = {k: (v.item() if hasattr(v, "item") else v) for k, v in f.attrs.items()}
    for key in ("cameras", "extra", "action_space", "high_level_space", "state_names", "variation"):
        meta[key] = json.loads(meta[key])
    meta["path"] = str(path)
    return meta


def read_recording(path: str | os.PathLike) -> dict:
    """How an episode was recorded, read from the file itself (so episodes of any version answer): record.cameras
    (sorted), record.image_size [H, W] of the per-step frames, record.scene_view_size [h, w] of the scene views
    (None without them), record.control_hz (None if unknown) and the action-space kind."""
    path = Path(path)
    with _open(path) as f, _damage_names(path):
        cams = json.loads(f.attrs["cameras"])
        size = list(f[f"obs/rgb/{cams[0]}"].shape[1:3]) if cams else None
        views = list(f["scene_views"].shape[1:3]) if "scene_views" in f else None
        hz = float(f.attrs["control_hz"]) or None
        kind = json.loads(f.attrs["action_space"]).get("kind")
    return {"record.cameras": sorted(cams), "record.image_size": size, "record.scene_view_size": views,
            "record.control_hz": hz, "action_space": kind}


def read_episode(path: str | os.PathLike, cameras: list[str] | None = None, cameras_key: str = "cameras") -> Episode:
    """The episode at `path`, with the frames of `cameras` (None: every recorded camera). A camera it does not
    record is a UserError naming `cameras_key`, the config key that asked for it."""
    path = Path(path)
    try:
        with _open(path) as f:
            a = dict(f.attrs)
            cams = json.loads(a["cameras"]) if cameras is None else cameras
            recorded = sorted(f["obs/rgb"]) if "obs/rgb" in f else []
            if cameras is not None and any(c not in recorded for c in cams):
                raise UserError(f"{cameras_key}=[{','.join(cams)}]: {path} records the cameras "
                                f"{', '.join(recorded) or '(none)'}; use those, or collect with record.cameras "
                                "including the others")
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
                control_hz=float(a["control_hz"]) or None, source=a["source"], extra=json.loads(a["extra"]),
                action_space=json.loads(a["action_space"]), high_level_space=json.loads(a["high_level_space"]),
                state_names=json.loads(a["state_names"]), variation=json.loads(a["variation"]),
                depth={c: f[f"obs/depth/{c}"][()] for c in cams if f"obs/depth/{c}" in f} or None,
                object_poses=f["obs/object_poses"][()] if "obs/object_poses" in f else None,
                robot_mask={c: f[f"obs/robot_mask/{c}"][()] for c in cams if f"obs/robot_mask/{c}" in f} or None,
                language=[x.decode() if isinstance(x, bytes) else str(x) for x in f["obs/language"][()]]
                if "obs/language" in f else None)
    except (KeyError, OSError) as e:
        raise EpisodeFormatError(f"{path}: damaged episode ({type(e).__name__}: {e})") from e


class EpisodeStore:
    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root).expanduser()

    def path_for(self, pipeline: str, task: str, seed: int, variation: dict | None = None) -> Path:
        vid = variation_id(variation)
        return self.root / _safe(pipeline) / _safe(task) / f"episode_{int(seed):06d}{'.v' + vid if vid else ''}.h5"

    def exists(self, pipeline: str, task: str, seed: int, variation: dict | None = None) -> bool:
        return self.path_for(pipeline, task, seed, variation).is_file()

    def exists_intact(self, pipeline: str, task: str, seed: int, variation: dict | None = None) -> bool:
        """Whether a readable episode is stored. An unreadable file at the path (0 bytes, damaged, another
        format, e.g. format 1) is moved aside as `<name>.corrupt-<time>` with a warning, so the episode is made
        again instead of blocking every later run; the bytes are kept for inspection."""
        path = self.path_for(pipeline, task, seed, variation)
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
        return write_episode(self.path_for(ep.pipeline, ep.task, ep.seed, ep.variation), ep)

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

    def first_k_per_task(self, k: int, pipeline: str | None = None, group: str | None = None,
                         variation_id: str | None = None) -> list[dict]:
        """The protocol of the paper's 10/20/40 episodes: the first k episodes of each task, by seed. Each
        variation of a task counts as a task of its own; `variation_id` keeps one ("" = the plain episodes)."""
        if k < 1:
            raise UserError(f"episodes per task must be >= 1, got {k}")
        by_task: dict[tuple[str, str], list[dict]] = {}
        for m in self.index(pipeline, group):
            if variation_id is None or m["variation_id"] == variation_id:
                by_task.setdefault((m["task"], m["variation_id"]), []).append(m)
        out = []
        for (task, vid), metas in sorted(by_task.items()):
            metas.sort(key=lambda m: m["seed"])
            if len(metas) < k:
                name = f"{task}' (variation {vid})" if vid else f"{task}'"
                raise UserError(f"task '{name} has {len(metas)} episodes, fewer than the {k} asked for")
            out += metas[:k]
        return out


def pipeline_episodes(store_root: str | os.PathLike, pipeline: str | None, group: str = "all") -> list[dict]:
    """Every episode's metadata of one pipeline (and group) of a store, or a UserError naming the config key
    (episodes.store, episodes.pipeline, episodes.group) and what the store holds: what the entrypoints that read a
    user's own pipeline from the store (src/export_data.py, src/evaluate.py) start from."""
    if not pipeline:
        raise UserError(f"episodes.pipeline is not set: episodes.pipeline=<a pipeline of the store {store_root}>")
    root = Path(store_root)
    if not root.is_dir():
        raise UserError(f"episodes.store={store_root}: no such folder")
    store = EpisodeStore(root)
    held = sorted(p.name for p in root.iterdir() if p.is_dir() and store.paths(p.name))
    if pipeline not in held:
        raise UserError(f"episodes.pipeline={pipeline}: the store {store_root} holds no episodes of it (it holds "
                        f"{', '.join(held) or 'none'})")
    metas = store.index(pipeline, group)
    if not metas:
        groups = sorted({m["group"] for m in store.index(pipeline)})
        raise UserError(f"episodes.group={group}: pipeline {pipeline} has no such group (it has {', '.join(groups)})")
    return metas


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
    """Fixed-length windows {key: (L, ...)} (+ "rgb" (L, H, W, 3) if `camera`) of rows (the module docstring's
    convention: within a window, row i's action produced row i + 1's observation, except at a row with
    `is_terminal`, whose action is padding). Every episode must have the same action-space kind (a UserError
    names the two kinds otherwise). Without cross_episodes a window never spans two episodes (an episode
    shorter than L yields nothing); with it, episodes are read as one stream in order, as the DreamerV3 loaders
    of the paper's authors do, and `is_first` marks the seams."""

    stride = spec.stride or spec.length
    if spec.length < 1 or stride < 1:
        raise UserError(f"window length and stride must be >= 1, got {spec.length}, {stride}")
    buffer: dict[str, list[np.ndarray]] = {}
    first_kind: tuple[str, Path] | None = None
    for p in paths:
        p = Path(p)
        with _open(p) as f:  # a damaged or incomplete file is a clear error naming it
            kind = json.loads(f.attrs["action_space"])["kind"]
            if first_kind is None:
                first_kind = (kind, p)
            elif kind != first_kind[0]:
                raise UserError(f"one training set mixes action spaces '{first_kind[0]}' ({first_kind[1]}) and "
                                f"'{kind}' ({p}); select episodes of one kind (read_meta(path)['action_space'])")
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
