"""robomimic / robosuite HDF5 demonstrations (the layout MimicGen, RoboCasa and robosuite's own demos use), read into
the episode store with h5py. tests/test_robomimic.py checks the reading against robomimic 0.3.0's SequenceDataset.

Layout read (one file):
  data/                          attrs: env_args (JSON: env_name, env_kwargs (control_freq, ...)), total
  data/demo_<N>/obs/<key>        (T, ...) per step: <camera>_image uint8 (T, H, W, 3); <camera>_depth (left out);
                                 every other key a low-dimensional observation (robot0_eef_pos, object, ...)
  data/demo_<N>/next_obs/<key>   (T, ...) the observation each action led to (optional)
  data/demo_<N>/actions (T, A), rewards (T,), dones (T,), states (T, S) (MuJoCo states: not read)
  mask/<filter key>              the names of the demos in a split (bytes), e.g. train / valid
Mapping into the store (simeval.episodes.store's rows): obs[t] is row t and actions[t] its action; with next_obs the
last next observation is row T (its action padding, a copy of the last), without it the last row keeps its own
action (no transition reads it). rgb: the *_image keys, named without "_image"; state: the other obs keys in sorted
order, flattened, named <key>.<i> (an `object` key is the objects' state, which the state reading of Table 4 uses);
reward[t] = rewards[t]; success: where rewards are 0/1 only, any reward of 1 (robosuite's sparse success reward),
else unknown; control_hz: env_kwargs.control_freq; the task is env_name (its description `descriptions[env_name]`,
else the name in words); seed = N; each episode's extra lists the filter keys that hold it.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from simeval.episodes.episode import Episode, EpisodeFormatError
from simeval.pipelines.import_parts import (NoDemonstrations, Stored, pipeline_name, resize_frames, sparse_success,
                                            task_name)


def _open(path: Path):
    import h5py

    if not path.is_file():
        raise NoDemonstrations(path, "not a file; give a robomimic HDF5 file (data/demo_N/{obs, actions})")
    try:
        return h5py.File(path, "r")
    except OSError as e:
        raise EpisodeFormatError(f"{path}: not a readable HDF5 file ({e})") from e


def _words(name: str) -> str:
    return re.sub(r"(?<=[a-z])(?=[A-Z])|[_-]+", " ", name).strip().lower()


def source_of(path: str | os.PathLike) -> str:
    """What an imported episode's `source` says: the file (import_into_store refuses to mix two under one name)."""
    return f"robomimic:{Path(path).expanduser().resolve()}"


def import_robomimic(src: str | os.PathLike, *, image_size: tuple[int, int] | None = None,
                     groups: dict | None = None, descriptions: dict | None = None, name: str | None = None,
                     filter_key: str | None = None, stored=None) -> Iterator:
    """The demos of a robomimic HDF5 file (all, or those of mask/<filter_key>) as store Episodes, or Stored where
    `stored` says the store holds one (its arrays are then not read). `name`: the pipeline (default: the file's
    stem)."""
    path = Path(src).expanduser()
    with _open(path) as f:
        if "data" not in f:
            raise EpisodeFormatError(f"{path}: no 'data' group: not a robomimic dataset (data/demo_N/{{obs, "
                                     f"actions}}; has {sorted(f)})")
        data = f["data"]
        try:
            env_args = json.loads(data.attrs.get("env_args", "{}"))
        except (TypeError, json.JSONDecodeError) as e:
            raise EpisodeFormatError(f"{path}: data.attrs['env_args'] is not JSON ({e})") from e
        env_name = str(env_args.get("env_name") or path.stem)
        control_hz = (env_args.get("env_kwargs") or {}).get("control_freq")
        masks = {k: {x.decode() if isinstance(x, bytes) else str(x) for x in f["mask"][k][()]}
                 for k in (f["mask"] if "mask" in f else [])}
        if filter_key is not None and filter_key not in masks:
            keys = ", ".join(sorted(masks)) or "none"
            raise EpisodeFormatError(f"{path}: no mask/{filter_key} (filter keys: {keys})")
        demos = sorted((k for k in data if re.fullmatch(r"demo_\d+", k)), key=lambda k: int(k.split("_")[1]))
        if filter_key is not None:
            demos = [d for d in demos if d in masks[filter_key]]
        if not demos:
            raise EpisodeFormatError(f"{path}: data/ holds no demo_<N> groups" +
                                     (f" in mask/{filter_key}" if filter_key else ""))
        pipeline = name or pipeline_name(path.stem)
        task = task_name(env_name)
        description = (descriptions or {}).get(env_name) or _words(env_name)
        for demo in demos:
            seed = int(demo.split("_")[1])
            if stored is not None and stored(pipeline, task, seed):
                yield Stored(pipeline, task, seed)
                continue
            yield _episode(path, data[demo], demo, pipeline=pipeline, task=task, description=description,
                           group=(groups or {}).get(task, (groups or {}).get(env_name, "all")), seed=seed,
                           env_name=env_name, control_hz=control_hz, image_size=image_size,
                           filter_keys=sorted(k for k, members in masks.items() if demo in members))


def _episode(path: Path, g, demo: str, *, env_name: str, control_hz, image_size, filter_keys: list[str],
             **fields) -> Episode:
    where = f"{path}: data/{demo}"
    for key in ("obs", "actions"):
        if key not in g:
            raise EpisodeFormatError(f"{where} has no '{key}' (has {sorted(g)})")
    try:
        actions = np.asarray(g["actions"][()], np.float32)
        actions = actions.reshape(len(actions), -1)
        n = len(actions)
        obs = {k: g["obs"][k][()] for k in g["obs"]}
        final = {k: g["next_obs"][k][-1:] for k in g["next_obs"]} if "next_obs" in g else None
        rewards = np.asarray(g["rewards"][()], np.float32).ravel() if "rewards" in g else None
    except (KeyError, OSError, ValueError) as e:
        raise EpisodeFormatError(f"{where}: damaged ({type(e).__name__}: {e})") from e
    bad = {k: len(v) for k, v in obs.items() if len(v) != n}
    if bad:
        raise EpisodeFormatError(f"{where}: {n} actions but obs lengths {bad}")
    if final is not None and set(final) >= set(obs):
        obs = {k: np.concatenate([v, final[k]]) for k, v in obs.items()}
        actions = np.concatenate([actions, actions[-1:]])  # row T: padding
        if rewards is not None:
            rewards = np.r_[rewards, 0.0].astype(np.float32)
    rows = len(actions)
    cameras = {k[: -len("_image")]: v for k, v in obs.items() if k.endswith("_image")}
    cameras = {k: v for k, v in cameras.items() if v.ndim == 4 and v.shape[-1] == 3}
    if not cameras:
        raise EpisodeFormatError(f"{where}/obs: no <camera>_image key of RGB frames (has {sorted(obs)})")
    low = sorted(k for k in obs if not k.endswith(("_image", "_depth")) and np.issubdtype(obs[k].dtype, np.number))
    state = [np.asarray(obs[k], np.float32).reshape(rows, -1) for k in low]
    names = [f"{k}.{i}" for k, s in zip(low, state) for i in range(s.shape[1])]
    success, known = sparse_success(rewards) if rewards is not None else (False, False)
    rgb = {c: resize_frames(np.asarray(v, np.uint8), image_size) for c, v in sorted(cameras.items())}
    views = [v[0] for v in rgb.values()]
    return Episode(
        rgb=rgb, state=np.concatenate(state, axis=1) if state else np.zeros((rows, 0), np.float32), action=actions,
        reward=rewards if rewards is not None else np.zeros(rows, np.float32), is_first=np.arange(rows) == 0,
        is_terminal=np.arange(rows) == rows - 1, success=success, success_known=known,
        control_hz=float(control_hz) if control_hz else None, source=source_of(path),
        action_space={"kind": f"robomimic:{env_name}", "dims": [f"a{i}" for i in range(actions.shape[1])],
                      "units": None, "control_hz": control_hz, "alignment": "robomimic: actions[t] follows obs[t]"},
        state_names=names, scene_views=np.stack(views) if len({v.shape for v in views}) == 1 else views[0][None],
        extra={"demo": demo, "filter_keys": filter_keys, "env_name": env_name}, **fields)


import_robomimic.reads_files = True  # src= is the HDF5 file, not a folder
import_robomimic.source_of = source_of
