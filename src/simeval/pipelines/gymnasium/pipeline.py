"""Any Gymnasium environment as a closed-loop pipeline, from its `conf/pipeline/<name>.yaml` alone (`kind:
gymnasium`): collection with a scripted expert, src/diversity.py on its episodes, src/generalization.py's rollouts.

    name: reach                     # the store's pipeline name
    kind: gymnasium
    env:
      id: my_sim:PointReach-v0      # gymnasium.make's id ("module:Id" imports the module, which registers it)
      # factory: my_sim.make_env    # or a function of the kwargs returning a gymnasium.Env (instead of id)
      kwargs: {size: 64}            # for every task
    tasks:                          # name -> group, description, kwargs (over env.kwargs)
      reach-left: {group: reach, description: reach the left target, kwargs: {target: [-0.5, 0.0]}}
    heldout: {reach: [reach-up]}    # group -> tasks src/generalization.py keeps out of training
    eval_variation: {gain: 0.5}     # env kwargs over a task's for the `eval` split ({}: no eval split)
    adapter:
      cameras: {front: render}      # a camera: "render" (env.render(), render_mode rgb_array) or an observation key
      state: null                   # observation keys concatenated (null: every numeric entry but the cameras')
      success: info.is_success      # info.<key>, or "terminated" (the env ends an episode on success); null: unknown
      progress: null                # info.<key> in [0, 1], or null (unknown)
    expert: {_target_: my_sim.expert}   # collection's policy: expert(env, obs, info, rng) -> action; or "random"
    native: {max_steps: 100, control_hz: 20}
    default_group: reach
The policy (src/generalization.py) acts in the action space the episodes were recorded in (`native` resolves to
"recorded": the env's own actions, one per step). Every task's action kind is "gymnasium:<id or factory>".
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import SimpleNamespace

import gymnasium as gym
import numpy as np

from simeval.episodes.episode import Episode
from simeval.errors import UserError, require_whole
from simeval.pipelines.base import Pipeline, load_target, select_tasks, split_by_heldout
from simeval.pipelines.import_parts import resize_frames

ACTION_SPACE = "recorded"  # the policy's action space: the episodes' own (simeval.measures.generalization.data)
KEYS = {"name", "kind", "source", "root", "tasks_path", "text_template", "grouped_file", "group_aliases", "suite",
        "default_group", "env", "tasks", "heldout", "eval_variation", "adapter", "expert", "native", "_target_"}


@dataclass(frozen=True)
class Adapter:
    """How an environment's observations and infos become simeval's (see the module docstring)."""

    cameras: dict = field(default_factory=lambda: {"front": "render"})
    state: list | None = None
    success: str | None = "terminated"
    progress: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.cameras, Mapping) or not self.cameras:
            raise UserError("pipeline.adapter.cameras: give at least one camera, e.g. {front: render}")
        for key in ("success", "progress"):
            v = getattr(self, key)
            if v is not None and not (v == "terminated" and key == "success" or str(v).startswith("info.")):
                raise UserError(f"pipeline.adapter.{key}={v!r}: expected info.<key>"
                                + (", terminated" if key == "success" else "") + " or null")

    def rgb(self, env, obs, size: Sequence[int], cameras: Sequence[str]) -> dict:
        out = {}
        for cam in cameras:
            where = self.cameras[cam]
            if where == "render":
                frame = env.render()
            elif isinstance(obs, Mapping) and where in obs:
                frame = obs[where]
            else:
                have = sorted(obs) if isinstance(obs, Mapping) else type(obs).__name__
                raise UserError(f"pipeline.adapter.cameras.{cam}={where!r}: the observation has no such key "
                                f"(has {have}); give an observation key or render")
            frame = np.asarray(frame)
            if frame.ndim != 3 or frame.shape[-1] != 3:
                raise UserError(f"pipeline.adapter.cameras.{cam}={where!r}: gives {frame.dtype} {frame.shape}, not "
                                "an (H, W, 3) image")
            if frame.dtype != np.uint8:
                frame = np.clip(frame * (255.0 if frame.max() <= 1.0 else 1.0), 0, 255).round().astype(np.uint8)
            out[cam] = resize_frames(frame[None], tuple(size))[0]
        return out

    def state_of(self, obs) -> np.ndarray:
        if not isinstance(obs, Mapping):
            return np.asarray(obs, np.float32).ravel()
        images = {w for w in self.cameras.values() if w != "render"}
        keys = self.state if self.state is not None else sorted(
            k for k, v in obs.items() if k not in images and np.issubdtype(np.asarray(v).dtype, np.number))
        missing = [k for k in keys if k not in obs]
        if missing:
            raise UserError(f"pipeline.adapter.state: the observation has no key {missing} (has {sorted(obs)})")
        return np.concatenate([np.asarray(obs[k], np.float32).ravel() for k in keys]) if keys else \
            np.zeros(0, np.float32)

    def read(self, which: str, info: Mapping, terminated: bool):
        spec = getattr(self, which)
        if spec is None:
            return None
        if spec == "terminated":
            return bool(terminated)
        key = spec[len("info."):]
        if key not in info:
            raise UserError(f"pipeline.adapter.{which}={spec}: the env's info has no {key!r} (has {sorted(info)})")
        return info[key]


@dataclass(frozen=True)
class GymSettings:
    env_id: str | None
    factory: str | None
    kwargs: dict
    tasks: dict  # name -> {group, description, kwargs}
    adapter: Adapter
    expert: object  # "random" or {_target_: ...}
    max_steps: int = 200
    control_hz: float | None = None

    @property
    def kind(self) -> str:
        return f"gymnasium:{self.env_id or self.factory}"

    @classmethod
    def from_config(cls, pipeline: Mapping) -> GymSettings:
        unknown = sorted(set(pipeline) - KEYS)
        if unknown:
            raise UserError(f"pipeline={pipeline.get('name')}: unknown key(s) {unknown} for kind gymnasium "
                            f"(simeval.pipelines.gymnasium.pipeline's docstring lists its keys)")
        env = dict(pipeline.get("env") or {})
        stray = sorted(set(env) - {"id", "factory", "kwargs"})
        if stray or bool(env.get("id")) == bool(env.get("factory")):
            raise UserError("pipeline.env: give id (gymnasium.make's, e.g. my_sim:Reach-v0) or factory (a function "
                            "path, e.g. my_sim.make_env), one of them" + (f"; unknown {stray}" if stray else ""))
        tasks = {}
        for name, t in dict(pipeline.get("tasks") or {}).items():
            t = dict(t or {})
            bad = sorted(set(t) - {"group", "description", "kwargs"})
            if bad or not t.get("group"):
                raise UserError(f"pipeline.tasks.{name}: needs group (and may have description, kwargs)"
                                + (f"; unknown {bad}" if bad else ""))
            tasks[str(name)] = {"group": str(t["group"]), "description": str(t.get("description") or
                                                                           str(name).replace("-", " ")),
                                "kwargs": dict(t.get("kwargs") or {})}
        if not tasks:
            raise UserError(f"pipeline.tasks: pipeline={pipeline.get('name')} lists no task")
        try:
            adapter = Adapter(**dict(pipeline.get("adapter") or {}))
        except TypeError as e:
            raise UserError(f"pipeline.adapter: {e} (keys: cameras, state, success, progress)") from None
        native = dict(pipeline.get("native") or {})
        bad = sorted(set(native) - {"max_steps", "control_hz"})
        if bad:
            raise UserError(f"pipeline.native: unknown key(s) {bad}; expected max_steps, control_hz")
        require_whole("pipeline.native.max_steps", native.get("max_steps", 200))
        expert = pipeline.get("expert") or "random"
        if expert != "random" and not (isinstance(expert, Mapping) and expert.get("_target_")):
            raise UserError(f"pipeline.expert={expert!r}: expected random or {{_target_: module.function}}")
        return cls(env.get("id"), env.get("factory"), dict(env.get("kwargs") or {}), tasks, adapter,
                   expert if expert == "random" else dict(expert), int(native.get("max_steps", 200)),
                   native.get("control_hz"))

    def make(self, task: str, variation: Mapping | None = None) -> gym.Env:
        kwargs = {**self.kwargs, **self.tasks[task]["kwargs"], **dict(variation or {})}
        if "render" in self.adapter.cameras.values():
            kwargs.setdefault("render_mode", "rgb_array")
        try:
            if self.env_id:
                return gym.make(self.env_id, disable_env_checker=True, **kwargs).unwrapped
            return load_target(self.factory, "pipeline.env.factory")(**kwargs)
        except gym.error.Error as e:
            raise UserError(f"pipeline.env.id={self.env_id}: {e}") from None
        except (ImportError, AttributeError, ValueError) as e:
            what = f"pipeline.env.id={self.env_id}" if self.env_id else f"pipeline.env.factory={self.factory}"
            raise UserError(f"{what}: cannot be made ({type(e).__name__}: {e})") from None
        except TypeError as e:
            where = ", ".join(["pipeline.env.kwargs", f"pipeline.tasks.{task}.kwargs",
                               *(["the split's variation (pipeline.eval_variation)"] if variation else [])])
            raise UserError(f"task {task}: the env refuses its kwargs ({e}); they come from {where}") from None

    def expert_fn(self) -> Callable:
        if self.expert == "random":
            return lambda env, obs, info, rng: rng.uniform(env.action_space.low, env.action_space.high)
        return load_target(self.expert["_target_"], "pipeline.expert._target_")


def action_space_of(env: gym.Env, settings: GymSettings) -> dict:
    space = env.action_space
    if not isinstance(space, gym.spaces.Box):
        raise UserError(f"{settings.kind}: its action space is {type(space).__name__}; simeval's policies act in a "
                        "Box (continuous) space")
    n = int(np.prod(space.shape))
    return {"kind": settings.kind, "dims": [f"a{i}" for i in range(n)], "units": None,
            "control_hz": settings.control_hz, "low": np.asarray(space.low, float).ravel().tolist(),
            "high": np.asarray(space.high, float).ravel().tolist()}


class AdaptedEnv(gym.Env):
    """A pipeline's environment observed as simeval's: obs {"rgb": {camera: (H, W, 3) uint8}, "state": (S,)}, info
    {"success", "progress"} (False / None where the adapter reads none); truncated after `max_steps` actions."""

    metadata = {"render_modes": []}  # noqa: RUF012 (gymnasium's convention)

    def __init__(self, settings: GymSettings, task: str, variation: Mapping | None, image_size: Sequence[int],
                 cameras: Sequence[str], max_steps: int | None = None) -> None:
        unknown = [c for c in cameras if c not in settings.adapter.cameras]
        if unknown:
            raise UserError(f"policy.model.cameras: the pipeline's adapter has cameras "
                            f"{list(settings.adapter.cameras)}, not {unknown}")
        self.settings, self.task, self.cameras = settings, task, list(cameras)
        self.size, self.max_steps = tuple(int(x) for x in image_size), int(max_steps or settings.max_steps)
        self.env = settings.make(task, variation)
        self.action_space = self.env.action_space

    def _observe(self, obs) -> dict:
        return {"rgb": self.settings.adapter.rgb(self.env, obs, self.size, self.cameras),
                "state": self.settings.adapter.state_of(obs)}

    def _info(self, info: Mapping, terminated: bool) -> dict:
        success = self.settings.adapter.read("success", info, terminated)
        progress = self.settings.adapter.read("progress", info, terminated)
        return {"success": bool(success), "progress": float(progress) if progress is not None else None}

    def reset(self, *, seed: int | None = None, options=None):
        obs, info = self.env.reset(seed=seed)
        self._steps = 0
        return self._observe(obs), self._info(info, False)

    def step(self, action):
        space = self.env.action_space
        action = np.clip(np.asarray(action, np.float32).reshape(space.shape), space.low, space.high)
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._steps += 1
        truncated = bool(truncated) or (self._steps >= self.max_steps and not terminated)
        return self._observe(obs), float(reward), bool(terminated), truncated, self._info(info, terminated)

    def close(self) -> None:
        self.env.close()


def record_episode(settings: GymSettings, task: str, seed: int, cameras: Sequence[str], image_size: Sequence[int],
                   pipeline: str, variation: Mapping | None = None, control_hz: float | None = None) -> Episode:
    """One expert episode of `task` from `env.reset(seed=seed)`, recorded in the store's rows (T + 1 observations,
    the last action padding)."""
    env = AdaptedEnv(settings, task, variation, image_size, cameras)
    expert = settings.expert_fn()
    rng = np.random.default_rng([int(seed), 31])
    try:
        raw, info = env.env.reset(seed=int(seed))
        frames = [env._observe(raw)]
        actions, rewards, progress = [], [], [settings.adapter.read("progress", info, False)]
        terminated = truncated = False
        while not (terminated or truncated) and len(actions) < settings.max_steps:
            action = np.asarray(expert(env.env, raw, info, rng), np.float32).reshape(env.action_space.shape)
            action = np.clip(action, env.action_space.low, env.action_space.high)
            raw, reward, terminated, truncated, info = env.env.step(action)
            frames.append(env._observe(raw))
            actions.append(action.ravel())
            rewards.append(float(reward))
            progress.append(settings.adapter.read("progress", info, terminated))
        success = settings.adapter.read("success", info, terminated)
        space = action_space_of(env.env, settings)
    finally:
        env.close()
    n = len(actions)
    if n == 0:
        raise UserError(f"{task} seed {seed}: the env ended at reset; nothing to record")
    known = None not in progress
    return Episode(
        pipeline=pipeline, task=task, description=settings.tasks[task]["description"],
        group=settings.tasks[task]["group"], seed=int(seed),
        rgb={c: np.stack([f["rgb"][c] for f in frames]) for c in cameras},
        state=np.stack([f["state"] for f in frames]),
        action=np.stack([*actions, actions[-1]]), reward=np.asarray([*rewards, 0.0], np.float32),
        is_first=np.arange(n + 1) == 0, is_terminal=np.arange(n + 1) == n,
        progress=np.asarray(progress, np.float32) if known else None, success=bool(success),
        success_known=success is not None, scene_views=np.stack([frames[0]["rgb"][c] for c in cameras]),
        control_hz=control_hz or settings.control_hz, source=settings.kind,
        action_space={**space, "control_hz": control_hz or settings.control_hz},
        variation=dict(variation or {}), extra={"env": settings.env_id or settings.factory})


def collect_one(task: str, seed: int, store_root: str, pipeline_config: dict, record: dict, variation: dict) -> dict:
    """A worker of simeval.collect.run_episodes: record and store one episode."""
    from simeval.collect import announce_episode
    from simeval.episodes.store import EpisodeStore

    announce_episode(task, seed)
    t0 = time.perf_counter()
    settings = GymSettings.from_config(pipeline_config)
    ep = record_episode(settings, task, seed, record["cameras"], record["image_size"], pipeline_config["name"],
                        variation, control_hz=record["control_hz"])
    path = EpisodeStore(store_root).write(ep)
    return {"task": task, "seed": seed, "success": ep.success, "steps": ep.n_steps,
            "seconds": time.perf_counter() - t0, "bytes": os.path.getsize(path)}


class GymnasiumPipeline(Pipeline):
    """A Gymnasium environment's tasks, from the pipeline config (the module docstring)."""

    def __init__(self, name: str, settings: GymSettings, heldout: Mapping[str, list[str]] | None = None,
                 eval_variation: Mapping | None = None) -> None:
        self.name, self.settings = name, settings
        self.heldout, self.eval_variation = dict(heldout or {}), dict(eval_variation or {})

    @classmethod
    def from_config(cls, pipeline: Mapping) -> GymnasiumPipeline:
        settings = GymSettings.from_config(pipeline)
        heldout = {str(g): list(v) for g, v in dict(pipeline.get("heldout") or {}).items()}
        for group, names in heldout.items():
            stray = sorted(set(names) - {t for t, s in settings.tasks.items() if s["group"] == group})
            if stray:
                raise UserError(f"pipeline.heldout.{group}: {stray} not among the group's tasks")
        return cls(pipeline["name"], settings, heldout, pipeline.get("eval_variation"))

    def cameras(self):
        return list(self.settings.adapter.cameras)

    def check_environment(self, pairs):
        """Each distinct variation's environment of the first task made and reset (a missing module, a kwarg the
        env refuses, an adapter key the observation lacks), before a policy trains."""
        seen = set()
        for task, variation in pairs:
            key = json.dumps(dict(variation or {}), sort_keys=True, default=str)
            if key in seen:
                continue
            seen.add(key)
            env = AdaptedEnv(self.settings, task, variation, (16, 16), list(self.settings.adapter.cameras))
            try:
                env.reset(seed=0)
            finally:
                env.close()

    def unseen_knobs(self, variation):
        """Every eval kwarg: simeval cannot tell which of an environment's kwargs a first observation shows, so the
        eval split rolls out every seed (none is left out as unvaried)."""
        return sorted(dict(variation or {}))

    def environment_id(self):
        return {"name": self.name, "env": self.settings.kind, "kwargs": self.settings.kwargs,
                "tasks": self.settings.tasks}

    def groups(self) -> dict[str, dict[str, str]]:
        out: dict[str, dict[str, str]] = {}
        for name, t in self.settings.tasks.items():
            out.setdefault(t["group"], {})[name] = t["group"]
        return out

    def group_and_heldout(self, task_group, tasks=None, heldout=None):
        groups = self.groups()
        if task_group == "all":
            chosen = {n: t["group"] for n, t in self.settings.tasks.items()}
        elif task_group in groups:
            chosen = groups[task_group]
        else:
            raise UserError(f"task_group={task_group}: pipeline {self.name}'s groups are {', '.join(groups)} (or all)")
        return select_tasks(chosen, task_group, tasks, self.heldout, heldout, ACTION_SPACE, f"{self.name}'s")

    def split_tasks(self, specs, split, heldout, *, eval_override=None):
        variation = dict(self.eval_variation if eval_override is None else eval_override)
        return split_by_heldout(specs, split, heldout, variation)

    def make_env(self, task, action_space, variation, image_size, cameras, max_steps):
        if action_space != ACTION_SPACE:
            raise UserError(f"policy.model.action_space={action_space}: pipeline {self.name}'s environment takes "
                            f"its own actions (policy.model.action_space=native or {ACTION_SPACE})")
        return AdaptedEnv(self.settings, task, variation, image_size, cameras, max_steps)

    @classmethod
    def collect(cls, pipeline, *, tasks, task_group, seeds, store, record, variation, workers):
        from tqdm import tqdm

        from simeval.collect import missing_episodes, run_episodes, stored_summary, worker_count
        from simeval.episodes.store import EpisodeStore
        self = cls.from_config(pipeline)
        specs, held = self.group_and_heldout(task_group, tasks, heldout=[])
        split = variation["split"]
        knobs = dict(variation["knobs"] or {})
        if split == "eval":
            knobs = knobs or dict(self.eval_variation)
        unknown = [c for c in record["cameras"] if c not in self.settings.adapter.cameras]
        if unknown:
            raise UserError(f"record.cameras={list(record['cameras'])}: pipeline {self.name}'s adapter has "
                            f"{list(self.settings.adapter.cameras)}")
        # what a stored episode must have been recorded with to count as done (check_recorded_like); the adapter's
        # camera names, not the suites' (RecordSettings knows only theirs); the scene views are the first frames
        size = tuple(int(x) for x in record["image_size"])
        hz = float(self.settings.control_hz or record["control_hz"])
        recording = SimpleNamespace(cameras=tuple(record["cameras"]), image_size=size, scene_view_size=size,
                                    control_hz=hz)
        epstore = EpisodeStore(store)
        names = [s.name for s in specs]
        todo = missing_episodes(epstore, self.name, dict.fromkeys(names, knobs or None), seeds, recording,
                                dict.fromkeys(names, self.settings.kind))
        workers = worker_count(workers)
        new: list[dict] = []
        args = (str(epstore.root), dict(pipeline), {"cameras": list(record["cameras"]), "image_size": list(size),
                                                    "control_hz": hz}, knobs)
        bar = tqdm(total=len(todo), desc=f"{self.name} episodes", unit="episode", disable=not todo)
        try:
            run_episodes(collect_one, todo, args, workers, new, bar)
        finally:
            bar.close()
        return {"new": sorted(new, key=lambda r: (r["task"], r["seed"])),
                "skipped": len(names) * len(seeds) - len(todo),
                "tasks": stored_summary(epstore, self.name, {s.name: s.group for s in specs}, seeds,
                                        dict.fromkeys(names, knobs or None))}
