"""Importers of other pipelines' demonstrations into the episode store.

Formats (each file is a pickle: only import files you trust, as with any pickle):
  ravens     GenSim/CLIPort `cliport/demos.py`: <data>/<task>-<mode>/{color,depth,action,reward,info}/<ep:06d>-<seed>.pkl
             color uint8 (T+1, cams, H, W, 3); depth float32 (T+1, cams, H, W) (optional); action list of
             {pose0, pose1} (position, xyzw quaternion) ending in None; reward list (reward[t+1] follows action
             t); info list of {object id: (position, quaternion, dimensions), "lang_goal": str}. Stored in the
             store's convention with T + 1 rows (the final, solved observation kept; the last action padded),
             action space `pick_place_14d` (Ravens' convention is the one simeval.sim.env uses), per-step language
             goals, object poses and depth; the description is the task-level one (`descriptions`, else the one
             goal when every step has the same, else the task name in words), never a sub-goal.
  gensim_pt  the paper authors' GenSim files <task>/episode_<i:03>_<len_high>_<len_low>.pt (torch.save'd dict)
  bbsea_pt   the authors' BBSEA files <scene>/<task description>/<episode_id>_<True|False>.pt
  robogen_pt the authors' RoboGen files <task>/episode_<i>_<len>.pt
  lerobot    a LeRobotDataset folder, v2.0/v2.1/v3.0 (simeval.pipelines.lerobot_format)
  robomimic  a robomimic / robosuite HDF5 file (simeval.pipelines.robomimic_format)
"""

from __future__ import annotations

import os
import pickle
import re
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from simeval.episodes.episode import Episode, EpisodeFormatError
from simeval.episodes.store import read_meta
from simeval.errors import UserError
from simeval.pipelines.import_parts import (IsStored, NoDemonstrations, Stored,  # noqa: F401 (image_size_option:
                                            image_size_option, never_stored, resize_frames)  # import_data's)
from simeval.pipelines.lerobot_format import import_lerobot
from simeval.pipelines.robomimic_format import import_robomimic
from simeval.sim.action_spaces import pick_place_action_space
from simeval.pipelines.bbsea.tasks import bbsea_group, utf8_name
from simeval.pipelines.gensim.tasks import gensim_groups


def _episode_files(root: Path, pattern: str, name: str, layout: str) -> list[tuple[Path, re.Match]]:
    """Files under `root` matching the glob `pattern` whose name fully matches the regex `name`; none is an
    error that shows the expected layout."""
    found = [(p, m) for p in sorted(root.glob(pattern)) if (m := re.fullmatch(name, p.name))]
    if not found:
        raise NoDemonstrations(root, f"no episode files ({layout})")
    return found


def _uint8_images(v, path: Path, key: str) -> np.ndarray:
    """Images as uint8, converted by their range: uint8 as is; integers in [0, 255] cast; floats in [0, 1]
    scaled by 255 (a plain cast would make every frame black); floats in [0, 255] rounded. A float image whose
    values all lie in [0, 1] is taken as [0, 1] (a [0, 255] image that dark is black either way). Any other range
    is refused rather than guessed."""
    v = v.detach().cpu().numpy() if hasattr(v, "detach") else np.asarray(v)
    if v.dtype == np.uint8 or v.size == 0:
        return v.astype(np.uint8, copy=False)
    if v.dtype.kind in "iufb":
        lo, hi = float(np.min(v)), float(np.max(v))  # NaN propagates, and fails every test below
        if v.dtype.kind == "f" and 0 <= lo and hi <= 1:
            return np.round(v * 255).astype(np.uint8)
        if 0 <= lo and hi <= 255:
            return np.round(v).astype(np.uint8) if v.dtype.kind == "f" else v.astype(np.uint8)
        seen = f"values in [{lo:g}, {hi:g}]"
    else:
        seen = "not numbers"
    raise EpisodeFormatError(f"{path}: images '{key}' are {v.dtype}, {seen}; expected uint8, or floats in [0, 1] or "
                             "[0, 255]")


def _load_pickle(path: Path):
    try:
        with path.open("rb") as f:
            return pickle.load(f)
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ValueError) as e:
        raise EpisodeFormatError(f"{path}: unreadable pickle ({type(e).__name__}: {e})") from e


def _load_torch(path: Path) -> dict:
    import torch

    try:
        data = torch.load(path, map_location="cpu", weights_only=False)  # numpy arrays inside: trusted files only
    except Exception as e:  # torch raises many types for a damaged file; all mean "cannot read this file"
        raise EpisodeFormatError(f"{path}: unreadable torch file ({type(e).__name__}: {e})") from e
    if not isinstance(data, dict):
        raise EpisodeFormatError(f"{path}: expected a dict, got {type(data).__name__}")
    return data


def _arr(d: dict, key: str, path: Path, dtype=None) -> np.ndarray:
    if key not in d:
        raise EpisodeFormatError(f"{path}: missing key '{key}' (has {sorted(d)})")
    v = d[key]
    v = v.detach().cpu().numpy() if hasattr(v, "detach") else np.asarray(v)
    return v.astype(dtype) if dtype is not None else v


def _group(groups: dict | None, task: str, default: str) -> str:
    return (groups or {}).get(task, default)


def _source_action_space(fmt: str, dim: int) -> dict:
    """The action space of the authors' files: their own convention, stored as they are (not re-aligned to the
    store's row convention, which these files do not document)."""
    return {"kind": f"{fmt}_action", "dims": [f"a{i}" for i in range(dim)], "units": None, "control_hz": None,
            "alignment": "as in the source files"}


def _resize_depth(depth: np.ndarray, size: tuple[int, int] | None) -> np.ndarray:
    if size is None or tuple(depth.shape[1:3]) == tuple(size):
        return np.ascontiguousarray(depth, dtype=np.float32)
    from PIL import Image

    h, w = size
    return np.stack([np.asarray(Image.fromarray(f.astype(np.float32), mode="F").resize((w, h), Image.NEAREST))
                     for f in depth]).astype(np.float32)


def _ravens_object_poses(info: list) -> np.ndarray | None:
    """(T+1, N, 7) poses of the objects Ravens lists in every step's info (integer keys), or None."""
    ids = sorted(k for k in (info[0] or {}) if isinstance(k, (int, np.integer)))
    if not ids or any(not isinstance(i, dict) or any(k not in i for k in ids) for i in info):
        return None
    try:
        return np.asarray([[np.r_[np.asarray(i[k][0], float), np.asarray(i[k][1], float)] for k in ids]
                           for i in info], np.float32)
    except (TypeError, ValueError, IndexError):
        return None


def _pose14(pose0, pose1) -> np.ndarray:
    (p0, q0), (p1, q1) = pose0, pose1
    return np.concatenate([np.asarray(p0), np.asarray(q0), np.asarray(p1), np.asarray(q1)]).astype(np.float32)


def _ravens_pose14(action, path: Path, index: int) -> np.ndarray:
    """One Ravens action {pose0, pose1}, each (position xyz, quaternion xyzw), as the 14-d pick/place pose."""
    try:
        pose = _pose14(action["pose0"], action["pose1"])
        if pose.shape != (14,):
            raise ValueError(f"{pose.size} numbers, not 3 + 4 per pose")
    except (KeyError, TypeError, ValueError, IndexError) as e:
        got = sorted(action) if isinstance(action, dict) else type(action).__name__
        raise EpisodeFormatError(f"{path}: action {index} is not {{pose0, pose1}} of ((x, y, z), (qx, qy, qz, qw)) "
                                 f"(got {got}; {type(e).__name__}: {e})") from e
    return pose


def import_ravens(root: str | os.PathLike, *, image_size: tuple[int, int] | None = None,
                  groups: dict | None = None, descriptions: dict | None = None,
                  stored: IsStored = never_stored) -> Iterator[Episode | Stored]:
    root = Path(root).expanduser()
    dirs = sorted(p for p in root.iterdir() if p.is_dir() and (p / "action").is_dir()) if root.is_dir() else []
    if not dirs:
        raise NoDemonstrations(root, "no Ravens demo folders (<task>-<mode>/action/*.pkl)")
    for d in dirs:
        task = re.sub(r"-(train|val|test)$", "", d.name)
        for action_file in sorted((d / "action").glob("*.pkl")):
            m = re.fullmatch(r"(\d+)-(\d+)\.pkl", action_file.name)
            if not m:
                continue
            seed = int(m.group(2))
            if stored("gensim", task, seed):
                yield Stored("gensim", task, seed)
                continue
            parts = {k: _load_pickle(d / k / action_file.name) for k in ("color", "action", "reward", "info")}
            color = _uint8_images(parts["color"], d / "color" / action_file.name, "color")
            if not isinstance(parts["action"], (list, tuple)):
                raise EpisodeFormatError(f"{d / 'action' / action_file.name}: expected a list of actions, got "
                                         f"{type(parts['action']).__name__}")
            actions = [a for a in parts["action"] if a is not None]
            t = len(actions)
            if color.ndim != 5 or len(color) < t + 1 or t == 0:
                raise EpisodeFormatError(f"{d / 'color' / action_file.name}: expected (T+1, cams, H, W, 3) for {t} "
                                         f"actions (the final observation included), got {color.shape}")
            color = color[: t + 1]
            reward = np.asarray(parts["reward"], dtype=np.float32)[1 : t + 1]  # reward[t+1] follows action t
            info = list(parts["info"] or [])[: t + 1]
            goals = [(i or {}).get("lang_goal") if isinstance(i, dict) else None for i in info]
            language = [g or "" for g in goals] if len(goals) == t + 1 and any(goals) else None
            distinct = list(dict.fromkeys(g for g in goals if g))
            description = ((descriptions or {}).get(task) or (distinct[0] if len(distinct) == 1 else None)
                           or task.replace("-", " "))
            depth_file = d / "depth" / action_file.name
            depth = np.asarray(_load_pickle(depth_file), np.float32)[: t + 1] if depth_file.is_file() else None
            if depth is not None and (depth.ndim != 4 or depth.shape[:2] != color.shape[:2]):
                raise EpisodeFormatError(f"{depth_file}: expected (T+1, cams, H, W) depth matching color "
                                         f"{color.shape[:2]}, got {depth.shape}")
            hl = np.stack([_ravens_pose14(a, d / "action" / action_file.name, i) for i, a in enumerate(actions)])
            progress = np.r_[0.0, np.cumsum(reward)].clip(0, 1).astype(np.float32)
            poses = _ravens_object_poses(info) if len(info) == t + 1 else None
            yield Episode(
                pipeline="gensim", task=task, description=description,
                group=_group(groups, task, (gensim_groups(task) or ["ungrouped"])[0]), seed=seed,
                rgb={f"color_{c}": resize_frames(color[:, c], image_size) for c in range(color.shape[1])},
                depth={f"color_{c}": _resize_depth(depth[:, c], image_size) for c in range(depth.shape[1])}
                if depth is not None else None,
                state=np.zeros((t + 1, 0), np.float32), action=np.concatenate([hl, hl[-1:]]),  # last row: padding
                reward=np.r_[reward, 0.0].astype(np.float32), progress=progress,
                is_first=np.arange(t + 1) == 0, is_terminal=np.arange(t + 1) == t, success=bool(reward.sum() > 0.99),
                high_level_action=hl, high_level_step=np.arange(t), scene_views=resize_frames(color[0], image_size),
                source=f"ravens:{d}", action_space=pick_place_action_space(), high_level_space=pick_place_action_space(),
                state_names=[], language=language, object_poses=poses,
                extra={"mode": d.name[len(task) + 1 :] or None, "episode": int(m.group(1)),
                       "object_ids": sorted(k for k in (info[0] or {}) if isinstance(k, (int, np.integer)))
                       if poses is not None else None})


def import_gensim_pt(root: str | os.PathLike, *, image_size: tuple[int, int] | None = None,
                     groups: dict | None = None, descriptions: dict | None = None) -> Iterator[Episode]:
    """(The seed is stored inside these files, so each is loaded even on a resumed import.)"""
    root = Path(root).expanduser()
    for path, _ in _episode_files(root, "*/episode_*.pt", r"episode_\d+_\d+_\d+\.pt",
                                  "GenSim: <task>/episode_<i>_<H>_<L>.pt"):
        d = _load_torch(path)
        task = path.parent.name
        low, high = d.get("obs_low") or {}, d.get("action_high") or {}
        rgb = _uint8_images(_arr(low, "rgb", path), path, "obs_low.rgb")
        n = len(rgb)
        hl = np.concatenate([_arr(high, "pose0", path, np.float32), _arr(high, "pose1", path, np.float32)], axis=1)
        obs_high = d.get("obs_high") or {}
        views = [obs_high[f"color_{c}"][0] for c in range(3) if f"color_{c}" in obs_high]
        views = [resize_frames(_uint8_images(v, path, "obs_high.color")[None], image_size)[0] for v in views]
        same_shape = len({v.shape for v in views}) == 1  # the authors' cameras differ in size unless resized
        yield Episode(
            pipeline="gensim", task=task, description=(descriptions or {}).get(task, task),
            group=_group(groups, task, (gensim_groups(task) or ["ungrouped"])[0]), seed=int(d.get("seed", 0)),
            rgb={"rgb": resize_frames(rgb, image_size)}, state=_arr(low, "state", path, np.float32),
            action=_arr(d, "action_low", path, np.float32), reward=np.zeros(n, np.float32),
            is_first=_arr(d, "is_first", path, bool), is_terminal=_arr(d, "is_terminal", path, bool),
            high_level_action=hl, high_level_step=np.asarray(d.get("high_step"), np.int64),
            scene_views=np.stack(views) if views and same_shape else None,
            source=f"gensim_pt:{path}", success_known=False,
            action_space=_source_action_space("gensim_pt", _arr(d, "action_low", path).reshape(n, -1).shape[1]),
            high_level_space=pick_place_action_space())


def _image_state_episode(path: Path, d: dict, image_size, **fields) -> Episode:
    """The BBSEA and RoboGen files share one layout: image, state, action, is_first, is_terminal."""
    image = _uint8_images(_arr(d, "image", path), path, "image")
    state = _arr(d, "state", path, np.float32)
    action = _arr(d, "action", path, np.float32)
    fields.setdefault("action_space",
                      _source_action_space(fields["pipeline"] + "_pt", action.reshape(len(action), -1).shape[1]))
    return Episode(rgb={"image": resize_frames(image, image_size)}, state=state,
                   action=action, reward=np.zeros(len(image), np.float32),
                   is_first=_arr(d, "is_first", path, bool), is_terminal=_arr(d, "is_terminal", path, bool),
                   scene_views=resize_frames(image[:1], image_size), **fields)


def import_bbsea_pt(root: str | os.PathLike, *, image_size: tuple[int, int] | None = None,
                    stored: IsStored = never_stored) -> Iterator[Episode | Stored]:
    root = Path(root).expanduser()
    for path, m in _episode_files(root, "*/*/*.pt", r"(\d+)_(True|False)\.pt",
                                  "BBSEA: <scene>/<task description>/<id>_<True|False>.pt"):
        desc, scene = utf8_name(path.parent), utf8_name(path.parent.parent)
        if stored("bbsea", f"{scene}/{desc}", int(m.group(1))):
            yield Stored("bbsea", f"{scene}/{desc}", int(m.group(1)))
            continue
        yield _image_state_episode(
            path, _load_torch(path), image_size, pipeline="bbsea", task=f"{scene}/{desc}", description=desc,
            group=bbsea_group(desc), seed=int(m.group(1)), success=m.group(2) == "True", source=f"bbsea_pt:{path}",
            extra={"scene": scene})


def import_robogen_pt(root: str | os.PathLike, *, image_size: tuple[int, int] | None = None,
                      groups: dict | None = None, descriptions: dict | None = None,
                      stored: IsStored = never_stored) -> Iterator[Episode | Stored]:
    root = Path(root).expanduser()
    for path, m in _episode_files(root, "*/episode_*.pt", r"episode_(\d+)_(\d+)\.pt",
                                  "RoboGen: <task>/episode_<i>_<len>.pt"):
        task = path.parent.name
        if stored("robogen", task, int(m.group(1))):
            yield Stored("robogen", task, int(m.group(1)))
            continue
        yield _image_state_episode(
            path, _load_torch(path), image_size, pipeline="robogen", task=task,
            description=(descriptions or {}).get(task, task.replace("_", " ")), group=_group(groups, task, "ungrouped"),
            seed=int(m.group(1)), source=f"robogen_pt:{path}", success_known=False)


IMPORTERS = {"ravens": import_ravens, "gensim_pt": import_gensim_pt, "bbsea_pt": import_bbsea_pt,
             "robogen_pt": import_robogen_pt, "lerobot": import_lerobot,
             "robomimic": import_robomimic}


def _naming_src(items: Iterator, src) -> Iterator:
    """`items`, with a folder that holds none of the format's files said as the `src=` key a user typed."""
    try:
        yield from items
    except NoDemonstrations as e:
        raise UserError(f"src={src}: {e.what}; give the folder that holds the demonstrations") from e


def import_into_store(importer: Callable[..., Iterator], src: str | os.PathLike, store, *, overwrite: bool = False,
                      progress: bool = True, **options) -> dict:
    """Run `importer(src, **options)` and write each episode unless the store holds it already, so an
    interrupted import resumes; importers that can tell from a file's path skip loading it altogether. A `src`
that does not exist or is a file is a UserError before any progress output."""
    import inspect

    from tqdm import tqdm

    folder = Path(src).expanduser()
    reads_files = getattr(importer, "reads_files", False)
    if not folder.exists():  # before any progress output: a typo is not "no demos found"
        raise UserError(f"src={src} does not exist; give the {'file' if reads_files else 'folder'} that holds the "
                        "demonstrations")
    if not folder.is_dir() and not reads_files:
        raise UserError(f"src={src}: is a file, not a folder; give the folder that holds the demonstrations")
    if folder.is_dir() and reads_files:
        raise UserError(f"src={src}: is a folder; give the file that holds the demonstrations")
    if "stored" in inspect.signature(importer).parameters:
        options["stored"] = never_stored if overwrite else store.exists_intact  # an unreadable file is moved aside
    written = skipped = 0
    per_task: dict[str, dict] = {}
    pipelines: set[str] = set()
    # delay: a folder without the format's layout fails at once, with its one line and no progress bar before it
    items = _naming_src(importer(src, **options), src)
    try:
        for item in tqdm(items, desc="importing", unit="episode", disable=not progress, delay=1.0):
            if item.pipeline not in pipelines:
                pipelines.add(item.pipeline)
                if hasattr(importer, "source_of") and not overwrite:
                    _refuse_another_source(store, item.pipeline, importer.source_of(src))
            written, skipped = _import_one(item, store, overwrite, per_task, written, skipped)
    except EpisodeFormatError as e:
        if written + skipped == 0:
            raise
        raise EpisodeFormatError(f"{e} ({written} episodes written and {skipped} already stored before it; the same "
                                 "command resumes after the fix)") from e
    return {"written": written, "skipped": skipped, "tasks": per_task, "pipelines": sorted(pipelines)}


def _refuse_another_source(store, pipeline: str, source: str) -> None:
    """A dataset imported under a name the store already holds from another dataset would mix the two (and an
    episode of the same task and seed would be kept as the old one): one line instead."""
    others = sorted({m["source"] for m in store.index(pipeline)} - {source}) if store.paths(pipeline) else []
    if others:
        raise UserError(f"name={pipeline}: the store {store.root} holds episodes of {pipeline} imported from "
                        f"{others[0].split(':', 1)[-1]}, not from this source; give another name= (or remove "
                        f"{store.root / pipeline})")


def _import_one(item, store, overwrite: bool, per_task: dict, written: int, skipped: int) -> tuple[int, int]:
    """One item of an import: written unless the store holds it, counted in `per_task`; (written, skipped)."""
    if isinstance(item, Stored):
        meta = read_meta(store.path_for(item.pipeline, item.task, item.seed))
        task, group, success, known, is_new = item.task, meta["group"], meta["success"], meta["success_known"], False
    else:
        task, group, success, known = item.task, item.group, item.success, item.success_known
        is_new = overwrite or not store.exists_intact(item.pipeline, item.task, item.seed)
    stats = per_task.setdefault(task, {"episodes": 0, "success": 0, "success_unknown": 0, "group": group})
    stats["episodes"] += 1
    stats["success"] += int(known and success)
    stats["success_unknown"] += int(not known)  # the source does not say: not counted as a failure
    if is_new:
        store.write(item)
        return written + 1, skipped
    return written, skipped + 1
