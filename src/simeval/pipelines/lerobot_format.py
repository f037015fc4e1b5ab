"""LeRobotDataset folders, read into the episode store and written from it, without the `lerobot` package at run time:
pyarrow reads and writes the parquet files, PyAV (the decoder lerobot itself falls back to) the mp4 files. Why not
lerobot: it pins an older torch and a CUDA-linked torchvision; its on-disk format is plain parquet + mp4 + JSON.
tests/test_lerobot.py checks both directions against lerobot 0.4.4's own writer and reader (`make lerobot-env`).

Layouts read (`meta/info.json` names its `codebase_version`):
  v3.0   meta/tasks.parquet (index: task text; column task_index); meta/episodes/chunk-*/file-*.parquet (a row per
         episode: episode_index, tasks, length, data/{chunk,file}_index, videos/<key>/{chunk_index, file_index,
         from_timestamp, to_timestamp}); data/chunk-*/file-*.parquet (a row per frame, several episodes per file);
         videos/<key>/chunk-*/file-*.mp4 (several episodes per file, each from its from_timestamp)
  v2.0, v2.1   meta/episodes.jsonl ({episode_index, tasks, length}), meta/tasks.jsonl ({task_index, task}); one
         parquet per episode at info's data_path, one mp4 per episode and camera at its video_path
Features: `observation.images.*` (or `observation.image`), dtype video or image, are the cameras (a depth map is
left out); `observation.state` the state, `observation.environment_state` appended to it (the state reading of
Table 4 reads object state where a dataset has it); `action`; `next.reward`; `next.success`; timestamp,
frame_index, episode_index, index and task_index are lerobot's own columns.

Mapping into the store (simeval.episodes.store's rows), frame t of an episode of T + 1 frames = row t:
  obs/rgb/<camera> (T+1, H, W, 3), the key without "observation.images."; obs/state = observation.state
  [+ observation.environment_state], state_names from info's feature names; action = action, row T keeping the
  dataset's last action (no transition reads it); reward[t] = next.reward[t] (0 without it); success: any
  next.success, else, where next.reward is 0/1 only, any reward of 1; otherwise unknown (success_known
  False), as the authors' GenSim files; progress unknown; control_hz = fps; the episode's task text (its first
  task) is the description and names the task (task_name), unless the episode's row has simeval/task (and
  simeval/group), which simeval's export writes: a round trip keeps the store's tasks and groups; seed =
  episode_index; the action space's kind is "lerobot:<robot_type>" and its dims the action's names.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from simeval.episodes.episode import Episode, EpisodeFormatError
from simeval.errors import UserError
from simeval.pipelines.import_parts import (NoDemonstrations, Stored, pipeline_name, resize_frames, sparse_success,
                                            task_name)

log = logging.getLogger(__name__)

READS = ("v2.0", "v2.1", "v3.0")
WRITES = "v3.0"
LEROBOT_COLUMNS = ("timestamp", "frame_index", "episode_index", "index", "task_index")
CAMERA_PREFIX = "observation.images."
ENV_STATE = "observation.environment_state"
# columns of meta/episodes that simeval's export adds (lerobot reads past them): a LeRobot task is an instruction,
# and a pipeline whose instructions vary per episode (colours, objects) would come back as a task per instruction
SIMEVAL_KEYS = {"task": "simeval/task", "group": "simeval/group"}


def _simeval_columns(row: dict) -> dict[str, str]:
    """{task, group} of an episode's row where simeval's export wrote them (SIMEVAL_KEYS); {} in anyone else's."""
    return {k: str(row[c]) for k, c in SIMEVAL_KEYS.items() if row.get(c)}


def _names(feature: dict, n: int) -> list[str]:
    """A feature's per-dimension names: lerobot writes a list, older datasets {"motors": [...]}; else x0, x1, ..."""
    names = feature.get("names")
    if isinstance(names, dict):
        names = next((v for v in names.values() if isinstance(v, list)), None)
    if isinstance(names, list) and len(names) == n and all(isinstance(x, str) for x in names):
        return list(names)
    return [f"x{i}" for i in range(n)]


def _width(feature: dict) -> int:
    return int(np.prod(feature.get("shape") or [1]))


@dataclass(frozen=True)
class Camera:
    key: str  # the dataset's feature key
    name: str  # the store's camera name
    video: bool  # an mp4 (else images in the parquet)


@dataclass
class LeRobotInfo:
    """What meta/info.json says, checked."""

    root: Path
    version: str
    fps: float
    features: dict
    data_path: str
    video_path: str | None
    robot_type: str
    cameras: list[Camera]
    ignored: list[str]

    @classmethod
    def read(cls, root: Path) -> LeRobotInfo:
        path = root / "meta" / "info.json"
        if not path.is_file():
            raise NoDemonstrations(root, "no meta/info.json: not a LeRobotDataset folder (meta/info.json, data/, "
                                         "videos/)")
        try:
            info = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise EpisodeFormatError(f"{path}: not readable JSON ({e})") from e
        version = str(info.get("codebase_version"))
        if version not in READS:
            raise EpisodeFormatError(f"{path}: codebase_version {version!r}; simeval reads {', '.join(READS)}")
        features = info.get("features")
        if not isinstance(features, dict) or "action" not in features:
            raise EpisodeFormatError(f"{path}: features has no 'action' (has {sorted(features or {})})")
        try:
            fps = float(info["fps"])
        except (KeyError, TypeError, ValueError) as e:
            raise EpisodeFormatError(f"{path}: fps is missing or not a number") from e
        cameras, ignored, depth = [], [], []
        for key, f in features.items():
            if f.get("dtype") not in ("video", "image"):
                continue
            shape = list(f.get("shape") or [])
            names = list(f.get("names") or [])
            channels = shape[names.index("channels")] if "channels" in names else (shape[-1] if shape else 0)
            if (f.get("info") or {}).get("video.is_depth_map") or channels != 3:
                depth.append(key)
                continue
            name = key[len(CAMERA_PREFIX):] if key.startswith(CAMERA_PREFIX) else key.rsplit(".", 1)[-1]
            cameras.append(Camera(key, name, f["dtype"] == "video"))
        if not cameras:
            what = f" ({', '.join(depth)}: depth maps or not 3-channel)" if depth else ""
            raise EpisodeFormatError(f"{path}: features: no RGB camera{what}; simeval's world model, judges and "
                                     "policies need one")
        if any(c.video for c in cameras) and not info.get("video_path"):
            raise EpisodeFormatError(f"{path}: video features but no video_path")
        used = {"action", "observation.state", ENV_STATE, "next.reward", "next.success", *LEROBOT_COLUMNS}
        used |= {c.key for c in cameras}
        ignored = sorted(set(features) - used - set(depth))
        if depth:
            log.info("%s: left out (depth or not RGB): %s", root, ", ".join(depth))
        return cls(root, version, fps, features, str(info.get("data_path")), info.get("video_path"),
                   str(info.get("robot_type") or "unknown"), cameras, ignored + depth)


@dataclass(frozen=True)
class EpisodeEntry:
    index: int
    tasks: list[str]
    length: int
    data_file: Path
    videos: dict[str, tuple[Path, float]]  # camera key -> (mp4, the episode's first timestamp in it)
    simeval: dict[str, str] = field(default_factory=dict)  # task, group: what simeval's export wrote (SIMEVAL_KEYS)


def _read_parquet(path: Path, columns: list[str] | None = None):
    import pyarrow as pa
    import pyarrow.parquet as pq

    if not path.is_file():
        raise EpisodeFormatError(f"{path}: missing")
    try:
        return pq.read_table(path, columns=columns)
    except (pa.ArrowException, OSError) as e:
        raise EpisodeFormatError(f"{path}: not a readable parquet file ({type(e).__name__}: {e})") from e


def _read_jsonl(path: Path) -> list[dict]:
    if not path.is_file():
        raise EpisodeFormatError(f"{path}: missing")
    rows = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if line.strip():
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError as e:
                raise EpisodeFormatError(f"{path}: line {n} is not JSON ({e.msg})") from e
    return rows


def episode_entries(info: LeRobotInfo) -> list[EpisodeEntry]:
    """Every episode the metadata lists, with the files holding it."""
    root, out = info.root, []
    if info.version == "v3.0":
        files = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
        if not files:
            raise EpisodeFormatError(f"{root / 'meta' / 'episodes'}: no chunk-*/file-*.parquet")
        for f in files:
            table = _read_parquet(f).to_pylist()
            for row in table:
                try:
                    videos = {c.key: (root / info.video_path.format(
                        video_key=c.key, chunk_index=int(row[f"videos/{c.key}/chunk_index"]),
                        file_index=int(row[f"videos/{c.key}/file_index"])),
                        float(row[f"videos/{c.key}/from_timestamp"])) for c in info.cameras if c.video}
                    data = root / info.data_path.format(chunk_index=int(row["data/chunk_index"]),
                                                        file_index=int(row["data/file_index"]))
                    out.append(EpisodeEntry(int(row["episode_index"]), list(row.get("tasks") or []),
                                            int(row["length"]), data, videos,
                                            _simeval_columns(row)))
                except (KeyError, TypeError, ValueError) as e:
                    raise EpisodeFormatError(f"{f}: episode row without {e} (has {sorted(row)[:8]} ...)") from e
        return sorted(out, key=lambda e: e.index)
    chunk_size = 1000
    for row in _read_jsonl(root / "meta" / "episodes.jsonl"):
        try:
            i = int(row["episode_index"])
            chunk = i // chunk_size
            videos = {c.key: (root / info.video_path.format(episode_chunk=chunk, video_key=c.key, episode_index=i),
                              0.0) for c in info.cameras if c.video}
            out.append(EpisodeEntry(i, list(row.get("tasks") or []), int(row["length"]),
                                    root / info.data_path.format(episode_chunk=chunk, episode_index=i), videos,
                                    _simeval_columns(row)))
        except (KeyError, TypeError, ValueError) as e:
            raise EpisodeFormatError(f"{root / 'meta' / 'episodes.jsonl'}: an episode without {e}") from e
    return sorted(out, key=lambda e: e.index)


def task_texts(info: LeRobotInfo) -> dict[int, str]:
    """task_index -> task text."""
    if info.version == "v3.0":
        table = _read_parquet(info.root / "meta" / "tasks.parquet").to_pandas()
        if "task_index" not in table:
            raise EpisodeFormatError(f"{info.root / 'meta' / 'tasks.parquet'}: no task_index column")
        texts = table["task"] if "task" in table else table.index
        return {int(i): str(t) for i, t in zip(table["task_index"], texts)}
    return {int(r["task_index"]): str(r["task"]) for r in _read_jsonl(info.root / "meta" / "tasks.jsonl")}


class _FrameTables:
    """The frames of one data file at a time (a v3.0 file holds many episodes, read in order)."""

    def __init__(self) -> None:
        self.path: Path | None = None
        self.table = None

    def rows(self, path: Path, episode: int) -> dict[str, np.ndarray]:
        import pyarrow.compute as pc

        if path != self.path:
            self.path, self.table = path, _read_parquet(path)
        t = self.table
        if "episode_index" not in t.column_names:
            raise EpisodeFormatError(f"{path}: no episode_index column")
        rows = t.filter(pc.equal(t["episode_index"], episode))
        return {name: rows[name] for name in rows.column_names}


def _column(rows: dict, key: str, path: Path, width: int) -> np.ndarray:
    col = rows[key].combine_chunks() if hasattr(rows[key], "combine_chunks") else rows[key]
    import pyarrow as pa

    if pa.types.is_fixed_size_list(col.type) or pa.types.is_list(col.type):
        values = col.flatten().to_numpy(zero_copy_only=False)
    else:
        values = col.to_numpy(zero_copy_only=False)
    try:
        return np.asarray(values).reshape(len(col), width)
    except ValueError as e:
        raise EpisodeFormatError(f"{path}: column {key} does not hold {width} values a frame") from e


def decode_video(path: Path, start: float, n: int, fps: float) -> np.ndarray:
    """n frames (n, H, W, 3) uint8 of the mp4 at `path` from time `start` (seconds), one every 1/fps, by PyAV; a
    missing or truncated file is an EpisodeFormatError naming it."""
    import av

    if not path.is_file():
        raise EpisodeFormatError(f"{path}: missing")
    frames: dict[int, np.ndarray] = {}
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            if start > 0:
                container.seek(int(start / stream.time_base), stream=stream, backward=True)
            for frame in container.decode(stream):
                i = int(round((float(frame.time) - start) * fps))
                if i >= n:
                    break
                if i >= 0:
                    frames[i] = frame.to_ndarray(format="rgb24")
    except (av.FFmpegError, IndexError, ValueError) as e:
        raise EpisodeFormatError(f"{path}: not a readable video ({type(e).__name__}: {e})") from e
    if len(frames) < n:
        raise EpisodeFormatError(f"{path}: {len(frames)} of the {n} frames from {start:g} s (truncated?)")
    return np.stack([frames[i] for i in range(n)])


def _images(rows: dict, key: str, path: Path) -> np.ndarray:
    import io

    from PIL import Image

    out = []
    for cell in rows[key].to_pylist():
        data = cell.get("bytes") if isinstance(cell, dict) else None
        if data is None and isinstance(cell, dict) and cell.get("path"):
            image = path.parents[2] / cell["path"]  # relative to the dataset's root (an absolute path stays itself)
            if not image.is_file():
                raise EpisodeFormatError(f"{path}: column {key} names {image}, which is missing")
            data = image.read_bytes()
        if data is None:
            raise EpisodeFormatError(f"{path}: column {key} holds a frame without image bytes")
        out.append(np.asarray(Image.open(io.BytesIO(data)).convert("RGB")))
    return np.stack(out).astype(np.uint8)


def _success(rows: dict, path: Path) -> tuple[bool, bool]:
    """(success, success_known) of an episode (see the module docstring)."""
    if "next.success" in rows:
        return bool(_column(rows, "next.success", path, 1).any()), True
    if "next.reward" in rows:
        return sparse_success(_column(rows, "next.reward", path, 1))
    return False, False


def source_of(root: str | os.PathLike) -> str:
    """What an imported episode's `source` says: the dataset's folder (import_into_store refuses to mix two)."""
    return f"lerobot:{Path(root).expanduser().resolve()}"


def import_lerobot(root: str | os.PathLike, *, image_size: tuple[int, int] | None = None,
                   groups: dict | None = None, name: str | None = None, stored=None) -> Iterator:
    """The episodes of a LeRobotDataset folder (v2.0, v2.1 or v3.0) as store Episodes, or Stored where `stored`
    says the store holds one already (its frames are then not decoded). `name`: the pipeline name (default: the
    folder's name); `groups`: task name or text -> group (default "all")."""
    root = Path(root).expanduser()
    info = LeRobotInfo.read(root)
    pipeline = name or pipeline_name(root.resolve().name)
    texts = task_texts(info)
    features = info.features
    tables = _FrameTables()
    action_names = _names(features["action"], _width(features["action"]))
    state_keys = [k for k in ("observation.state", ENV_STATE) if k in features]
    state_names = [n if k == "observation.state" else f"environment_state.{n}"
                   for k in state_keys for n in _names(features[k], _width(features[k]))]
    if info.ignored:
        log.info("%s: features not imported: %s", root, ", ".join(info.ignored))
    for entry in episode_entries(info):
        text = entry.tasks[0] if entry.tasks else f"episode {entry.index}"
        task = entry.simeval.get("task") or task_name(text)  # simeval's export: the task its episodes had
        if stored is not None and stored(pipeline, task, entry.index):
            yield Stored(pipeline, task, entry.index)
            continue
        rows = tables.rows(entry.data_file, entry.index)
        n = len(rows["episode_index"])
        if n != entry.length or n < 2:
            raise EpisodeFormatError(f"{entry.data_file}: episode {entry.index} has {n} frames, its metadata says "
                                     f"{entry.length} (at least 2 needed)")
        order = np.argsort(_column(rows, "frame_index", entry.data_file, 1).ravel(), kind="stable")
        if not np.array_equal(order, np.arange(n)):
            rows = {k: v.take(order) for k, v in rows.items()}
        rgb = {}
        for cam in info.cameras:
            if cam.video:
                video, start = entry.videos[cam.key]
                frames = decode_video(video, start, n, info.fps)
            else:
                frames = _images(rows, cam.key, entry.data_file)
            rgb[cam.name] = resize_frames(frames, image_size)
        state = [_column(rows, k, entry.data_file, _width(features[k])).astype(np.float32) for k in state_keys]
        reward = (_column(rows, "next.reward", entry.data_file, 1).ravel().astype(np.float32)
                  if "next.reward" in rows else np.zeros(n, np.float32))
        success, known = _success(rows, entry.data_file)
        step_tasks = [texts.get(int(i), text) for i in _column(rows, "task_index", entry.data_file, 1).ravel()] \
            if "task_index" in rows else None
        views = [frames[0] for frames in rgb.values()]
        yield Episode(
            pipeline=pipeline, task=task, description=text, group=(groups or {}).get(task, (groups or {}).get(
                text, entry.simeval.get("group", "all"))), seed=entry.index, rgb=rgb,
            state=np.concatenate(state, axis=1) if state else np.zeros((n, 0), np.float32),
            action=_column(rows, "action", entry.data_file, len(action_names)).astype(np.float32),
            reward=reward, is_first=np.arange(n) == 0, is_terminal=np.arange(n) == n - 1, success=success,
            success_known=known, control_hz=info.fps, source=source_of(root),
            action_space={"kind": f"lerobot:{info.robot_type}", "dims": action_names, "units": None,
                          "control_hz": info.fps, "alignment": "lerobot: a frame's action follows its observation"},
            state_names=state_names,
            language=step_tasks if step_tasks and len(set(step_tasks)) > 1 else None,
            scene_views=np.stack(views) if len({v.shape for v in views}) == 1 else views[0][None],
            extra={"episode_index": entry.index, "codebase_version": info.version, "robot_type": info.robot_type,
                   "tasks": entry.tasks})


# ---- writing: the store as a LeRobotDataset v3.0 -------------------------------------------------------------------

VIDEO_OPTIONS = {"g": "2", "crf": "30"}  # lerobot 0.4.4's encode_video_frames defaults (libsvtav1, yuv420p)
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)


# the smallest frames SVT-AV1 (PyAV's libsvtav1) encodes here: a width of 24 or a height of 2 kills the process with
# SIGFPE inside the encoder (measured 2026-12-07 with the pinned av: widths 16-24 crash, 26-64 encode; heights 4-64)
MIN_VIDEO_WIDTH, MIN_VIDEO_HEIGHT = 26, 4


class _VideoWriter:
    """One camera's frames of every exported episode, one after another in one AV1 mp4, as lerobot encodes them."""

    def __init__(self, path: Path, fps: float, height: int, width: int) -> None:
        import av
        from fractions import Fraction

        if height % 2 or width % 2:
            raise UserError(f"{path}: frames of {height}x{width}: AV1 in yuv420p needs an even height and width "
                            "(image_size=[H, W] on import or collection)")
        if width < MIN_VIDEO_WIDTH or height < MIN_VIDEO_HEIGHT:  # SVT-AV1 dies of SIGFPE: no Python error at all
            raise UserError(f"{path}: frames of {height}x{width}: the AV1 encoder lerobot uses (SVT-AV1) needs at "
                            f"least {MIN_VIDEO_HEIGHT} rows and {MIN_VIDEO_WIDTH} columns (record.image_size=[H, W] "
                            "on collection, image_size= on import)")
        path.parent.mkdir(parents=True, exist_ok=True)
        os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its whole configuration per file unless told not to
        self.container = av.open(str(path), "w")
        self.stream = self.container.add_stream("libsvtav1", Fraction(fps).limit_denominator(100000),
                                                options=dict(VIDEO_OPTIONS))
        self.stream.pix_fmt, self.stream.height, self.stream.width = "yuv420p", height, width
        self.frames = 0

    def add(self, frames: np.ndarray) -> None:
        import av

        for f in frames:
            for packet in self.stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="rgb24")):
                self.container.mux(packet)
        self.frames += len(frames)

    def close(self) -> None:
        for packet in self.stream.encode():
            self.container.mux(packet)
        self.container.close()


class _Stats:
    """Per-feature min, max, mean, std, count and quantiles over every exported frame (meta/stats.json, which
    lerobot's policies normalise with); images per channel in [0, 1], as lerobot writes them."""

    def __init__(self) -> None:
        self.values: dict[str, list[np.ndarray]] = {}

    def add(self, key: str, values: np.ndarray) -> None:
        self.values.setdefault(key, []).append(np.asarray(values, np.float64))

    def result(self) -> dict:
        out = {}
        for key, parts in self.values.items():
            x = np.concatenate(parts)
            axes = (0, 1, 2) if x.ndim == 4 else 0  # images (N, H, W, 3): per channel
            s = {"min": x.min(axes), "max": x.max(axes), "mean": x.mean(axes), "std": x.std(axes),
                 "count": np.array([len(x)])}
            s.update({f"q{round(q * 100):02d}": np.quantile(x, q, axis=axes) for q in QUANTILES})
            if x.ndim == 4:  # lerobot's image stats are (3, 1, 1)
                s = {k: (v.reshape(3, 1, 1) if k != "count" else v) for k, v in s.items()}
            out[key] = {k: np.atleast_1d(v).tolist() for k, v in s.items()}
        return out


def _vector_feature(width: int, names: list[str], dtype: str = "float32") -> dict:
    return {"dtype": dtype, "shape": [width], "names": names}


def _exportable(paths: list[os.PathLike], fps: float | None) -> tuple[list[dict], float]:
    """The episodes' metadata and their one control rate, or a UserError naming the first episode that differs
    from the first in cameras, control rate or action space."""
    from simeval.episodes.store import read_meta

    if not paths:
        raise UserError("no episodes to export")
    metas = [read_meta(p) for p in paths]
    first = metas[0]
    rate = fps or float(first["control_hz"] or 0) or None
    if rate is None:
        raise UserError(f"{paths[0]}: the episode records no control rate; give fps=<frames per second>")
    mismatched = [m["path"] for m in metas if m["cameras"] != first["cameras"] or (not fps and float(
        m["control_hz"] or 0) != rate) or m["action_space"].get("kind") != first["action_space"].get("kind")]
    if mismatched:
        raise UserError(f"{mismatched[0]}: its cameras, control rate or action space differ from {first['path']}'s "
                        "(export one pipeline's episodes of one kind)")
    return metas, rate


def _features(ep: Episode, rate: float, success_known: bool) -> dict:
    """meta/info.json's features, from the first episode: a video per camera, state and action vectors (named as
    the store names them), reward, success where known, and lerobot's index columns."""
    h, w = next(iter(ep.rgb.values())).shape[1:3]
    features = {f"{CAMERA_PREFIX}{c}": {
        "dtype": "video", "shape": [h, w, 3], "names": ["height", "width", "channels"],
        "info": {"video.height": h, "video.width": w, "video.codec": "av1", "video.pix_fmt": "yuv420p",
                 "video.is_depth_map": False, "video.fps": rate, "video.channels": 3,
                 "has_audio": False}} for c in sorted(ep.rgb)}
    features["observation.state"] = _vector_feature(ep.state.shape[1], list(ep.state_names or [])
                                                    or _names({}, ep.state.shape[1]))
    dims = list(ep.action_space.get("dims") or [])
    features["action"] = _vector_feature(ep.action.shape[1], dims if len(dims) == ep.action.shape[1]
                                         else _names({}, ep.action.shape[1]))
    features["next.reward"] = {"dtype": "float32", "shape": [1], "names": None}
    if success_known:
        features["next.success"] = {"dtype": "bool", "shape": [1], "names": None}
    features.update({"timestamp": {"dtype": "float32", "shape": [1], "names": None},
                     **{k: {"dtype": "int64", "shape": [1], "names": None}
                        for k in ("frame_index", "episode_index", "index", "task_index")}})
    return features


def _frame_table(ep: Episode, episode: int, index: int, rate: float, task: int, success_known: bool):
    """One episode's rows of data/*.parquet (a pyarrow table): a frame per store row, from global row `index`."""
    import pyarrow as pa

    n = ep.n_steps
    columns = {"observation.state": pa.FixedSizeListArray.from_arrays(
                   pa.array(ep.state.astype(np.float32).ravel()), ep.state.shape[1]),
               "action": pa.FixedSizeListArray.from_arrays(pa.array(ep.action.astype(np.float32).ravel()),
                                                           ep.action.shape[1]),
               "next.reward": pa.array(np.asarray(ep.reward, np.float32))}
    if success_known:
        columns["next.success"] = pa.array((np.arange(n) == n - 1) & bool(ep.success))
    columns.update({"timestamp": pa.array((np.arange(n) / rate).astype(np.float32)),
                    "frame_index": pa.array(np.arange(n, dtype=np.int64)),
                    "episode_index": pa.array(np.full(n, episode, np.int64)),
                    "index": pa.array(np.arange(index, index + n, dtype=np.int64)),
                    "task_index": pa.array(np.full(n, task, np.int64))})
    return pa.table(columns)


def _episode_row(ep: Episode, episode: int, index: int, rate: float, starts: dict[str, float]) -> dict:
    """One row of meta/episodes/*.parquet: where the episode's frames and each camera's video span lie."""
    n = ep.n_steps
    row = {"episode_index": episode, "tasks": [ep.description], "length": n, "data/chunk_index": 0,
           "data/file_index": 0, "dataset_from_index": index, "dataset_to_index": index + n,
           SIMEVAL_KEYS["task"]: ep.task, SIMEVAL_KEYS["group"]: ep.group}
    for c, start in starts.items():
        row.update({f"videos/{CAMERA_PREFIX}{c}/chunk_index": 0, f"videos/{CAMERA_PREFIX}{c}/file_index": 0,
                    f"videos/{CAMERA_PREFIX}{c}/from_timestamp": start,
                    f"videos/{CAMERA_PREFIX}{c}/to_timestamp": start + n / rate})
    row.update({"meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0})
    return row


def _check_shapes(path: os.PathLike, ep: Episode, features: dict) -> None:
    if (features["observation.state"]["shape"] != [ep.state.shape[1]]
            or features["action"]["shape"] != [ep.action.shape[1]]):
        raise UserError(f"{path}: state or action width differs from the first episode's")
    for c, frames in ep.rgb.items():
        if list(frames.shape[1:]) != features[f"{CAMERA_PREFIX}{c}"]["shape"]:
            raise UserError(f"{path}: camera {c} is {frames.shape[1:3]}, the first episode's "
                            f"{features[f'{CAMERA_PREFIX}{c}']['shape'][:2]}")


def _write_meta(folder: Path, episodes: list[dict], texts: list[str], info: dict, stats: dict) -> None:
    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq

    (folder / "meta" / "episodes" / "chunk-000").mkdir(parents=True)
    pq.write_table(pa.Table.from_pylist(episodes), folder / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
    pd.DataFrame({"task_index": range(len(texts))}, index=pd.Index(texts, name="task")).to_parquet(
        folder / "meta" / "tasks.parquet")
    (folder / "meta" / "info.json").write_text(json.dumps(info, indent=4))
    (folder / "meta" / "stats.json").write_text(json.dumps(stats, indent=4))


def export_lerobot(paths: list[os.PathLike], out: str | os.PathLike, *, robot_type: str = "simeval",
                   fps: float | None = None, progress: bool = True) -> dict:
    """Write the store episodes at `paths` (one pipeline's; every one with the same cameras, image size, state and
    action widths and control rate) as a LeRobotDataset v3.0 at `out`: a frame per store row (row T's action
    included), each camera an AV1 mp4 as lerobot encodes it, the description as the task, next.success where
    the store knows success (on the last frame), next.reward the store's reward, meta/stats.json over every frame.
    Written in a temporary folder beside `out` and renamed into place, so a killed export leaves no dataset
    that looks complete. `fps`: the control rate where the episodes do not record one."""
    import shutil
    import tempfile

    import pyarrow.parquet as pq
    from tqdm import tqdm

    from simeval.episodes.store import read_episode

    out = Path(out).expanduser()
    metas, rate = _exportable(paths, fps)
    texts = list(dict.fromkeys(m["description"] for m in metas))
    success_known = all(m["success_known"] for m in metas)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        stats, videos, writer, episodes, features, index = _Stats(), {}, None, [], None, 0
        for e, path in enumerate(tqdm(paths, desc="exporting", unit="episode", disable=not progress, delay=1.0)):
            ep = read_episode(path)
            if features is None:
                features = _features(ep, rate, success_known)
                h, w = features[f"{CAMERA_PREFIX}{sorted(ep.rgb)[0]}"]["shape"][:2]
                videos = {c: _VideoWriter(tmp / "videos" / f"{CAMERA_PREFIX}{c}" / "chunk-000" / "file-000.mp4",
                                          rate, h, w) for c in sorted(ep.rgb)}
            _check_shapes(path, ep, features)
            starts = {c: videos[c].frames / rate for c in videos}
            for c, frames in ep.rgb.items():
                videos[c].add(frames)
                stats.add(f"{CAMERA_PREFIX}{c}", frames[:: max(1, ep.n_steps // 10)] / 255.0)  # lerobot samples too
            table = _frame_table(ep, e, index, rate, texts.index(ep.description), success_known)
            if writer is None:
                (tmp / "data" / "chunk-000").mkdir(parents=True)
                writer = pq.ParquetWriter(tmp / "data" / "chunk-000" / "file-000.parquet", table.schema)
            writer.write_table(table)
            stats.add("observation.state", ep.state)
            stats.add("action", ep.action)
            stats.add("next.reward", np.asarray(ep.reward)[:, None])
            episodes.append(_episode_row(ep, e, index, rate, starts))
            index += ep.n_steps
        writer.close()
        for v in videos.values():
            v.close()
        info = {"codebase_version": WRITES, "robot_type": robot_type, "total_episodes": len(paths),
                "total_frames": index, "total_tasks": len(texts), "chunks_size": 1000, "data_files_size_in_mb": 100,
                "video_files_size_in_mb": 200, "fps": int(rate) if float(rate).is_integer() else rate,
                "splits": {"train": f"0:{len(paths)}"},
                "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
                "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
                "features": features}
        _write_meta(tmp, episodes, texts, info, stats.result())
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return {"episodes": len(paths), "frames": index, "tasks": len(texts), "fps": rate, "out": str(out)}


import_lerobot.source_of = source_of
