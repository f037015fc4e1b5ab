"""Policies through the environment (simeval.sim.env): the oracle as a policy, the recording of an oracle episode
for the store, and rollouts of any policy over seeds for closed-loop evaluation. Collection and evaluation share
this one code path: `env.reset` / `env.step`.

A policy is a callable `policy(obs) -> action` (None: it gives up, the episode ends), optionally with
`policy.reset(env)`, called after every `env.reset` (the oracle reads the simulator there; a learned policy clears
its observation history)."""

from __future__ import annotations

import numbers
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simeval.episodes.episode import Episode
from simeval.errors import UserError, check_field_types
from simeval.sim.action_spaces import (
    EE_HIGH,
    EE_LOW,
    ee_delta_action_space,
    ee_pose_action_space,
    joint_action_space,
    pick_place_action_space,
)
from simeval.sim.core.articulated import moving_links
from simeval.sim.core.world import OBS_CAMERAS, SCENE_VIEWS
from simeval.sim.closed_loop import act_until_done
from simeval.sim.env import SimEnv, state_names
from simeval.sim.experts.pick_place import next_primitive
from simeval.sim.robots.xarm import STATE_NAMES
from simeval.sim.tasks.spec import TaskSpec, check_variation


@dataclass
class RecordSettings:
    cameras: tuple[str, ...] = ("top", "front")
    image_size: tuple[int, int] = (64, 64)
    scene_view_size: tuple[int, int] = (128, 128)
    control_hz: float = 30.0  # every control step is one stored transition; for a coarser rate lower this
    noise_std: float = 0.002  # ee_delta tasks: the controller's action noise (m per step per axis); oracle tasks ignore it
    robot_masks: bool = True  # record each camera's robot pixels beside its frames (obs/robot_mask/<camera>)

    def __post_init__(self) -> None:
        # configs give lists; the settings travel to worker processes and into keys, so keep them immutable.
        # Messages name the config keys (record.*), where these values come from on the command line.
        check_field_types(self, "record")
        self.cameras = (self.cameras,) if isinstance(self.cameras, str) else tuple(self.cameras or ())
        self.image_size = image_size_pair(self.image_size, "record.image_size")
        self.scene_view_size = image_size_pair(self.scene_view_size, "record.scene_view_size")
        unknown = [c for c in self.cameras if c not in OBS_CAMERAS]
        if unknown:
            raise UserError(f"record.cameras: unknown camera(s) {unknown}; known: {', '.join(OBS_CAMERAS)}")
        hz = self.control_hz
        if isinstance(hz, bool) or not isinstance(hz, numbers.Real) or not hz > 0:
            raise UserError(f"record.control_hz must be a number > 0, got {self.control_hz!r}")
        ns = self.noise_std
        if isinstance(ns, bool) or not isinstance(ns, numbers.Real) or not ns >= 0:
            raise UserError(f"record.noise_std must be a number of metres >= 0, got {self.noise_std!r}")


def image_size_pair(value, key: str) -> tuple[int, int]:
    """[H, W] with both >= 1, as a tuple; anything else is a UserError naming `key`."""
    ok = (isinstance(value, (list, tuple)) and len(value) == 2
          and all(isinstance(x, numbers.Integral) and not isinstance(x, bool) and x >= 1 for x in value))
    if not ok:
        raise UserError(f"{key} must be [H, W] with whole numbers H, W >= 1, got {value!r}")
    return int(value[0]), int(value[1])


class OraclePolicy:
    """The replanning oracle (simeval.sim.experts.pick_place) as a policy for action_space="pick_place": each call plans the
    next primitive from the simulator's state and returns its 14-d pose; None when every goal is done."""

    def reset(self, env: SimEnv) -> None:
        if env.mode != "pick_place":
            raise UserError(f"the oracle acts through action_space='pick_place', not {env.mode!r}; its control "
                            "steps are what make_env(..., record_low_level=True) returns")
        self.env = env

    def __call__(self, obs) -> np.ndarray | None:
        prim = next_primitive(self.env.world, self.env.inst)
        return None if prim is None else prim.pose14(self.env.world)


class Expert(ABC):
    """How one kind of suite task is solved and stored: the only part in which recording differs between them.
    `run_episode` drives any expert through the same loop; an expert says which action space the environment runs
    in and its settings there, which policy solves the task, how an action is stored, what the episode keeps
    beside the rows, and how the final view is taken."""

    name = "expert"  # in errors
    mode = "joint"
    action_space = staticmethod(joint_action_space)  # control_hz -> the stored actions' space

    def env_kwargs(self, settings: RecordSettings) -> dict:
        return {"control_hz": settings.control_hz}

    @abstractmethod
    def policy(self, settings: RecordSettings):
        """The policy that solves the task: reset(env), then policy(obs) -> action or None when done."""

    def to_env(self, action) -> np.ndarray:
        """The action handed to env.step."""
        return action

    def stored(self, env: SimEnv, action: np.ndarray) -> np.ndarray:
        """The action as the episode keeps it: as applied, so it replays bit for bit."""
        return action

    def state_names(self, spec: TaskSpec) -> tuple[str, ...]:
        return STATE_NAMES

    def extra(self, env: SimEnv, policy, settings: RecordSettings) -> dict:
        """Kept in the episode's `extra`, read before the final view moves anything."""
        return {}

    def final_view(self, env: SimEnv, size: tuple[int, int]) -> np.ndarray:
        return env.world.render(SCENE_VIEWS[0], size)


class PickPlaceOracle(Expert):
    """GenSim-style tasks: the replanning oracle's pick/place primitives, stored as the environment's low-level
    control steps (7-d joint actions at settings.control_hz) with the 14-d primitives and the row each starts at."""

    name, mode = "oracle", "pick_place"

    def env_kwargs(self, settings: RecordSettings) -> dict:
        return {"control_hz": settings.control_hz, "record_low_level": True}

    def policy(self, settings: RecordSettings):
        return OraclePolicy()


class ArticulationExpert(Expert):
    """RoboGen-style ee_delta tasks: the closed-loop articulation controller (simeval.sim.experts.articulation, action
    noise settings.noise_std), one 7-d action per control step, clipped and with a binary suction as applied.
    The final view is taken with the suction off and the arm parked, so it shows the articulation (those moves are
    not recorded)."""

    name, mode = "controller", "ee_delta"
    action_space = staticmethod(ee_delta_action_space)

    def policy(self, settings: RecordSettings):
        from simeval.sim.experts.articulation import ArticulationController

        return ArticulationController(settings.noise_std)

    def to_env(self, action) -> np.ndarray:
        action = np.clip(np.asarray(action, np.float32), EE_LOW, EE_HIGH).astype(np.float32)
        action[6] = np.float32(action[6] >= 0.5)
        return action

    def extra(self, env: SimEnv, policy, settings: RecordSettings) -> dict:
        final = {o.id: [float(x) for x in _joint_fractions(env, o)] for o in env.inst.objects
                 if o.id in env.inst.joints}
        return {"initial_state": env.spec_task.initial_state, "noise_std": settings.noise_std,
                "joint_fractions": {"initial": env.inst.joints, "final": final}}

    def final_view(self, env: SimEnv, size: tuple[int, int]) -> np.ndarray:
        env.arm.suction_off()
        env.arm.park()
        return env.world.render(SCENE_VIEWS[0], size)


class PlanExpert(Expert):
    """BBSEA-style ee_pose tasks: the task's plan (simeval.sim.experts.plan.PlanPolicy) at the task's own 4 Hz
    (`settings.control_hz` does not apply), one 8-d action per control step; the plan and the row where each
    primitive starts are kept in `extra`."""

    name, mode = "plan", "ee_pose"
    action_space = staticmethod(ee_pose_action_space)

    def env_kwargs(self, settings: RecordSettings) -> dict:
        return {}

    def policy(self, settings: RecordSettings):
        from simeval.sim.experts.plan import PlanPolicy

        return PlanPolicy()

    def stored(self, env: SimEnv, action: np.ndarray) -> np.ndarray:
        return np.asarray(env.arm.last_action, np.float32)

    def state_names(self, spec: TaskSpec) -> tuple[str, ...]:
        return state_names(spec.robot)

    def extra(self, env: SimEnv, policy, settings: RecordSettings) -> dict:
        return {"plan": [{p: n} for p, n in env.spec_task.plan], "plan_step": [int(x) for x in policy.plan_step]}


EXPERTS = {"ee_delta": ArticulationExpert(), "ee_pose": PlanExpert()}  # by the task's action space; else the oracle


def expert_for(spec: TaskSpec) -> Expert:
    return EXPERTS.get(spec.action_space, PickPlaceOracle())


def run_episode(spec: TaskSpec, seed: int, settings: RecordSettings | None = None, pipeline: str = "gensim",
                variation: dict | None = None, final_frame_size: tuple[int, int] | None = None) -> Episode:
    """One suite episode solved by the task's expert (expert_for), recorded for the store: the reset observation,
    then for each control step its action and the observation it produced (the convention of
    simeval.episodes.store; the last row's action repeated as padding). A pick/place step is many control steps:
    the environment returns them (record_low_level) and they are stored as such, with the 14-d primitives and the
    row where each starts. `variation` overrides the spec's knobs ({object name: {colors, count, ...}},
    {"robot": {"home_noise": radians}}: what a generalization test varies). A failed episode is returned like any
    other, with success False; `final_view` (if asked) is rendered after the episode."""
    settings = settings or RecordSettings()
    variation = check_variation([spec], variation)
    expert = expert_for(spec)
    env = SimEnv(spec, expert.mode, variation, settings.image_size, settings.cameras,
                 scene_view_size=settings.scene_view_size, robot_masks=settings.robot_masks,
                 **expert.env_kwargs(settings))
    try:
        obs, info = env.reset(seed=seed)
        trace = _Trace(views=info.pop("scene_views"), rows=[obs], progress=[info["progress"]],
                       poses=[env.object_poses()])
        policy = expert.policy(settings)
        policy.reset(env)
        while True:
            action = policy(obs)
            if action is None:
                break
            action = expert.to_env(action)
            obs, _, terminated, truncated, info = env.step(action)
            if info.get("low_level") is not None:  # a primitive: the control steps it took
                trace.add_primitive(action, info["low_level"])
            else:
                trace.add_step(expert.stored(env, action), obs, info["progress"], env.object_poses())
            if terminated or truncated:
                break
        trace.success = info["success"]
        trace.extra = expert.extra(env, policy, settings)
        trace.final_view = expert.final_view(env, final_frame_size) if final_frame_size else None
        trace.inst, trace.control_hz = env.inst, env.control_hz
        trace.links = {o.id: sum(len(moving_links(env.world.c, b)) for b in o.body_ids) for o in env.inst.objects}
    finally:
        env.close()
    if not trace.actions:  # an episode with no step cannot be stored; a spec that starts solved is a spec error
        raise RuntimeError(f"{spec.name} seed {seed}: the {expert.name} made no move; is the task solved at start?")
    return trace.episode(spec, seed, pipeline, settings.cameras, variation,
                         action_space=expert.action_space(trace.control_hz), state_names=expert.state_names(spec))


@dataclass
class _Trace:
    """What an expert's episode leaves while its environment is open: the reset observation then one row per
    control step, with its action, task progress and object poses, and the primitives (pick/place) that made them."""
    views: Any
    rows: list
    progress: list
    poses: list
    actions: list = field(default_factory=list)
    high_level: list = field(default_factory=list)
    high_level_steps: list = field(default_factory=list)
    success: bool = False
    extra: dict = field(default_factory=dict)
    final_view: Any = None
    inst: Any = None
    control_hz: float = 0.0
    links: dict = field(default_factory=dict)  # object id -> its links on moving joints (rows after its bodies')

    def add_primitive(self, action: np.ndarray, low: dict) -> None:
        self.high_level_steps.append(len(self.actions))
        self.high_level.append(action)
        self.actions += low["action"]
        self.rows += low["obs"]
        self.progress += low["progress"]
        self.poses += low["object_poses"]

    def add_step(self, action: np.ndarray, obs: dict, progress: float, poses: np.ndarray) -> None:
        self.actions.append(action)
        self.rows.append(obs)
        self.progress.append(progress)
        self.poses.append(poses)

    def episode(self, spec: TaskSpec, seed: int, pipeline: str, cameras, variation: dict, *, action_space: dict,
                state_names) -> Episode:
        """The stored episode: the rows (T + 1), the last row's action repeated as padding (format 2,
        simeval.episodes.store), and the high-level primitives where the expert used them."""
        rows, actions, t = self.rows, self.actions, len(self.actions)
        prog = np.asarray(self.progress, np.float32)
        high = ({"high_level_action": np.stack(self.high_level),
                 "high_level_step": np.asarray(self.high_level_steps, np.int64),
                 "high_level_space": pick_place_action_space(self.control_hz)} if self.high_level else {})
        return Episode(
            pipeline=pipeline, task=spec.name, description=self.inst.description, group=spec.group, seed=seed,
            rgb={c: np.stack([o["rgb"][c] for o in rows]) for c in cameras},
            state=np.stack([o["state"] for o in rows]), action=np.stack([*actions, actions[-1]]),  # last: padding
            reward=np.r_[np.diff(prog), 0.0].astype(np.float32), progress=prog,
            is_first=np.arange(t + 1) == 0, is_terminal=np.arange(t + 1) == t, success=bool(self.success),
            scene_views=self.views, control_hz=self.control_hz, source="simeval-suite", final_view=self.final_view,
            action_space=action_space, state_names=list(state_names), variation=variation,
            object_poses=np.stack(self.poses).astype(np.float32), robot_mask=robot_masks(rows, cameras),
            extra={"objects": {o.id: {"shape": o.shape, "color": o.color, "bodies": len(o.body_ids),
                                      "links": self.links.get(o.id)} for o in self.inst.objects}, **self.extra}, **high)


def robot_masks(rows: list[dict], cameras) -> dict[str, np.ndarray] | None:
    """camera -> (T + 1, H, W) bool from observations made with robot_masks (None when they carry none)."""
    if not rows or "robot_mask" not in rows[0]:
        return None
    return {c: np.stack([o["robot_mask"][c] for o in rows]) for c in cameras}


def _joint_fractions(env: SimEnv, obj) -> list[float]:
    from simeval.sim.core.articulated import joint_fraction

    return [joint_fraction(env.world.c, obj.body_ids[0], k) for k in range(len(env.inst.joints[obj.id]))]


# --- closed-loop evaluation ----------------------------------------------------------------------------------
def _one_rollout(policy, task, seed: int, env_kwargs: dict, video_camera: str | None) -> dict:
    video_low = video_camera is not None and env_kwargs.get("action_space") == "pick_place"
    env = SimEnv(task, **env_kwargs, record_low_level=video_low)
    frames = []

    def record(obs: dict, info: dict) -> None:
        frames.extend([o["rgb"][video_camera] for o in info["low_level"]["obs"]] if video_low else
                      [obs["rgb"][video_camera]])

    try:
        obs, info = env.reset(seed=seed)
        if hasattr(policy, "reset"):
            policy.reset(env)
        if video_camera is not None:
            frames.append(obs["rgb"][video_camera])
        done = act_until_done(env, policy, obs, record if video_camera is not None else None)
        if not done["steps"]:  # gave up at once: the reset's success and progress stand
            done.update(success=bool(info["success"]), progress=float(info["progress"]))
    finally:
        env.close()
    return {"seed": int(seed), "success": done["success"], "progress": done["progress"], "steps": done["steps"],
            "gave_up": done["gave_up"], "video": np.stack(frames) if frames else None}


def rollout_policy(policy: Callable, task: str | TaskSpec, seeds: Sequence[int], *, action_space: str | None = None,
                   variation: dict | None = None, image_size: Sequence[int] = (64, 64),
                   cameras: Sequence[str] = ("top", "front"), max_steps: int | None = None,
                   control_hz: float | None = None,
                   video_camera: str | None = None, workers: int = 1) -> dict:
    """Roll `policy` out once per seed through make_env(task, action_space, ...) (None: the task's own space). Returns {"success": rate,
    "progress": mean final progress, "episodes": [{seed, success, progress, steps, gave_up, video}]}; `video` is
    (N, H, W, 3) uint8 frames of `video_camera` (every control step, also for pick_place) or None.
    workers > 1 runs seeds in separate processes (spawned: the policy must pickle; each process has its own
    PyBullet client and its own copy of the policy)."""
    cameras = tuple(cameras)
    if video_camera is not None and video_camera not in cameras:
        raise UserError(f"video_camera={video_camera!r} is not among cameras {list(cameras)}")
    if not len(seeds):
        raise UserError("rollout_policy: no seeds given")
    env_kwargs = {"action_space": action_space, "variation": variation, "image_size": tuple(image_size),
                  "cameras": cameras, "max_steps": max_steps, "control_hz": control_hz}
    if workers <= 1:
        episodes = [_one_rollout(policy, task, s, env_kwargs, video_camera) for s in seeds]
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool:
            episodes = list(pool.map(_one_rollout, [policy] * len(seeds), [task] * len(seeds), seeds,
                                     [env_kwargs] * len(seeds), [video_camera] * len(seeds)))
    return {"success": float(np.mean([e["success"] for e in episodes])),
            "progress": float(np.mean([e["progress"] for e in episodes])), "episodes": episodes}
