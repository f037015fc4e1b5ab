"""A closed-loop articulation controller for ee_delta tasks (the RoboGen-style suite): the stand-in for RoboGen's
RL policies (RoboGen trained SAC/PPO per task; we have no such policies, so a scripted controller with
configurable Gaussian action noise produces the solutions instead).

It re-plans every control step from the live simulation (privileged state, as the pick-and-place oracle does):
for the first unfinished joint_range goal it approaches the grip point of the goal's link from above (the grip
point whose normal points most upwards, simeval.sim.core.articulated.grip_points), descends with the suction on until
the cup seizes the link, then drags the seized point along the joint's arc (revolute) or axis (prismatic) a little
per step towards the middle of the goal range; holding the wrong thing, or a finished link while another goal
remains, it releases and lifts. Actions are 7-d ee_delta (simeval.sim.env): the translation is the next waypoint
minus the environment's commanded tip (`env.ee_target`; while dragging: minus the seized point, so the command
moves by the step the link should make), plus noise N(0, noise_std^2) per axis (m), then clipped
to the action bounds; the rotation channels stay 0 (the tool keeps pointing down: the point grip lets the link
turn under it). The noise is drawn from the episode seed, so under RoboGen's fixed initial state the episodes of
a task differ by it alone."""

from __future__ import annotations

import numpy as np

from simeval.errors import UserError
from simeval.sim.action_spaces import EE_HIGH, EE_LOW, EE_MAX_TRANSLATION
from simeval.sim.core.articulated import grip_points, joint_axis_world, joint_fraction, joint_limits, link_frame
from simeval.sim.tasks.goals import unit_status

APPROACH_HEIGHT = 0.05  # m above the grip point before the descent
DESCENT_STEP = 0.005  # m per step in the last part of the descent (a gentle contact)
DRAG_STEP = 0.008  # m the seized point is moved along its path per step (below the 1 cm action bound)
ALIGN_TOL = 0.012  # m: horizontal distance to the grip point below which the descent starts


def _rotate(p: np.ndarray, pivot: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' rotation of point p about the line through `pivot` along unit `axis`."""
    v = p - pivot
    c, s = np.cos(angle), np.sin(angle)
    return pivot + v * c + np.cross(axis, v) * s + axis * np.dot(axis, v) * (1 - c)


class ArticulationController:
    """policy(obs) -> 7-d ee_delta action, or None once every goal is done; `reset(env)` after each env.reset."""

    def __init__(self, noise_std: float = 0.002) -> None:
        if isinstance(noise_std, bool) or not isinstance(noise_std, (int, float)) or noise_std < 0:
            raise UserError(f"noise_std must be a number of metres >= 0, got {noise_std!r}")
        self.noise_std = float(noise_std)
        self.env = None

    def reset(self, env) -> None:
        if env.mode != "ee_delta":
            raise UserError(f"the articulation controller acts through action_space='ee_delta', not {env.mode!r}")
        self.env = env
        self.rng = np.random.default_rng([int(env.episode_seed), 7])  # the action noise: from the episode seed
        self._seized: tuple[int, int, np.ndarray] | None = None  # (body, link, seized point in the link frame)

    def _target(self):
        """The first unfinished joint_range goal and its object, or None."""
        world, inst = self.env.world, self.env.inst
        for goal in inst.spec.goals:
            if goal.type != "joint_range":
                raise UserError(f"task {inst.spec.name}: the articulation controller solves joint_range goals, "
                                f"not {goal.type}")
            status = unit_status(world, inst, goal)
            if not all(status):
                return goal, inst.by_name(goal.what[0])[status.index(False)]
        return None

    def plan(self) -> tuple[np.ndarray, float, np.ndarray | None] | None:
        """The next waypoint of the tool tip, the suction command and, while dragging, the seized point now (the
        step is then the waypoint minus that point: a loaded arm lags its command, and the drag must not shrink
        by the lag); None when done."""
        env, c = self.env, self.env.world.c
        target = self._target()
        if target is None:
            return None
        goal, obj = target
        body, link = obj.body_ids[0], goal.joint
        arm, tip = env.arm, env.arm.tip()
        if arm.held is not None and (arm.held, arm.held_link) != (body, link):
            self._seized = None
            return tip + np.array([0.0, 0.0, EE_MAX_TRANSLATION]), 0.0, None  # the wrong thing: let go and lift
        if arm.held is not None:
            pos, rot = link_frame(c, body, link)
            if self._seized is None or self._seized[:2] != (body, link):
                self._seized = (body, link, rot.T @ (tip - pos))
            point = pos + rot @ self._seized[2]
            lo, hi = joint_limits(c, body, link)
            want = float(np.clip((goal.range[0] + goal.range[1]) / 2, 0.0, 1.0))
            dq = (want - joint_fraction(c, body, link)) * (hi - lo)
            pivot, axis, kind = joint_axis_world(c, body, link)
            if kind == "revolute":
                radius = max(np.linalg.norm(np.cross(axis, point - pivot)), 1e-3)
                step = float(np.clip(dq, -DRAG_STEP / radius, DRAG_STEP / radius))
                return _rotate(point, pivot, axis, step), 1.0, point
            return point + axis * float(np.clip(dq, -DRAG_STEP, DRAG_STEP)), 1.0, point
        self._seized = None
        grip, normal = max(grip_points(c, obj, link), key=lambda g: g[1][2])
        above = grip + np.array([0.0, 0.0, APPROACH_HEIGHT])
        horizontal = np.linalg.norm(tip[:2] - grip[:2])
        if horizontal > ALIGN_TOL:
            if tip[2] < above[2] - 0.01 and horizontal > 0.05:
                return np.r_[tip[:2], above[2]], 0.0, None  # rise first: never sweep low across the object
            return above, 0.0, None
        # above the grip point: descend; the suction goes on only in the last 2 cm (so a cup blocked higher up
        # by another part seizes nothing) and seizes the link at contact (Arm.apply)
        down = grip - np.array([0.0, 0.0, 0.01])
        near = tip[2] - grip[2] < 0.02
        step = min(DESCENT_STEP if near else EE_MAX_TRANSLATION, max(tip[2] - down[2], 0.0))
        return np.r_[grip[:2], tip[2] - step], float(near), None

    def __call__(self, obs) -> np.ndarray | None:
        planned = self.plan()
        if planned is None:
            return None
        waypoint, suction, seized = planned
        delta = waypoint - (self.env.ee_target if seized is None else seized) + self.rng.normal(0.0, self.noise_std, 3)
        action = np.r_[delta, 0.0, 0.0, 0.0, suction].astype(np.float32)
        return np.clip(action, EE_LOW, EE_HIGH)
