"""A generic oracle: goals -> the next primitive (pick-and-place with suction, or a push with the spatula),
replanned after every primitive from the live state, so a slipped block is simply picked again."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simeval.sim.core.geometry import height, offset_target, pose, still
from simeval.sim.core.objects import BOWL_WALL, SimObject
from simeval.sim.core.world import TABLE_Z, WORKSPACE, World
from simeval.sim.robots.xarm import SAFE_Z, Arm  # noqa: F401 (SAFE_Z: re-exported)
from simeval.sim.tasks.goal_types import goal_kind
from simeval.sim.tasks.goals import unit_status
from simeval.sim.tasks.spec import Instance


def _wrap(yaw: float, period: float) -> float:
    return (yaw + period / 2) % period - period / 2


def symmetry(obj: SimObject) -> float:
    if obj.shape in ("sphere", "cylinder", "bowl", "pile"):
        return 2 * math.pi  # any yaw: keep the tool straight
    return math.pi / 2 if abs(obj.size[0] - obj.size[1]) < 1e-6 else math.pi


@dataclass
class PickPlace:
    obj: SimObject
    place_xy: np.ndarray
    place_bottom_z: float  # where the object's bottom should end up
    target_yaw: float
    settle_bodies: tuple[int, ...] = ()  # waited for after the place (default: the object itself)

    def pose14(self, world: World) -> np.ndarray:
        """The 14-d action (Ravens' convention, simeval.sim.env): the tool at the pick point (the top centre of
        the object, tool yaw aligned with it) and at the place point (where that point lands when the object is
        at its target pose: the target centre plus half the object's height; tool yaw that turns it to the
        target yaw)."""
        p, yaw = pose(world, self.obj)
        sym = symmetry(self.obj)
        pick_yaw = 0.0 if sym > math.pi else _wrap(yaw, sym)
        # the held object turns with the tool: choose the place yaw that lands it at the target yaw
        place_yaw = pick_yaw if sym > math.pi else pick_yaw + _wrap(self.target_yaw - yaw, sym)
        q0 = world.c.getQuaternionFromEuler([0, 0, pick_yaw])
        q1 = world.c.getQuaternionFromEuler([0, 0, place_yaw])
        top = p[2] + height(self.obj) / 2
        return np.r_[p[:2], top, q0, self.place_xy, self.place_bottom_z + height(self.obj), q1].astype(np.float32)

    def execute(self, arm: Arm, world: World) -> bool:
        """The primitive as the environment runs it (Arm.pick_place of the 14-d pose), then a wait until the
        moved bodies rest (make_env waits for every object instead)."""
        picked = arm.pick_place(self.pose14(world))
        wait_still(arm, world, self.settle_bodies or self.obj.body_ids, max_steps=60)
        return picked


def wait_still(arm: Arm, world: World, bodies: list[int], max_steps: int = 30) -> None:
    """Hold until the moved bodies are at rest, so the next plan sees settled objects (a goal counts only
    objects at rest, and a rolling ball is not to be picked again)."""
    for _ in range(max_steps):
        if all(still(world, b) for b in bodies):
            return
        arm.hold(1)


@dataclass
class Push:
    start: np.ndarray  # xy
    end: np.ndarray
    bodies: tuple[int, ...] = ()  # the particles it moves (waited for after the push)

    def pose14(self, world: World) -> np.ndarray:
        yaw = self.yaw
        q = world.c.getQuaternionFromEuler([0, 0, yaw])
        return np.r_[self.start, TABLE_Z, q, self.end, TABLE_Z, q].astype(np.float32)

    @property
    def yaw(self) -> float:
        d = self.end - self.start
        return _wrap(math.atan2(d[1], d[0]), math.pi)  # the blade is symmetric: push with either face

    def execute(self, arm: Arm, world: World) -> bool:
        arm.push(self.pose14(world))
        wait_still(arm, world, self.bodies, max_steps=20)
        return True


def zone_slot(zone_xy: np.ndarray, zone_yaw: float, k: int, obj: SimObject, zone: SimObject) -> np.ndarray:
    """The k-th free spot in a zone: a small grid so several objects fit side by side."""
    per_row = max(1, int(zone.size[0] // (obj.footprint * 2 + 0.01)))
    rows = max(1, int(zone.size[1] // (obj.footprint * 2 + 0.01)))
    if per_row * rows == 1:
        return zone_xy
    i, j = k % per_row, (k // per_row) % rows
    dx = (i - (per_row - 1) / 2) * zone.size[0] / per_row
    dy = (j - (rows - 1) / 2) * zone.size[1] / rows
    return offset_target(np.r_[zone_xy, 0.0], zone_yaw, [dx, dy])


def plan_push(zone_xy: np.ndarray, outside: np.ndarray, bodies: tuple[int, ...]) -> Push:
    """Sweep the lane of particles behind the one farthest from the zone: start just behind it (pulled into
    the reachable workspace, where the blade still reaches the table) and stop 2.5 cm short of the zone's
    centre, so the particles the 10 cm blade drives ahead of it end inside the zone, not past it."""
    far = outside[np.argmax(np.linalg.norm(outside - zone_xy, axis=1))]
    d = zone_xy - far
    d /= max(np.linalg.norm(d), 1e-6)
    start = far - 0.025 * d
    (x0, x1), (y0, y1) = WORKSPACE
    for _ in range(20):  # step along the push until the start is reachable
        if x0 - 0.01 <= start[0] <= x1 + 0.01 and y0 - 0.01 <= start[1] <= y1 + 0.01:
            break
        start = start + 0.01 * d
    return Push(start, zone_xy - 0.025 * d, bodies)


def bowl_spot(world: World, inst: Instance, bowl: SimObject, obj: SimObject) -> np.ndarray:
    """Where to drop `obj` in the bowl: of 12 spots on a ring inside the wall, the one farthest from what is
    already in the bowl, so a second object does not land on the first and knock it over."""
    bp, _ = pose(world, bowl)
    inner = bowl.size[0] / 2 - BOWL_WALL
    ring = inner - obj.footprint - 0.004
    if ring <= 0.005:
        return bp[:2]
    spots = [bp[:2] + ring * np.array([math.cos(a), math.sin(a)]) for a in np.linspace(0, 2 * math.pi, 12, endpoint=False)]
    there = [pose(world, o)[0][:2] for o in inst.objects if o is not obj and o.shape not in ("pile", "bowl", "zone", "line")
             and np.linalg.norm(pose(world, o)[0][:2] - bp[:2]) < inner]
    if not there:
        return spots[0]
    return max(spots, key=lambda xy: min(np.linalg.norm(xy - t) for t in there))


def next_primitive(world: World, inst: Instance, held_out: set | None = None):
    """The first undone unit of the first unfinished goal, as a primitive (its goal type's `plan`,
    simeval.sim.tasks.goal_types); None when every goal is done or no type's plan reaches the rest."""
    for goal in inst.spec.goals:
        status = unit_status(world, inst, goal)
        if all(status):
            continue
        plan = goal_kind(goal.type).plan
        primitive = plan(world, inst, goal, status) if plan is not None else None
        if primitive is not None:
            return primitive
    return None
