"""A Gymnasium environment over a suite task: the one code path for learned policies, the oracle and collection.

    from simeval.sim import make_env
    env = make_env("stack-two-blocks", action_space="joint", image_size=(64, 64), cameras=("top",))
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(action)

Observations: {"rgb": {camera: (H, W, 3) uint8}, "state": float32} -- the state follows the task's robot (spec
field `robot`; names in `state_names(robot)`): xarm6 (14): 6 joint positions (rad), 6 joint velocities (rad/s), the
suction command in force (0/1) and whether an object is held (0/1) (simeval.sim.robots.xarm.STATE_NAMES); panda (16):
7 joint positions, 7 velocities, the gripper opening (m) and the gripper command (simeval.sim.robots.panda.STATE_NAMES).
`info` carries `progress` (partial progress in [0, 1], the mean over the task's goals) and `success` (every goal
done); the reward is the change in progress; `terminated` is success; `truncated` is the step limit.

Action spaces (`ACTION_SPACES`; each stored episode records the one it was recorded in):
  joint           kind `joint_pos+suction`, 7-d at the control rate (30 Hz by default): the 6 joint position
                  targets (rad, clipped to the joint limits) and the suction command (>= 0.5: on). Suction on with
                  nothing held attaches whatever the cup touches; off releases. The spatula has no actuation: its
                  tasks take the same 7-d action and ignore the last channel (recorded as 0).
  pick_place      kind `pick_place_14d`, one primitive per step, Ravens' convention:
                  [pose0 xyz (m), pose0 quaternion xyzw, pose1 xyz (m), pose1 quaternion xyzw], world frame.
                  Suction tasks: pose0 is the pick point (the top centre of the object to pick) with the tool yaw
                  there; pose1 is the place point: where the pick point should end up, i.e. the object's target
                  pose applied to the grasp (for a top-centre grasp: the target centre raised by half the object's
                  height), with the tool yaw there; the object turns by yaw(pose1) - yaw(pose0) (Ravens' oracle
                  uses an identity pick rotation, a special case). The tool goes down at pose0 until the cup
                  touches, lifts, goes over pose1 and down until the pick point is at pose1, and releases.
                  Spatula tasks: pose0 and pose1 are the push's start and end on the table (z and rotations
                  ignored; the blade is across the push). The step returns when the primitive finishes and
                  every object rests (holding still for at most 60 control steps, 20 after a push); a
                  step that ends the episode (success, or the step limit) then parks the arm out of the
                  cameras' view and holds still for 10 control steps (`park_at_end`, on by default), so the
                  final observation shows the result (those control steps are part of the step).
  ee_delta        kind `ee_delta+suction`, 7-d per control step (RoboGen's low-level action): [dx, dy, dz (m),
                  droll, dpitch, dyaw (rad), suction (>= 0.5: on)], each clipped to +-EE_MAX_TRANSLATION (1 cm)
                  and +-EE_MAX_ROTATION (0.05 rad) per step. The environment keeps a commanded tool pose (from the
                  tool's pose at reset), moves it by the delta (translation in the world frame; rotation: the
                  increment's XYZ Euler angles about the world axes, applied on the left), keeps the commanded tip
                  within EE_MAX_LAG of the real one (a blocked arm does not wind up a far target), and sends the IK
                  solution with the suction command through the same low-level step as `joint`. Suction on with
                  nothing held attaches what the cup touches: a free object rigidly, a moving link of an
                  articulated object by a point at the cup's tip.

  ee_pose         kind `ee_pose+gripper` (Panda tasks), 8-d at the control rate (4 Hz by default, BBSEA's): the
                  absolute grasp-point target [x, y, z (m), qx, qy, qz, qw, gripper (>= 0.5 closed)], reached
                  within the step (simeval.sim.robots.panda). A step that ends the episode parks the arm as above.
A task's native action space is its spec's `action_space` (default joint); `make_env(task)` uses it.

With `record_low_level=True` a pick_place step also returns, in info["low_level"], every control step it took:
{"action": [(7,)], "obs": [...], "progress": [...], "success": [...], "object_poses": [(N, 7)]} -- each entry
exactly what a joint step with that action would have returned. Collection records that (simeval.sim.rollout),
so stored low-level episodes replay bit for bit through action_space="joint" (PyBullet DIRECT is deterministic).

Every reset builds a fresh PyBullet world (the same seed gives the same scene, bit for bit).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from simeval.errors import UserError
from simeval.sim.action_spaces import (  # noqa: F401
    EE_DELTA_KIND,
    EE_HIGH,
    EE_LOW,
    EE_POSE_HIGH,
    EE_POSE_HZ,
    EE_POSE_KIND,
    EE_POSE_LOW,
    JOINT_KIND,
    PICK_PLACE_KIND,
    POSE_HIGH,
    POSE_LOW,
    ee_delta_action_space,
    ee_pose_action_space,
    joint_action_space,
    pick_place_action_space,
)
from simeval.sim.core.articulated import moving_links, set_joint_fraction
from simeval.sim.core.geometry import still
from simeval.sim.core.objects import make_object
from simeval.sim.core.world import OBS_CAMERAS, PILE_SOLVER_RESIDUAL, SCENE_VIEWS, TABLE_Z, World
from simeval.sim.robots import Robot, robot_kind
from simeval.sim.robots.xarm import JOINT_LOWER, JOINT_UPPER
from simeval.sim.tasks.goals import task_progress
from simeval.sim.tasks.spec import (
    TaskSpec,
    check_variation,
    load_suite,
    sample_instance,
    scene_seed,
    suite_dirs,
    task_seed,
)

ACTION_SPACES = {"joint": JOINT_KIND, "pick_place": PICK_PLACE_KIND, "ee_delta": EE_DELTA_KIND,
                 "ee_pose": EE_POSE_KIND}
EE_MAX_LAG = 0.03  # m: the commanded tip of ee_delta stays within this of the real tip
EE_STEPS_PER_PRIMITIVE = 150  # ee_delta's default step limit: 5 s at 30 Hz per `max_primitives` of the task


def state_names(robot: str = "xarm6") -> tuple[str, ...]:
    """The names of the state dimensions of `robot` (a spec's `robot` field)."""
    return robot_kind(robot).state_names


def find_task(task: str | TaskSpec) -> TaskSpec:
    """A TaskSpec as is, or a suite task by name (every suite simeval ships, spec.suite_dirs)."""
    if isinstance(task, TaskSpec):
        return task
    specs = {s.name: s for d in suite_dirs().values() for s in load_suite(d)}
    if task not in specs:
        raise UserError(f"task={task!r} is not a suite task; available: {', '.join(sorted(specs))}")
    return specs[task]


def _gym():
    try:
        import gymnasium
    except ImportError as e:  # pragma: no cover - gymnasium is in requirements.txt
        raise UserError("make_env needs gymnasium: pip install -r requirements.txt") from e
    return gymnasium


class SimEnv(_gym().Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, task: str | TaskSpec, action_space: str | None = None, variation: dict | None = None,
                 image_size: Sequence[int] = (64, 64), cameras: Sequence[str] = ("top", "front"),
                 control_hz: float | None = None, max_steps: int | None = None, record_low_level: bool = False,
                 scene_view_size: Sequence[int] | None = None, render_mode: str | None = None,
                 park_at_end: bool = True, robot_masks: bool = False) -> None:
        from gymnasium import spaces

        self.spec_task = find_task(task)
        action_space = action_space or self.spec_task.action_space
        if action_space not in ACTION_SPACES:
            raise UserError(f"action_space={action_space!r}: expected one of {', '.join(ACTION_SPACES)}")
        robot = robot_kind(self.spec_task.robot)
        if action_space not in robot.action_spaces:
            raise UserError(f"action_space={action_space!r}: task {self.spec_task.name} (robot {robot.name}) takes "
                            f"{', '.join(robot.action_spaces)}")
        if control_hz is None:
            control_hz = EE_POSE_HZ if action_space == "ee_pose" else 30.0
        self.cameras = tuple(cameras)
        unknown = [c for c in self.cameras if c not in OBS_CAMERAS]
        if unknown:
            raise UserError(f"cameras: unknown camera(s) {unknown}; known: {', '.join(OBS_CAMERAS)}")
        self.image_size = tuple(int(x) for x in image_size)
        if len(self.image_size) != 2 or min(self.image_size) < 1:
            raise UserError(f"image_size={list(image_size)}: expected [H, W] with H, W >= 1")
        if render_mode not in (None, "rgb_array"):
            raise UserError(f"render_mode={render_mode!r}: expected None or 'rgb_array'")
        self.mode, self.variation = action_space, check_variation([self.spec_task], variation)
        self.control_hz, self.record_low_level = float(control_hz), bool(record_low_level)
        self.scene_view_size = tuple(scene_view_size) if scene_view_size else None
        self.render_mode = render_mode
        self.park_at_end = bool(park_at_end)
        self.robot_masks = bool(robot_masks)  # observations add "robot_mask" (for recorders; not in observation_space)
        # joint: a generous bound on an oracle episode (~150-300 control steps per primitive)
        # ee_pose: a primitive takes 20-40 control steps at 4 Hz
        per = {"joint": 400, "pick_place": 1, "ee_delta": EE_STEPS_PER_PRIMITIVE, "ee_pose": 60}[action_space]
        self.max_steps = int(max_steps or (self.spec_task.max_primitives * per))
        h, w = self.image_size
        self.observation_space = spaces.Dict({
            "rgb": spaces.Dict({c: spaces.Box(0, 255, (h, w, 3), np.uint8) for c in self.cameras}),
            "state": spaces.Box(robot.state_low, robot.state_high, dtype=np.float32)})
        if action_space == "ee_pose":
            self.action_space = spaces.Box(EE_POSE_LOW, EE_POSE_HIGH, dtype=np.float32)
            self.action_info = ee_pose_action_space(self.control_hz)
        elif action_space == "joint":
            self.action_space = spaces.Box(np.array([*JOINT_LOWER, 0.0], np.float32),
                                           np.array([*JOINT_UPPER, 1.0], np.float32), dtype=np.float32)
            self.action_info = joint_action_space(self.control_hz)
        elif action_space == "ee_delta":
            self.action_space = spaces.Box(EE_LOW, EE_HIGH, dtype=np.float32)
            self.action_info = ee_delta_action_space(self.control_hz)
        else:
            self.action_space = spaces.Box(POSE_LOW, POSE_HIGH, dtype=np.float32)
            self.action_info = pick_place_action_space(self.control_hz)
        self.world: World | None = None
        self.arm: Robot | None = None  # an Arm (xArm6) or a Panda, by the task's robot
        self.inst = None
        self.episode_seed: int | None = None
        self._low: dict | None = None
        self._steps, self._progress = 0, 0.0

    # --- gymnasium API ---------------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.episode_seed = int(seed) if seed is not None else int(self.np_random.integers(0, 2**31 - 1))
        self._build(self.episode_seed)
        self._steps = 0
        obs = self.observe()
        info = self._info()
        self._progress = info["progress"]
        if self.scene_view_size:
            info["scene_views"] = np.stack([self.world.render(v, self.scene_view_size) for v in SCENE_VIEWS])
        return obs, info

    def step(self, action):
        if self.world is None:
            raise UserError("call env.reset() before env.step()")
        action = np.asarray(action, np.float32).reshape(-1)
        if action.shape != self.action_space.shape:
            raise UserError(f"action_space={self.mode!r} takes {self.action_space.shape[0]} values per action, "
                            f"got shape {action.shape}")
        if not np.all(np.isfinite(action)):  # NaN targets leave the solver's state non-finite and later steps hang
            raise UserError(f"action_space={self.mode!r}: the action has non-finite values {action.tolist()}")
        low = None
        self._steps += 1
        if self.mode == "joint":
            self.arm.apply(action)
        elif self.mode == "ee_pose":
            self.arm.apply(action)
            if self.park_at_end and (self._info()["success"] or self._steps >= self.max_steps):
                self._settle_ee(8)  # let what was just released come to rest before the arm leaves
                self.arm.park()  # out of the cameras' view: the last observation shows the result
        elif self.mode == "ee_delta":
            self.apply_ee_delta(action)
        else:
            self._low = low = ({"action": [], "obs": [], "progress": [], "success": [], "object_poses": []}
                               if self.record_low_level else None)
            try:
                if self.spec_task.end_effector == "spatula":
                    self.arm.push(action)
                    self._settle(20)
                else:
                    self.arm.pick_place(action)
                    self._settle(60)
                if self.park_at_end and (self._info()["success"] or self._steps >= self.max_steps):
                    self.arm.park()  # out of the cameras' view: the last observation shows the result
                    self.arm.hold(10)
            finally:
                self._low = None
        obs = low["obs"][-1] if low and low["obs"] else self.observe()
        info = self._info() if not low or not low["obs"] else {"progress": low["progress"][-1],
                                                                 "success": low["success"][-1]}
        if low is not None:
            info["low_level"] = low
        reward = float(info["progress"] - self._progress)
        self._progress = info["progress"]
        return obs, reward, bool(info["success"]), self._steps >= self.max_steps and not info["success"], info

    def render(self):
        cam = OBS_CAMERAS[self.cameras[0] if self.cameras else "front"]
        return self.world.render(cam, self.image_size) if self.world is not None else None

    def close(self) -> None:
        if self.world is not None:
            self.world.close()
        self.world = self.arm = None

    # --- helpers ---------------------------------------------------------------------------------------------
    def observe(self) -> dict:
        """The observation of the current state (what reset and step return)."""
        if not self.robot_masks:
            return {"rgb": {c: self.world.render(OBS_CAMERAS[c], self.image_size) for c in self.cameras},
                    "state": self.arm.state()}
        rgb, robot = {}, {}
        for c in self.cameras:  # one render per camera gives the image and which body each pixel shows
            rgb[c], bodies = self.world.render_with_bodies(OBS_CAMERAS[c], self.image_size)
            robot[c] = np.isin(bodies, self.arm.body_ids)
        return {"rgb": rgb, "state": self.arm.state(), "robot_mask": robot}

    def _info(self) -> dict:
        progress, success = task_progress(self.world, self.inst)
        return {"progress": float(progress), "success": bool(success)}

    @property
    def ee_target(self) -> np.ndarray:
        """The commanded tool tip of ee_delta (m, world frame): where the deltas are added."""
        return np.array(self._ee_pos, dtype=float)

    def apply_ee_delta(self, action) -> np.ndarray:
        """One ee_delta control step (see the module docstring); returns the action as applied (clipped, float32,
        suction 0/1), which replays bit for bit."""
        c = self.world.c
        a = np.clip(np.asarray(action, np.float32).reshape(-1), EE_LOW, EE_HIGH).astype(np.float32)
        a[6] = np.float32(a[6] >= 0.5)
        tip = self.arm.tip()
        target = self._ee_pos + a[:3].astype(np.float64)
        lag = target - tip
        if np.linalg.norm(lag) > EE_MAX_LAG:
            target = tip + lag * (EE_MAX_LAG / np.linalg.norm(lag))
        self._ee_pos = target
        if np.any(a[3:6]):
            turn = c.getQuaternionFromEuler(a[3:6].astype(np.float64).tolist())
            self._ee_orn = c.multiplyTransforms([0, 0, 0], turn, [0, 0, 0], self._ee_orn)[1]
        self.arm.apply(np.r_[self.arm.ik_pose(target, self._ee_orn), a[6]])
        return a

    def _build(self, seed: int) -> None:
        self.close()
        spec, variation = self.spec_task, dict(self.variation)
        home_noise = float(variation.pop("robot", {}).get("home_noise", spec.home_noise))
        seed = scene_seed(spec, seed, variation)  # a `fixed` task: every episode from the scene of seed 0
        pose_range = float(variation.pop("scene", {}).get("pose_range", 1.0))
        self.inst = sample_instance(spec, seed, variation, pose_range)
        # the physical randomness (pile spreads, the arm's home noise): a child of the task's own stream, so two
        # tasks with the same seed differ here too, and it stays unrelated to the draws of sample_instance
        rng = np.random.default_rng(task_seed(spec.name, seed).spawn(1)[0])
        piles = any(o.shape == "pile" for o in self.inst.objects)
        self.world = World(self.control_hz, solver_residual=PILE_SOLVER_RESIDUAL if piles else None)
        self.arm = robot_kind(spec.robot).build(self.world, spec, home_noise, rng)
        for obj in self.inst.objects:
            xy, yaw = self.inst.poses[obj.id]
            make_object(self.world.c, obj, xy, yaw, rng, TABLE_Z)
            for k, f in enumerate(self.inst.joints.get(obj.id, ())):  # articulated objects, jointed fixtures
                set_joint_fraction(self.world.c, obj.body_ids[0], k, f)
            for body in obj.body_ids if obj.id in self.inst.frictions else ():
                self.world.c.changeDynamics(body, -1, lateralFriction=self.inst.frictions[obj.id])
        self.world.settle(60)
        self.arm.on_step = self._on_low_level_step
        if "ee_delta" in robot_kind(spec.robot).action_spaces:  # ee_delta's commanded tool pose
            self._ee_pos = self.arm.tip()
            self._ee_orn = tuple(self.world.c.getLinkState(self.arm.body, self.arm.ee)[5])

    def _on_low_level_step(self, action: np.ndarray) -> None:
        if self._low is None:
            return
        info = self._info()
        self._low["action"].append(action.copy())
        self._low["obs"].append(self.observe())
        self._low["progress"].append(info["progress"])
        self._low["success"].append(info["success"])
        self._low["object_poses"].append(self.object_poses())

    def _settle_ee(self, max_steps: int) -> None:
        """ee_pose: hold the last target (whole control steps of physics, not logged) until every object rests."""
        bodies = [b for o in self.inst.objects for b in o.body_ids]
        for _ in range(max_steps):
            if all(still(self.world, b) for b in bodies):
                return
            self.world.step()

    def _settle(self, max_steps: int) -> None:
        """Hold still until every object rests (at most `max_steps` control steps), so the step returns a
        settled scene (goals count only objects at rest) and the next primitive is planned on it."""
        bodies = [b for o in self.inst.objects for b in o.body_ids]
        for _ in range(max_steps):
            if all(still(self.world, b) for b in bodies):
                return
            self.arm.hold(1)

    def object_poses(self) -> np.ndarray:
        """(N, 7) position and xyzw quaternion of every object body, in the order of the instance's objects
        (a pile contributes one row per particle), each body's row followed by one per link on a moving joint (its
        joint frame in the world: an articulated object's lid, door or drawer, a fixture's drawer or button cap), so
        an articulation shows in the poses although its fixed base never moves. Privileged: not part of the
        observation."""
        c = self.world.c
        rows = []
        for b in (b for o in self.inst.objects for b in o.body_ids):
            pos, orn = c.getBasePositionAndOrientation(b)
            rows.append(np.r_[pos, orn])
            for k in moving_links(c, b):
                pos, orn = c.getLinkState(b, k, computeForwardKinematics=True)[4:6]
                rows.append(np.r_[pos, orn])
        return np.asarray(rows, np.float32).reshape(-1, 7)


def make_env(task: str | TaskSpec, action_space: str | None = None, variation: dict | None = None,
             image_size: Sequence[int] = (64, 64), cameras: Sequence[str] = ("top", "front"), **kwargs) -> SimEnv:
    """A Gymnasium environment of a suite task (name or TaskSpec); action_space None: the task's native one (its
    spec's `action_space`); see the module docstring. kwargs: control_hz,
    max_steps, record_low_level, scene_view_size, render_mode, park_at_end."""
    return SimEnv(task, action_space, variation, image_size, cameras, **kwargs)
