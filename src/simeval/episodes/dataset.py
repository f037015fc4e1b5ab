"""Random-access windows over episodes, for sequence models (the world model of simeval.models.world_model).

The convention (the store's, simeval.episodes.store): an episode of T actions has T + 1 rows; row t holds the
observation o_t and the action a_t taken *after* observing it, so a_t produced o_{t+1} (row t + 1); row T's action is
padding. A window of rows [s, s + L) gives, per step i (row r = s + i):
    image[i], state[i]   o_r
    action[i]            a_r, the action that follows o_r (and produces o_{r+1}; padding at row T)
    prev_action[i]       a_{r-1}, the action that produced o_r (zeros at row 0: no action led to the reset)
    is_first[i]          r == 0;  mask[i]: r is a real row (False on padding before row 0 or after row T)
A recurrent model consumes (o_r, prev_action_r, is_first_r): that is DreamerV3's layout (p(o_{t+1} | o_t, a_t) in
the paper's words).

Windows never cross episodes. `WindowSpec` says how they are cut: every `stride` rows from a start `offset`,
optionally beginning up to `pad_start` rows before row 0 and running past the last row (`pad_end`); padded steps
have mask False, zero arrays and never count in a loss. `WindowSpec.random_offset` draws a new offset in
[0, stride) per epoch (seeded), so strided windows do not always cut at the same rows.

Which episodes: `episode_ranks` ranks each episode within its task by seed; `rank_mask(ranks, lo, hi)` keeps the
ranks in [lo, hi). The paper's protocol is rank < k for training (k = 10, 20, 40) and rank < 40 for evaluation;
held-out episodes are ranks 40..49.

Normalisation: `NormStats` (per-key mean and std of state and action over the training episodes) is stored with the
model and applied by the dataset (x - mean) / std; a constant dimension (std < 1e-6) gets std 1.

Sources: `StoreSource` reads HDF5 episodes lazily (one open file handle per episode per process, so DataLoader
workers each open their own), `ArraySource` holds episodes in memory (synthetic data, or a preloaded store).
Episodes of different action-space kinds (or dimensions) are refused: a model's action input has one meaning.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from simeval.episodes.episode import EpisodeFormatError
from simeval.errors import UserError, check_field_types, require_whole_fields


@dataclass
class WindowSpec:
    length: int
    stride: int = 1
    offset: int = 0  # first start (before padding), in [0, stride)
    random_offset: bool = False  # draw the offset per epoch from the seed
    pad_start: int = 0  # windows may begin up to this many rows before row 0
    pad_end: bool = False  # a last window may run past the final row (padded)

    def __post_init__(self) -> None:
        check_field_types(self, "world_model.window")
        require_whole_fields(self, "world_model.window", ("length", "stride"))
        if not 0 <= self.offset < self.stride:
            raise UserError(f"window.offset={self.offset}: expected 0 <= offset < stride ({self.stride})")
        if not 0 <= self.pad_start < self.length:
            raise UserError(f"window.pad_start={self.pad_start}: expected 0 <= pad_start < length ({self.length})")


def window_starts(n_rows: int, spec: WindowSpec, offset: int | None = None) -> np.ndarray:
    """Start rows (may be negative with pad_start) of the windows of one episode of n_rows rows."""
    off = spec.offset if offset is None else offset
    first = off - spec.pad_start
    last = n_rows - 1 if spec.pad_end else n_rows - spec.length  # the last start keeping >= 1 real row / no padding
    if last < first:
        return np.zeros(0, np.int64)
    return np.arange(first, last + 1, spec.stride, dtype=np.int64)


def build_index(n_rows: Sequence[int], spec: WindowSpec, episodes: np.ndarray | None = None,
                offset: int | None = None) -> np.ndarray:
    """(N, 2) int64 [episode, start] over the episodes whose mask is True (all when None)."""
    keep = np.ones(len(n_rows), bool) if episodes is None else np.asarray(episodes, bool)
    rows = []
    for e, n in enumerate(n_rows):
        if keep[e]:
            s = window_starts(int(n), spec, offset)
            rows.append(np.stack([np.full(len(s), e, np.int64), s], 1))
    return np.concatenate(rows) if rows else np.zeros((0, 2), np.int64)


def epoch_offset(spec: WindowSpec, seed: int, epoch: int) -> int:
    if not spec.random_offset:
        return spec.offset
    return int(np.random.default_rng([seed, epoch, 7]).integers(spec.stride))


def episode_ranks(tasks: Sequence[str], seeds: Sequence[int]) -> np.ndarray:
    """Each episode's rank within its task when the task's episodes are sorted by seed (0 = lowest seed)."""
    ranks = np.zeros(len(tasks), np.int64)
    by_task: dict[str, list[int]] = {}
    for i, t in enumerate(tasks):
        by_task.setdefault(t, []).append(i)
    for idx in by_task.values():
        for r, i in enumerate(sorted(idx, key=lambda i: seeds[i])):
            ranks[i] = r
    return ranks


def rank_mask(ranks: np.ndarray, lo: int, hi: int) -> np.ndarray:
    return (ranks >= lo) & (ranks < hi)


def require_ranks(tasks: Sequence[str], ranks: np.ndarray, hi: int, what: str,
                  how_to_get_more: Callable[[int], str] | None = None) -> None:
    """A UserError naming the task when a task has fewer than `hi` episodes (the protocol needs all of them);
    `how_to_get_more(hi)` says what to run (e.g. the collect command with the run's pipeline, group and store)."""
    for t in sorted(set(tasks)):
        n = int(sum(1 for x in tasks if x == t))
        if n < hi:
            how = how_to_get_more(hi) if how_to_get_more is not None else f"collect more: src/collect.py episodes={hi}"
            raise UserError(f"task '{t}' has {n} episodes; {what} needs {hi} per task ({how})")


@dataclass
class NormStats:
    state_mean: np.ndarray
    state_std: np.ndarray
    action_mean: np.ndarray
    action_std: np.ndarray

    @classmethod
    def fit(cls, states: Sequence[np.ndarray], actions: Sequence[np.ndarray]) -> NormStats:
        """From whole episodes: states (n_rows, D) each, actions (n_rows - 1, A) each (the real actions only)."""
        s, a = np.concatenate(states).astype(np.float64), np.concatenate(actions).astype(np.float64)
        fix = lambda sd: np.where(sd < 1e-6, 1.0, sd)  # noqa: E731
        return cls(s.mean(0).astype(np.float32), fix(s.std(0)).astype(np.float32),
                   a.mean(0).astype(np.float32), fix(a.std(0)).astype(np.float32))

    def to_dict(self) -> dict:
        return {k: getattr(self, k).tolist() for k in ("state_mean", "state_std", "action_mean", "action_std")}

    @classmethod
    def from_dict(cls, d: dict) -> NormStats:
        return cls(**{k: np.asarray(v, np.float32) for k, v in d.items()})


@dataclass
class EpisodeInfo:
    task: str
    seed: int
    group: str
    n_rows: int
    action_space: dict
    path: str | None = None
    extra: dict = field(default_factory=dict)


def check_one_action_space(infos: Sequence[EpisodeInfo]) -> dict:
    """The action space all episodes share (kind and number of dimensions); a UserError naming two that differ."""
    if not infos:
        raise UserError("no episodes to build a dataset from")
    first = infos[0]
    kind0, dims0 = first.action_space.get("kind"), len(first.action_space.get("dims") or [])
    for i in infos[1:]:
        kind, dims = i.action_space.get("kind"), len(i.action_space.get("dims") or [])
        if (kind, dims) != (kind0, dims0):
            raise UserError(f"episodes mix action spaces: '{kind0}' ({dims0} dims, {first.path or first.task}) and "
                            f"'{kind}' ({dims} dims, {i.path or i.task}); train one model per action space")
    return first.action_space


class ArraySource:
    """Episodes in memory: per episode image (n, H, W, 3) uint8, state (n, D), action (n, A) in the store's
    convention (row n - 1's action is padding)."""

    def __init__(self, infos: list[EpisodeInfo], arrays: list[dict[str, np.ndarray]]) -> None:
        if len(infos) != len(arrays):
            raise ValueError("one array dict per episode")
        self.infos, self.arrays = infos, arrays
        for info, a in zip(infos, arrays):
            refuse_unfit_arrays(info, {k: np.asarray(v) for k, v in a.items() if v is not None},
                                {k: a[k] for k in ("state", "action", "object_poses") if a.get(k) is not None})

    def frame_size(self, e: int) -> tuple[int, int]:
        """(H, W) of episode e's frames."""
        return tuple(self.arrays[e]["image"].shape[1:3])

    def read(self, e: int, lo: int, hi: int, robot_mask: bool = False) -> dict[str, np.ndarray]:
        a = self.arrays[e]
        out = {"image": a["image"][lo:hi], "state": a["state"][lo:hi], "action": a["action"][lo:hi]}
        if robot_mask and self.has_robot_masks():
            out["robot_mask"] = a["robot_mask"][lo:hi]
        return out

    def has_robot_masks(self) -> bool:
        return bool(self.arrays) and all("robot_mask" in a for a in self.arrays)

    def read_full(self, e: int, key: str) -> np.ndarray | None:
        """One array of episode e whole; "object_poses" is None where the episode has none."""
        return self.arrays[e].get(key) if key == "object_poses" else self.arrays[e][key]


def particle_rows(objects: dict) -> tuple[int, ...]:
    """The rows of obs/object_poses that are a pile's particles, from simeval's suites' `extra.objects` (in the
    order the rows were recorded: each object's bodies, each followed by its moving links, `links` of them in all;
    none where recorded before the links were)."""
    rows, start = [], 0
    for o in objects.values():
        n = int(o["bodies"]) + int(o.get("links") or 0)
        if o.get("shape") == "pile":
            rows.extend(range(start, start + n))
        start += n
    return tuple(rows)


def refuse_unfit_arrays(info: EpisodeInfo, per_row: Mapping[str, Any], numbers: Mapping[str, np.ndarray]) -> None:
    """An EpisodeFormatError naming the episode where an array of `per_row` ({name: anything with .shape}) has
    another number of rows than its info's n_rows, or one of `numbers` holds NaN or inf: either would otherwise
    surface as an IndexError deep in a reading, or as a training whose loss is NaN and a verdict that blames the
    model (a fresh-clone trial's episodes: `action` cut to 30 of 61 rows; obs/state NaN in rows 10-19)."""
    where = info.path or f"{info.task} seed {info.seed}"
    rows = {k: int(v.shape[0]) for k, v in per_row.items()}
    if any(n != info.n_rows for n in rows.values()):
        raise EpisodeFormatError(
            f"{where}: damaged episode: its arrays' rows differ ({', '.join(f'{k} {n}' for k, n in rows.items())}; "
            f"n_steps says {info.n_rows}); delete it and make it again (src/collect.py or src/import_data.py)")
    for k, a in numbers.items():
        bad = ~np.isfinite(np.asarray(a, float)).reshape(len(a), -1).all(1) if len(a) else np.zeros(0, bool)
        if bad.any():
            at = np.flatnonzero(bad)
            raise EpisodeFormatError(
                f"{where}: {k} holds NaN or inf in {len(at)} of its {len(a)} rows (first at row {at[0]}), which no "
                "reading can use: delete the episode and make it again, or fix what wrote it (the store's episodes "
                "are checked when it opens, whether this run reads them or not)")


class StoreSource:
    """Episodes in the HDF5 store, read lazily: each read opens (once per process) the episode file and slices
    the rows it needs, so a window costs L frames of decompression, not an episode."""

    def __init__(self, paths: Sequence[str | os.PathLike], camera: str | None) -> None:
        """`camera` None: no frame is read (the state reading alone), so episodes recorded without frames serve."""
        from simeval.episodes.store import read_meta

        self.camera = camera
        self.infos = []
        for p in paths:
            m = read_meta(p)
            if camera is not None and not m["cameras"]:
                raise UserError(f"{p}: recorded without frames (record.cameras=[]), and the pixel reading needs "
                                f"camera '{camera}': read the state alone (protocol.pixels=false) or collect with "
                                "cameras into another store")
            if camera is not None and camera not in m["cameras"]:
                raise UserError(f"{p}: no camera '{camera}' (has {m['cameras']}); set the camera key to one of them")
            objects = (m["extra"] or {}).get("objects") or {}
            bodies = (sum(int(o["bodies"]) for o in objects.values())  # simeval's suites: rows before the links'
                      if objects and all(isinstance(o, dict) and "bodies" in o for o in objects.values()) else None)
            self.infos.append(EpisodeInfo(task=m["task"], seed=int(m["seed"]), group=m["group"],
                                          n_rows=int(m["n_steps"]), action_space=m["action_space"], path=str(p),
                                          extra={"variation_id": m.get("variation_id", ""), "bodies": bodies,
                                                 "particles": particle_rows(objects) if bodies else ()}))
        self._files: dict[int, object] = {}
        self._frame_sizes: dict[int, tuple[int, int]] = {}
        self._with_mask: list[bool] = []
        self._pid = os.getpid()
        for e in range(len(self.infos)):  # before any training: a damaged index would otherwise surface mid-run
            self._check_structure(e)
        self._masks = bool(self._with_mask) and all(self._with_mask)
        self.close()

    def _check_structure(self, e: int) -> None:
        """Read the object headers and chunk indexes of what this source reads (metadata, not pixels): damage
        there, the usual result of a partly overwritten file, is named now instead of after a training. Damage
        inside compressed chunk data is found when it is read (see _damage_named)."""
        with self._damage_named(e):
            f = self._file(e)
            frames = () if self.camera is None else (f"obs/rgb/{self.camera}",)
            for key in (*frames, "obs/state", "action"):
                d = f[key]
                if d.chunks is not None:
                    d.id.get_num_chunks()
            per_row = [k for k in (*frames, "obs/state", "action", "obs/object_poses",
                                   *(() if self.camera is None else (f"obs/robot_mask/{self.camera}",))) if k in f]
            refuse_unfit_arrays(self.infos[e], {k: f[k] for k in per_row},
                                {k: f[k][()] for k in ("obs/state", "action", "obs/object_poses") if k in f})
            if self.camera is not None:
                self._frame_sizes[e] = tuple(f[f"obs/rgb/{self.camera}"].shape[1:3])
            self._with_mask.append(self.camera is not None and f"obs/robot_mask/{self.camera}" in f)

    def frame_size(self, e: int) -> tuple[int, int]:
        """(H, W) of episode e's frames of this source's camera (read from the file's header when it was opened)."""
        return self._frame_sizes[e]

    def _file(self, e: int):
        import h5py

        if self._pid != os.getpid():  # a forked DataLoader worker: never share the parent's HDF5 handles
            self._files, self._pid = {}, os.getpid()
        f = self._files.get(e)
        if f is None:
            f = self._files[e] = h5py.File(self.infos[e].path, "r")
        return f

    def read(self, e: int, lo: int, hi: int, robot_mask: bool = False) -> dict[str, np.ndarray]:
        with self._damage_named(e):
            f = self._file(e)
            out = {"image": f[f"obs/rgb/{self.camera}"][lo:hi], "state": f["obs/state"][lo:hi],
                   "action": f["action"][lo:hi]}
            if robot_mask and self._masks:
                out["robot_mask"] = f[f"obs/robot_mask/{self.camera}"][lo:hi].astype(bool)
            return out

    def has_robot_masks(self) -> bool:
        """Whether every episode has robot masks of this source's camera (recorded at collection; the windows
        carry them only then, so one model's evaluation never mixes masked and unmasked episodes)."""
        return self._masks

    def read_full(self, e: int, key: str) -> np.ndarray | None:
        """One array of episode e whole: image (this source's camera), state, action, or object_poses (None where
        the episode did not record them)."""
        with self._damage_named(e):
            f = self._file(e)
            if key == "object_poses":
                return f["obs/object_poses"][()] if "obs/object_poses" in f else None
            return f[{"state": "obs/state", "action": "action", "image": f"obs/rgb/{self.camera}"}[key]][()]

    @contextlib.contextmanager
    def _damage_named(self, e: int) -> Iterator[None]:
        """A file whose header reads (read_meta passed) but whose data does not: h5py's OSError names neither the
        file nor the remedy, and it may come after a whole training (an episode used only for evaluation)."""
        try:
            yield
        except (KeyError, OSError) as err:
            raise EpisodeFormatError(
                f"{self.infos[e].path}: damaged episode ({type(err).__name__}: {err}); delete it and re-run the "
                "src/collect.py (or src/import_data.py) command that made it, which makes missing episodes again; "
                "then this command again (a finished training is kept in its checkpoint)") from err

    def preload(self) -> ArraySource:
        """Everything in memory (images included): for small stores, reads become copies."""
        arrays = [{k: self.read_full(e, k) for k in ("image", "state", "action")} for e in range(len(self.infos))]
        self.close()
        return ArraySource(self.infos, arrays)

    def close(self) -> None:
        for f in self._files.values():
            f.close()
        self._files = {}

    def __getstate__(self) -> dict:  # h5py handles do not pickle (spawned workers): reopen there
        d = dict(self.__dict__)
        d["_files"] = {}
        return d


def store_paths_for(store_root: str | os.PathLike, pipeline: str, group: str, variation_id: str = "") -> list[Path]:
    """Paths of the complete episodes of a pipeline's group (`all` = every group) with one variation id ("" = the
    plain episodes). A UserError names the store and pipeline when none are there."""
    from simeval.episodes.store import EpisodeStore

    store = EpisodeStore(store_root)
    metas = [m for m in store.index(pipeline, group) if m.get("variation_id", "") == variation_id]
    if not metas:
        groups = sorted({m["group"] for m in store.index(pipeline)}) if store.root.is_dir() else []
        hint = (f"its groups there: {groups}" if groups else "none of this pipeline there" if store.root.is_dir()
                else "it is a file, not a folder" if store.root.exists() else "the folder does not exist")
        raise UserError(f"no episodes of pipeline '{pipeline}' group '{group}' in store {store.root} ({hint})")
    return [Path(m["path"]) for m in metas]


class WindowDataset:
    """A map-style dataset whose items are windows: `dataset[(episode, start)]` -> dict of numpy arrays (see the
    module docstring). `windows(epoch)` gives the (N, 2) index of an epoch; index items are plain tuples, so a
    DataLoader's batch_sampler can hand them straight to workers (the dataset itself holds no epoch state)."""

    def __init__(self, source, spec: WindowSpec, episodes: np.ndarray | None = None, stats: NormStats | None = None,
                 image_size: int | None = None, seed: int = 0, robot_masks: bool = False,
                 mask_margin: int = 0) -> None:
        self.source, self.spec, self.stats, self.seed = source, spec, stats, seed
        self.mask_margin = int(mask_margin)  # robot masks grown by this many pixels (at image_size), see grow_masks
        # windows carry `robot_mask` (L, H, W) only when asked and every episode has masks (the evaluation's
        # object-focused error; in training, WorldModel.step_errors leaves those pixels out of the loss)
        self.robot_masks = bool(robot_masks) and source.has_robot_masks()
        self.image_size = image_size
        self.episodes = np.ones(len(source.infos), bool) if episodes is None else np.asarray(episodes, bool)
        self.action_space = check_one_action_space([i for i, k in zip(source.infos, self.episodes) if k])
        self.n_rows = [i.n_rows for i in source.infos]

    def windows(self, epoch: int = 0) -> np.ndarray:
        return build_index(self.n_rows, self.spec, self.episodes, epoch_offset(self.spec, self.seed, epoch))

    def __len__(self) -> int:
        return len(self.windows(0))

    def fit_stats(self) -> NormStats:
        states, actions = [], []
        for e in np.flatnonzero(self.episodes):
            states.append(self.source.read_full(int(e), "state"))
            actions.append(self.source.read_full(int(e), "action")[:-1])  # the last row's action is padding
        return NormStats.fit(states, actions)

    def __getitem__(self, item) -> dict[str, np.ndarray]:
        e, s = int(item[0]), int(item[1])
        n, L = self.n_rows[e], self.spec.length
        lo, hi = max(s, 0), min(s + L, n)
        plo = max(lo - 1, 0)  # one more action row before: prev_action
        raw = self.source.read(e, plo, hi, robot_mask=self.robot_masks)
        k = lo - plo  # 1 when the row before lo was read
        image = raw["image"][k:]
        if self.image_size is not None and image.shape[1] != self.image_size:
            image = resize_frames(image, self.image_size)
        state = raw["state"][k:].astype(np.float32)
        action = raw["action"].astype(np.float32)
        if self.stats is not None:
            state = (state - self.stats.state_mean) / self.stats.state_std
            action = (action - self.stats.action_mean) / self.stats.action_std
        prev = np.concatenate([np.zeros_like(action[:1]), action[:-1]]) if k == 0 else action[:-1]
        if lo == 0:
            prev[0] = 0.0  # no action led to the reset observation
        act = action[k:]
        a, b = lo - s, lo - s + (hi - lo)  # where the real rows sit in the window
        robot = raw.get("robot_mask")
        out = {
            "image": np.zeros((L, *image.shape[1:]), np.uint8),
            "state": np.zeros((L, state.shape[1]), np.float32),
            "action": np.zeros((L, act.shape[1]), np.float32),
            "prev_action": np.zeros((L, act.shape[1]), np.float32),
            "is_first": np.zeros(L, bool),
            "mask": np.zeros(L, bool),
            "row": np.arange(s, s + L, dtype=np.int64),
            "episode": np.full(L, e, np.int64),
        }
        out["image"][a:b], out["state"][a:b], out["action"][a:b], out["prev_action"][a:b] = image, state, act, prev
        out["mask"][a:b] = True
        out["is_first"][a:b] = out["row"][a:b] == 0
        if robot is not None:
            robot = robot[k:]
            if self.image_size is not None and robot.shape[1] != self.image_size:
                robot = resize_masks(robot, self.image_size)
            robot = grow_masks(robot, self.mask_margin)
            out["robot_mask"] = np.zeros((L, *robot.shape[1:]), bool)
            out["robot_mask"][a:b] = robot
        return out


def resize_frames(frames: np.ndarray, size: int) -> np.ndarray:
    """(n, H, W, 3) uint8 -> (n, size, size, 3) uint8, antialiased bilinear (area-like when shrinking)."""
    import torch
    import torch.nn.functional as F

    x = torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2).float()
    y = F.interpolate(x, size=(size, size), mode="bilinear", antialias=True, align_corners=False)
    return y.round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1).numpy()


def resize_masks(masks: np.ndarray, size: int) -> np.ndarray:
    """(n, H, W) bool -> (n, size, size) bool: a pixel of the smaller mask is set when any part of the area it
    covers is set (area interpolation > 0), so shrinking never drops a robot pixel into the object-focused error."""
    import torch
    import torch.nn.functional as F

    x = torch.from_numpy(np.ascontiguousarray(masks, dtype=np.float32))[:, None]
    mode = "area" if size <= masks.shape[1] else "nearest"
    return (F.interpolate(x, size=(size, size), mode=mode)[:, 0] > 0).numpy()


def grow_masks(masks: np.ndarray, margin: int) -> np.ndarray:
    """(n, H, W) bool masks grown by `margin` pixels (a square neighbourhood: a pixel is set when any pixel within
    `margin` rows and columns is). Why: a world model's image of the robot is blurred, so its error spills a pixel
    or two past the robot's outline; a margin keeps that spill out of an object-focused error."""
    if margin <= 0 or not len(masks):
        return masks
    import torch
    import torch.nn.functional as F

    x = torch.from_numpy(np.ascontiguousarray(masks, dtype=np.float32))[:, None]
    return (F.max_pool2d(x, 2 * margin + 1, stride=1, padding=margin)[:, 0] > 0).numpy()
