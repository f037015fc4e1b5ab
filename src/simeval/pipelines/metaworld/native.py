"""Meta-World's own tasks, experts and MuJoCo renders, recorded as simeval episodes.

    record_episode(task, seed, settings, cameras, image_size, scene_view_size) -> Episode
        Meta-World's scripted expert (metaworld.policies) on its goal-observable task `task`, variant `seed`
        (Meta-World's own seeding: the object and goal positions it draws for that seed), one stored transition per
        env step (Meta-World's 80 Hz: frame_skip 5 x 2.5 ms), until Meta-World reports success or
        settings.max_steps actions. T actions, T + 1 rows (the store's convention, simeval.episodes.store):
        rgb/<camera>        (T+1, H, W, 3) uint8  MuJoCo's offscreen render of simeval camera <camera> (CAMERAS)
        robot_mask/<camera> (T+1, H, W) bool      the Sawyer's pixels (every geom under its `base` body: pedestal,
                                                  arm, gripper), from a segmentation render of the same state
        state               (T+1, 39)             Meta-World's observation (STATE_NAMES)
        action              (T+1, 4)              the expert's action clipped to Meta-World's [-1, 1] (ACTION_KIND);
                                                  row T repeats row T-1 (padding: nothing was taken there)
        progress            (T+1,)                Meta-World's shaped reward / 10 (its v3 rewards lie in [0, 10])
                                                  of the row's state; reward[t] = progress[t+1] - progress[t]

Rendering: MUJOCO_GL defaults to egl (Mesa's EGL renders offscreen on a CPU). `render_quality: fast` turns off
multisampling, shadows and reflections: one 64x64 colour render 18x cheaper on this CPU's software GL (0.168 ->
0.0095 s), a recorded row 5.8-7.3x (outputs/bench/metaworld.json); the same scene with flatter light; `full` renders as Meta-World's own models say.
"""

from __future__ import annotations

import logging
import os
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from simeval.episodes.episode import Episode
from simeval.errors import UserError

# ML10 (Meta-World's meta-learning benchmark): 10 training tasks and 5 test tasks, metaworld.env_dict.ML10_V3
ML10_TRAIN = ("reach-v3", "push-v3", "pick-place-v3", "door-open-v3", "drawer-close-v3", "button-press-topdown-v3",
              "peg-insert-side-v3", "window-open-v3", "sweep-v3", "basketball-v3")
ML10_TEST = ("drawer-open-v3", "door-close-v3", "shelf-place-v3", "sweep-into-v3", "lever-pull-v3")
GROUPS = {"ml10": ML10_TRAIN + ML10_TEST}
# simeval's camera names -> Meta-World's; its offscreen images come out upside down (flipped upright on render)
CAMERAS = {"top": "topview", "front": "corner"}
SCENE_VIEWS = ("corner", "corner2", "corner4", "topview")  # the 4 views of the initial scene for the judges
CONTROL_HZ = 80.0  # Meta-World's step: frame_skip 5 x timestep 2.5 ms
ACTION_KIND = "metaworld_xyz_delta+gripper"
ACTION_SPACE = {"kind": ACTION_KIND, "dims": ["dx", "dy", "dz", "gripper"], "units": ["1/100 m"] * 3 + ["effort"],
                "control_hz": CONTROL_HZ, "low": [-1.0] * 4, "high": [1.0] * 4,
                "convention": "xyz: the hand's mocap target moves by action x 1/100 m in the world frame (Meta-World's "
                              "action_scale); gripper: the fingers' effort (1 closes, -1 opens)"}
_POSE = ("x", "y", "z", "qx", "qy", "qz", "qw")
_FRAME = ("hand_x", "hand_y", "hand_z", "gripper_open",
          *(f"obj1_{k}" for k in _POSE), *(f"obj2_{k}" for k in _POSE))
STATE_NAMES = (*_FRAME, *(f"prev_{k}" for k in _FRAME), "goal_x", "goal_y", "goal_z")
MAX_STEPS = 200  # ML10's experts: 727 of 750 seeds succeed within it (Meta-World's own limit: 500)
ROBOT_ROOT_BODY = "base"


@dataclass(frozen=True)
class MetaworldSettings:
    max_steps: int = MAX_STEPS  # actions per episode at most; an expert that has not succeeded by then fails
    render_quality: str = "fast"  # fast | full (see the module docstring)
    hand_init_noise: float = 0.0  # m: the hand starts this far (uniform per axis) from Meta-World's start pose

    def __post_init__(self) -> None:
        steps = self.max_steps
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise UserError(f"pipeline.native.max_steps must be a whole number >= 1, got {steps!r}")
        if self.render_quality not in ("fast", "full"):
            raise UserError(f"pipeline.native.render_quality={self.render_quality!r}: expected fast or full")
        noise = self.hand_init_noise
        if isinstance(noise, bool) or not isinstance(noise, (int, float)) or not 0 <= noise <= 0.1:
            raise UserError(f"hand_init_noise={noise!r}: expected metres in [0, 0.1]")


def import_metaworld():
    """(mujoco, goal-observable env classes by task, expert classes by task); a UserError naming the set-up when
    Meta-World or MuJoCo is missing."""
    if not os.environ.get("MUJOCO_GL", "").strip():  # unset or empty (MUJOCO_GL= in a script): mujoco picks its
        os.environ["MUJOCO_GL"] = "egl"  # GL backend on import, and an empty value would mean its onscreen glfw
    logging.getLogger("OpenGL").setLevel(logging.WARNING)  # its INFO lines ("no OpenGL_accelerate", "failed to load
    # libOSMesa" before the error below says it) would stand in every run's log
    try:
        import mujoco
        from metaworld.env_dict import ALL_V3_ENVIRONMENTS_GOAL_OBSERVABLE
        from metaworld.policies import ENV_POLICY_MAP
    except ImportError as e:
        raise UserError(f"pipeline=metaworld needs Meta-World and MuJoCo ({e}); install them beside simeval with "
                        "`make metaworld-env` (requirements-metaworld.txt)") from None
    except RuntimeError as e:  # mujoco refuses an unknown MUJOCO_GL at import
        raise UserError(f"MuJoCo cannot start: {e}; {GL_FIX}") from None
    except (AttributeError, OSError) as e:  # PyOpenGL found no library for MUJOCO_GL's backend (e.g. no libOSMesa)
        raise UserError(f"MuJoCo cannot load the GL library of MUJOCO_GL={os.environ['MUJOCO_GL']} "
                        f"({type(e).__name__}: {e}); {GL_FIX}") from None
    envs = {name.removesuffix("-goal-observable"): cls for name, cls in ALL_V3_ENVIRONMENTS_GOAL_OBSERVABLE.items()}
    return mujoco, envs, ENV_POLICY_MAP


GL_FIX = ("MuJoCo renders offscreen through MUJOCO_GL=egl (Mesa's EGL: apt install libegl1 libgl1-mesa-dri) or "
          "MUJOCO_GL=osmesa (apt install libosmesa6)")


_PROBE = ("import mujoco; m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=\"1\"/></worldbody>"
          "</mujoco>'); r = mujoco.Renderer(m, 2, 2); r.render(); r.close()")


def check_rendering() -> None:
    """Meta-World importable and MuJoCo able to render offscreen, else a UserError naming the fix. The render is
    tried in a child process: a collector that forks its workers afterwards should hold no GL context."""
    import subprocess
    import sys

    import_metaworld()
    probe = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120, check=False,
                           env={**os.environ, "MUJOCO_GL": os.environ["MUJOCO_GL"]})
    if probe.returncode != 0:
        last = (probe.stderr.strip().splitlines() or ["no message"])[-1]
        raise UserError(f"MuJoCo cannot render offscreen (MUJOCO_GL={os.environ['MUJOCO_GL']}: {last[:160]}); "
                        f"{GL_FIX}")


def check_task(task: str, envs: Mapping) -> None:
    if task not in envs:
        raise UserError(f"task {task!r} is not a Meta-World v3 task; its tasks: {', '.join(sorted(envs))}")


def make_task_env(task: str, seed: int, hand_init_noise: float = 0.0):
    """Meta-World's goal-observable `task` at variant `seed` (its constructor draws the object and goal positions
    from `seed` and freezes them, so each seed is its own environment); the hand starts `hand_init_noise` m (uniform
    per axis, drawn from `seed`) away from Meta-World's start pose."""
    _, envs, _ = import_metaworld()
    check_task(task, envs)
    env = envs[task](seed=int(seed))
    env.max_path_length = 10**6  # simeval's step limit ends episodes (max_steps), not Meta-World's 500
    if hand_init_noise:
        rng = np.random.default_rng([int(seed), 7])
        env.hand_init_pos = np.asarray(env.hand_init_pos, float) + rng.uniform(-hand_init_noise, hand_init_noise, 3)
    obs, _ = env.reset()
    return env, obs


def progress_of(env, obs: np.ndarray) -> float:
    """Meta-World's shaped reward of a state, scaled to [0, 1] (its v3 rewards lie in [0, 10]), with a zero action
    (some rewards read the gripper command; at reset there is none)."""
    reward, _ = env.evaluate_state(obs, np.zeros(4))
    return float(np.clip(reward / 10.0, 0.0, 1.0))


class Cameras:
    """Offscreen renders of `cameras` (simeval names) at `size`, each with the robot's pixels from a segmentation
    render of the same state. One MuJoCo GL context per instance: close() it."""

    def __init__(self, env, cameras: Sequence[str], size: Sequence[int], quality: str = "fast") -> None:
        mujoco, _, _ = import_metaworld()
        unknown = [c for c in cameras if c not in CAMERAS and c not in SCENE_VIEWS]
        if unknown:
            raise UserError(f"record.cameras: Meta-World's episodes have cameras {list(CAMERAS)}, not {unknown}")
        self.env, self.cameras = env, list(cameras)
        model = env.model
        if quality == "fast":
            model.vis.quality.offsamples = 0
            model.light_castshadow[:] = 0
            model.mat_reflectance[:] = 0
        try:
            self.renderer = mujoco.Renderer(model, int(size[0]), int(size[1]))
        except Exception as e:  # noqa: BLE001 -- MuJoCo and PyOpenGL raise several types (AttributeError, EGLError,
            raise UserError(f"MuJoCo cannot render offscreen (MUJOCO_GL={os.environ.get('MUJOCO_GL')}: "  # FatalError)
                            f"{type(e).__name__}); {GL_FIX}") from None
        robot_bodies = _subtree(model, model.body(ROBOT_ROOT_BODY).id)
        self.robot_geoms = np.flatnonzero(np.isin(model.geom_bodyid, robot_bodies))
        self.geom_type = int(mujoco.mjtObj.mjOBJ_GEOM)

    def render(self, with_masks: bool = True) -> tuple[dict, dict]:
        rgb, masks = {}, {}
        data = self.env.data
        for cam in self.cameras:
            name = CAMERAS.get(cam, cam)
            self.renderer.update_scene(data, camera=name)
            rgb[cam] = np.flipud(self.renderer.render()).copy()
            if with_masks:
                self.renderer.enable_segmentation_rendering()
                self.renderer.update_scene(data, camera=name)
                seg = np.flipud(self.renderer.render())
                self.renderer.disable_segmentation_rendering()
                masks[cam] = (seg[..., 1] == self.geom_type) & np.isin(seg[..., 0], self.robot_geoms)
        return rgb, masks

    def close(self) -> None:
        self.renderer.close()


def _subtree(model, root: int) -> np.ndarray:
    inside = np.zeros(model.nbody, bool)
    inside[root] = True
    for b in range(root + 1, model.nbody):  # MuJoCo numbers a body after its parent
        inside[b] = inside[model.body_parentid[b]]
    return np.flatnonzero(inside)


def expert_action(expert, obs: np.ndarray) -> np.ndarray:
    """The expert's action clipped to Meta-World's [-1, 1] (its experts warn that their gains may exceed it: the
    clip is the answer, so the warning is not shown)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"Constant\(s\) may be too high", category=UserWarning)
        return np.clip(np.asarray(expert.get_action(obs), np.float32), -1.0, 1.0)


def record_episode(task: str, seed: int, settings: MetaworldSettings, cameras: Sequence[str],
                   image_size: Sequence[int], scene_view_size: Sequence[int] | None = (128, 128), *,
                   group: str = "ml10", pipeline: str = "metaworld", robot_masks: bool = True) -> Episode:
    """One expert episode of `task` at variant `seed` (the module docstring has the arrays)."""
    _, _, experts = import_metaworld()
    env, obs = make_task_env(task, seed, settings.hand_init_noise)
    expert = experts[task]()
    cams = Cameras(env, cameras, image_size, settings.render_quality)
    views = Cameras(env, SCENE_VIEWS, scene_view_size, settings.render_quality) if scene_view_size else None
    try:
        scene_views = np.stack([views.render(False)[0][v] for v in SCENE_VIEWS]) if views else None
        frames, masks = cams.render(robot_masks)
        rgb = {c: [frames[c]] for c in cameras}
        robot = {c: [masks[c]] for c in cameras} if robot_masks else None
        states, actions, progress = [obs.astype(np.float32)], [], [progress_of(env, obs)]
        success = False
        while len(actions) < settings.max_steps and not success:
            action = expert_action(expert, obs)
            obs, reward, _, _, info = env.step(action)
            frames, masks = cams.render(robot_masks)
            for c in cameras:
                rgb[c].append(frames[c])
                if robot is not None:
                    robot[c].append(masks[c])
            states.append(obs.astype(np.float32))
            actions.append(action)
            progress.append(float(np.clip(reward / 10.0, 0.0, 1.0)))
            success = bool(info["success"])
        final_view = views.render(False)[0][SCENE_VIEWS[0]] if views else None
    finally:
        cams.close()
        if views:
            views.close()
        env.close()
    n = len(actions)
    progress = np.asarray(progress, np.float32)
    return Episode(
        pipeline=pipeline, task=task, description=task.removesuffix("-v3").replace("-", " "), group=group,
        seed=int(seed), rgb={c: np.stack(v) for c, v in rgb.items()}, state=np.stack(states),
        action=np.stack([*actions, actions[-1]]) if n else np.zeros((1, 4), np.float32),
        reward=np.append(np.diff(progress), 0.0).astype(np.float32),
        is_first=np.arange(n + 1) == 0, is_terminal=np.arange(n + 1) == n, progress=progress, success=success,
        scene_views=scene_views, final_view=final_view, control_hz=CONTROL_HZ, source="metaworld",
        action_space=ACTION_SPACE, state_names=list(STATE_NAMES),
        variation={"hand_init_noise": settings.hand_init_noise} if settings.hand_init_noise else {},
        robot_mask={c: np.stack(v) for c, v in robot.items()} if robot is not None else None,
        extra={"metaworld_task": task, "description_source": "the task's name (Meta-World ships no descriptions)"})


def collect_one(task: str, seed: int, store_root: str, settings: dict, record: dict, pipeline: str,
                group_of: dict) -> dict:
    """A worker of simeval.collect.run_episodes: record and store one episode."""
    from simeval.collect import announce_episode
    from simeval.episodes.store import EpisodeStore

    announce_episode(task, seed)
    t0 = time.perf_counter()
    ep = record_episode(task, seed, MetaworldSettings(**settings), record["cameras"], record["image_size"],
                        record["scene_view_size"], group=group_of[task], pipeline=pipeline,
                        robot_masks=record["robot_masks"])
    path = EpisodeStore(store_root).write(ep)
    return {"task": task, "seed": seed, "success": ep.success, "steps": ep.n_steps,
            "seconds": time.perf_counter() - t0, "bytes": os.path.getsize(path)}
