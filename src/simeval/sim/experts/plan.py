"""BBSEA's primitive actions as generators of `ee_pose` targets, and a task's plan (a list of them) as a policy.

A task spec's `plan` is what BBSEA's LLM decomposition produces: `[{open_drawer: drawer}, {pick: block},
{place_in: drawer}]`. Each primitive is a generator that yields 8-d ee_pose actions (simeval.sim.robots.panda) one
control step (4 Hz) at a time; it is closed loop: poses are read from the simulator when the primitive starts
and again before each contact (grasp, release, push), and pick and push retry (at most RETRIES times) when the
state after them shows they failed. Motions are straight lines of at most STEP_M per control step, the hand yaw
turning with them, so the controller reaches each target within its step.

Primitives (the object named is the instance 0 of that spec object):
  pick X          grasp X from above (hand yaw along X's footprint) and lift it to CARRY_Z
  place_on X      put what is held on top of X
  place_at X      put what is held on the table at X's centre (X: a zone)
  place_in X      put what is held into X (a bin, a bowl, or the open part of a drawer)
  push X          push X with the closed gripper to the zone of the in_zone goal that names X
  open_drawer X   pinch X's handle, pull it out to the middle of its joint_range goal if that is an open one
                  (fully otherwise), let go
  close_drawer X  pinch the handle and push it in to the middle of its closed joint_range goal (fully otherwise)
  press X         press the button X down with the closed fingers and come back up
"""

from __future__ import annotations

import math

import numpy as np

from simeval.sim.core.geometry import height, in_zone, pose
from simeval.sim.core.objects import SimObject
from simeval.sim.core.world import TABLE_Z

STEP_M = 0.05  # longest straight-line move per control step (m): 0.2 m/s at 4 Hz
SLOW_M = 0.02  # near contact
CARRY_Z = 0.25  # grasp-point height for moves across the table (clears the cabinet and the bins)
APPROACH = 0.10  # height above a grasp or release point where the straight descent starts
FINGER_BELOW = 0.011  # the finger tips are this far below the grasp point
RETRIES = 2
SETTLE_STEPS = 6  # control steps held after the plan (1.5 s at 4 Hz)


class Context:
    """What the primitives share within one episode: the environment, the commanded pose, what is held."""

    def __init__(self, env) -> None:
        self.env, self.world, self.inst = env, env.world, env.inst
        a = env.arm.last_action
        self.pos, self.yaw, self.grip = np.asarray(a[:3], float), _yaw(a[3:7]), 0.0
        self.held: SimObject | None = None
        self.grasp_above_bottom = 0.0  # held object: the grasp point's height above its bottom

    def obj(self, name: str) -> SimObject:
        return self.inst.by_name(name)[0]

    def action(self) -> np.ndarray:
        from simeval.sim.robots.panda import down_quat

        return np.r_[self.pos, down_quat(self.yaw), self.grip].astype(np.float32)

    def move(self, pos, yaw: float | None = None, step: float = STEP_M):
        """Straight line from the commanded pose to `pos` (and `yaw`), at most `step` per control step."""
        pos = np.asarray(pos, float)
        yaw = self.yaw if yaw is None else yaw
        dyaw = (yaw - self.yaw + math.pi) % (2 * math.pi) - math.pi
        n = max(1, int(math.ceil(max(np.linalg.norm(pos - self.pos) / step, abs(dyaw) / 0.5))))
        start, yaw0 = self.pos.copy(), self.yaw
        for k in range(1, n + 1):
            self.pos, self.yaw = start + (pos - start) * k / n, yaw0 + dyaw * k / n
            yield self.action()

    def gripper(self, closed: bool, steps: int = 2):
        self.grip = 1.0 if closed else 0.0
        for _ in range(steps):
            yield self.action()

    def holding(self) -> bool:
        return self.env.arm.held is not None


def _yaw(quat) -> float:
    """The hand yaw of a pointing-down quaternion (the inverse of panda.down_quat)."""
    x, y = float(quat[0]), float(quat[1])
    return 2 * math.atan2(y, x)


def _wrap(a: float, period: float) -> float:
    return (a + period / 2) % period - period / 2


def grasp_yaw(world, obj: SimObject) -> float:
    """Hand yaw that closes the fingers across the object's footprint's short side (its local y), the nearest
    to 0 among the symmetric ones."""
    if obj.shape in ("sphere", "cylinder"):
        return 0.0
    _, yaw = pose(world, obj)
    sx, sy = obj.size[:2]
    if abs(sx - sy) < 1e-6:
        return _wrap(yaw, math.pi / 2)
    return _wrap(yaw if sx >= sy else yaw + math.pi / 2, math.pi)


def pick(ctx: Context, name: str):
    obj = ctx.obj(name)
    for _ in range(RETRIES + 1):
        p, _ = pose(ctx.world, obj)
        top = p[2] + height(obj) / 2
        grasp_z = max(top - min(0.02, height(obj) / 2), TABLE_Z + FINGER_BELOW + 0.004)
        yaw = grasp_yaw(ctx.world, obj)
        yield from ctx.gripper(False, 1)
        yield from ctx.move([p[0], p[1], max(CARRY_Z, top + APPROACH)], yaw)
        p, _ = pose(ctx.world, obj)  # re-read: it may have been nudged
        yield from ctx.move([p[0], p[1], grasp_z + 0.04])
        yield from ctx.move([p[0], p[1], grasp_z], step=SLOW_M)
        yield from ctx.gripper(True)
        if ctx.holding():
            ctx.held, ctx.grasp_above_bottom = obj, grasp_z - (p[2] - height(obj) / 2)
            yield from ctx.move([ctx.pos[0], ctx.pos[1], CARRY_Z], step=0.04)
            return
        yield from ctx.gripper(False, 1)
        yield from ctx.move([ctx.pos[0], ctx.pos[1], CARRY_Z])


def _release_at(ctx: Context, xy, bottom_z: float, yaw: float | None = None, drop: float = 0.012):
    """Carry the held object over `xy`, lower it until its bottom is `drop` above `bottom_z`, let go, go up."""
    z = bottom_z + ctx.grasp_above_bottom + drop
    yield from ctx.move([ctx.pos[0], ctx.pos[1], max(ctx.pos[2], CARRY_Z)])
    yield from ctx.move([xy[0], xy[1], max(CARRY_Z, z + APPROACH)], yaw)
    yield from ctx.move([xy[0], xy[1], z + 0.04])
    yield from ctx.move([xy[0], xy[1], z], step=SLOW_M)
    yield from ctx.gripper(False)
    ctx.held = None
    yield from ctx.move([xy[0], xy[1], max(CARRY_Z, z + APPROACH)])


def place_on(ctx: Context, name: str):
    target = ctx.obj(name)
    p, _ = pose(ctx.world, target)
    yield from _release_at(ctx, p[:2], p[2] + height(target) / 2, drop=0.008)


def place_at(ctx: Context, name: str):
    p, _ = pose(ctx.world, ctx.obj(name))
    yield from _release_at(ctx, p[:2], TABLE_Z)


def place_in(ctx: Context, name: str):
    from simeval.sim.core.fixtures import WALL, drawer_drop_point, yaw_of_body

    target = ctx.obj(name)
    c, body = ctx.world.c, target.body_ids[0]
    if target.shape == "drawer_cabinet":
        spot = drawer_drop_point(c, body, target.size)
        # hand yaw along the drawer's front (a long object ends across the drawer's opening, where it fits)
        yield from _release_at(ctx, spot[:2], spot[2], _wrap(yaw_of_body(c, body), math.pi), drop=0.015)
    else:
        p, _ = pose(ctx.world, target)
        floor = p[2] + (WALL if target.shape == "bin" else 0.004)
        yield from _release_at(ctx, p[:2], floor, drop=0.015)


def _goal_target(ctx: Context, name: str, goal_type: str) -> SimObject | None:
    for g in ctx.inst.spec.goals:
        if g.type == goal_type and name in g.what and g.where:
            return ctx.obj(g.where[0])
    return None


def push(ctx: Context, name: str):
    obj = ctx.obj(name)
    zone = _goal_target(ctx, name, "in_zone")
    if zone is None:
        raise ValueError(f"task {ctx.inst.spec.name}: push {name} needs an in_zone goal naming {name}")
    for _ in range(RETRIES + 1):
        p, _ = pose(ctx.world, obj)
        zp, _ = pose(ctx.world, zone)
        if in_zone(ctx.world, p, zone, margin=0.01):
            return
        d = zp[:2] - p[:2]
        u = d / max(np.linalg.norm(d), 1e-6)
        reach = 0.5 * math.hypot(*obj.size[:2]) + 0.02
        start, end = p[:2] - u * (reach + 0.03), zp[:2] - u * (reach - 0.01)
        z = TABLE_Z + FINGER_BELOW + 0.008
        yaw = _wrap(math.atan2(u[1], u[0]) + math.pi / 2, math.pi)  # fingers side by side across the push
        yield from ctx.gripper(True, 1)
        yield from ctx.move([ctx.pos[0], ctx.pos[1], CARRY_Z])
        yield from ctx.move([start[0], start[1], CARRY_Z], yaw)
        yield from ctx.move([start[0], start[1], z])
        yield from ctx.move([end[0], end[1], z], step=0.025)
        yield from ctx.move([end[0] - 0.03 * u[0], end[1] - 0.03 * u[1], z])  # back off before lifting
        yield from ctx.move([ctx.pos[0], ctx.pos[1], CARRY_Z])


def _drawer_target(ctx: Context, name: str, opening: bool) -> float:
    """Where open_drawer (close_drawer) takes the drawer: the middle of the drawer's joint_range goal when that
    goal is an open (closed) one, else all the way (a plan may open a drawer that its goal wants closed)."""
    for g in ctx.inst.spec.goals:
        if g.type == "joint_range" and g.what[0] == name and (g.range[0] >= 0.5 if opening else g.range[1] <= 0.5):
            return (g.range[0] + g.range[1]) / 2
    return 1.0 if opening else 0.0


def _slide_drawer(ctx: Context, name: str, fraction: float):
    from simeval.sim.core.articulated import joint_limits
    from simeval.sim.core.fixtures import handle_point, yaw_of_body

    drawer = ctx.obj(name)
    c, body = ctx.world.c, drawer.body_ids[0]
    yaw = yaw_of_body(c, body)
    out = np.array([-math.cos(yaw), -math.sin(yaw)])  # the drawer slides out along the cabinet's local -x
    for _ in range(RETRIES + 1):
        lo, hi = joint_limits(c, body, 0)
        q = c.getJointState(body, 0)[0]
        delta = lo + fraction * (hi - lo) - q
        if abs(delta) < 0.1 * (hi - lo):
            return
        h = handle_point(c, body, drawer.size)
        yield from ctx.gripper(False, 1)
        yield from ctx.move([ctx.pos[0], ctx.pos[1], CARRY_Z])
        yield from ctx.move([h[0], h[1], CARRY_Z], _wrap(yaw, math.pi))
        yield from ctx.move([h[0], h[1], h[2] + 0.04])
        yield from ctx.move(h, step=SLOW_M)
        yield from ctx.gripper(True)
        end = h[:2] + out * delta
        yield from ctx.move([end[0], end[1], h[2]], step=0.03)
        yield from ctx.gripper(False)
        yield from ctx.move([end[0], end[1], CARRY_Z])


def open_drawer(ctx: Context, name: str):
    yield from _slide_drawer(ctx, name, _drawer_target(ctx, name, True))


def close_drawer(ctx: Context, name: str):
    yield from _slide_drawer(ctx, name, _drawer_target(ctx, name, False))


def press(ctx: Context, name: str):
    from simeval.sim.core.fixtures import BUTTON_TRAVEL

    button = ctx.obj(name)
    p, _ = pose(ctx.world, button)
    top = p[2] + button.size[2] + 0.02  # housing plus cap
    yield from ctx.gripper(True, 1)
    yield from ctx.move([ctx.pos[0], ctx.pos[1], CARRY_Z])
    yield from ctx.move([p[0], p[1], CARRY_Z])
    yield from ctx.move([p[0], p[1], top + FINGER_BELOW + 0.03])
    yield from ctx.move([p[0], p[1], top + FINGER_BELOW - BUTTON_TRAVEL - 0.004], step=0.01)
    yield from ctx.move([p[0], p[1], CARRY_Z])


PRIMITIVES = {"pick": pick, "place_on": place_on, "place_at": place_at, "place_in": place_in, "push": push,
              "open_drawer": open_drawer, "close_drawer": close_drawer, "press": press}


class PlanPolicy:
    """A task's plan (spec.plan) as a policy for action_space="ee_pose": each call returns the next 8-d target
    of the running primitive (computed from the current state); None when the plan is done."""

    def reset(self, env) -> None:
        from simeval.errors import UserError

        if env.mode != "ee_pose":
            raise UserError(f"the plan policy acts through action_space='ee_pose', not {env.mode!r}")
        if not env.spec_task.plan:
            raise UserError(f"task {env.spec_task.name} has no `plan` for the ee_pose oracle")
        self.ctx = Context(env)
        self.plan_step: list[int] = []  # the control step where each primitive starts
        self._steps = 0
        self._gen = self._run()

    def _run(self):
        for prim, name in self.ctx.inst.spec.plan:
            self.plan_step.append(self._steps)
            yield from PRIMITIVES[prim](self.ctx, name)
        # the plan is done: hold still while what was let go of comes to rest (a goal counts only objects at
        # rest); the environment ends the episode at the first step the goals are met
        for _ in range(SETTLE_STEPS):
            yield self.ctx.action()

    def __call__(self, obs) -> np.ndarray | None:
        try:
            action = next(self._gen)
        except StopIteration:
            return None
        self._steps += 1
        return action
