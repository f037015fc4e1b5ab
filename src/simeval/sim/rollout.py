"""Run one episode of a task spec with the oracle and log it as the authors did: low-level frames, 12-d state
and joint-target actions at the control rate, and the 14-d high-level pick/place poses with the low-level step
where each starts."""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from simeval.episodes.episode import Episode
from simeval.errors import UserError
from simeval.sim.goals import task_progress
from simeval.sim.objects import make_object
from simeval.sim.oracle import next_primitive
from simeval.sim.robot import Arm
from simeval.sim.spec import TaskSpec, check_variation, sample_instance
from simeval.sim.world import OBS_CAMERAS, SCENE_VIEWS, TABLE_Z, World


@dataclass
class RecordSettings:
    cameras: tuple[str, ...] = ("top", "front")
    image_size: tuple[int, int] = (64, 64)
    scene_view_size: tuple[int, int] = (128, 128)
    control_hz: float = 30.0
    record_every: int = 1  # log every k-th control step (1 = the full control rate)

    def __post_init__(self) -> None:
        # configs give lists; the settings travel to worker processes and into keys, so keep them immutable.
        # Messages name the config keys (record.*), where these values come from on the command line.
        self.cameras = (self.cameras,) if isinstance(self.cameras, str) else tuple(self.cameras or ())
        self.image_size = image_size_pair(self.image_size, "record.image_size")
        self.scene_view_size = image_size_pair(self.scene_view_size, "record.scene_view_size")
        unknown = [c for c in self.cameras if c not in OBS_CAMERAS]
        if unknown:
            raise UserError(f"record.cameras: unknown camera(s) {unknown}; known: {', '.join(OBS_CAMERAS)}")
        every = self.record_every
        if isinstance(every, bool) or not isinstance(every, numbers.Integral) or every < 1:
            raise UserError(f"record.record_every must be an integer >= 1, got {self.record_every!r}")
        hz = self.control_hz
        if isinstance(hz, bool) or not isinstance(hz, numbers.Real) or not hz > 0:
            raise UserError(f"record.control_hz must be a number > 0, got {self.control_hz!r}")


def image_size_pair(value, key: str) -> tuple[int, int]:
    """[H, W] with both >= 1, as a tuple; anything else is a UserError naming `key`."""
    ok = (isinstance(value, (list, tuple)) and len(value) == 2
          and all(isinstance(x, numbers.Integral) and not isinstance(x, bool) and x >= 1 for x in value))
    if not ok:
        raise UserError(f"{key} must be [H, W] with whole numbers H, W >= 1, got {value!r}")
    return int(value[0]), int(value[1])


def run_episode(spec: TaskSpec, seed: int, settings: RecordSettings | None = None, pipeline: str = "gensim",
                variation: dict | None = None, final_frame_size: tuple[int, int] | None = None) -> Episode:
    """`variation` overrides the spec's knobs for this episode: {object name: {colors, count}} and
    {"robot": {"home_noise": radians}} for the robot's start (what a generalization test varies)."""
    settings = settings or RecordSettings()
    variation = check_variation([spec], variation)
    home_noise = float(variation.pop("robot", {}).get("home_noise", spec.home_noise))
    inst = sample_instance(spec, seed, variation)
    rng = np.random.default_rng(seed + 7919)
    with World(settings.control_hz) as world:
        arm = Arm(world, spec.end_effector, home_noise, rng)
        for obj in inst.objects:
            xy, yaw = inst.poses[obj.id]
            make_object(world.c, obj, xy, yaw, rng, TABLE_Z)
        world.settle(60)
        views = np.stack([world.render(v, settings.scene_view_size) for v in SCENE_VIEWS])
        frames = {c: [] for c in settings.cameras}
        states, actions, progress = [], [], []
        control_steps = 0

        def log(action: np.ndarray) -> None:
            nonlocal control_steps
            control_steps += 1
            if (control_steps - 1) % settings.record_every:
                return
            for cam in settings.cameras:
                frames[cam].append(world.render(OBS_CAMERAS[cam], settings.image_size))
            states.append(arm.state())
            actions.append(action)
            progress.append(task_progress(world, inst)[0])

        arm.logger = log
        hl_actions, hl_steps = [], []
        for _ in range(spec.max_primitives):
            prim = next_primitive(world, inst)
            if prim is None:
                break
            hl_steps.append(len(actions))
            hl_actions.append(prim.pose14(world))
            prim.execute(arm, world)
        arm.park()  # out of the cameras' view: the last frames show the result
        arm.hold(10)
        final, success = task_progress(world, inst)
        final_view = world.render(SCENE_VIEWS[0], final_frame_size) if final_frame_size else None
    t = len(actions)
    if t == 0:  # an episode with no step cannot be stored; a spec that starts solved is a spec error
        raise RuntimeError(f"{spec.name} seed {seed}: the oracle made no move; is the task solved at start?")
    prog = np.asarray(progress, np.float32)
    prog[-1] = final
    reward = np.diff(np.r_[0.0, prog]).astype(np.float32)  # rewards sum to the final partial progress
    return Episode(
        pipeline=pipeline, task=spec.name, description=inst.description, group=spec.group, seed=seed,
        rgb={c: np.stack(f) for c, f in frames.items()}, state=np.stack(states), action=np.stack(actions),
        reward=reward, progress=prog, is_first=np.arange(t) == 0, is_terminal=np.arange(t) == t - 1,
        success=bool(success), high_level_action=np.stack(hl_actions) if hl_actions else np.zeros((0, 14), np.float32),
        high_level_step=np.asarray(hl_steps, np.int64), scene_views=views, control_hz=settings.control_hz,
        source="simeval-suite", final_view=final_view,
        extra={"objects": {o.id: {"shape": o.shape, "color": o.color} for o in inst.objects}})
