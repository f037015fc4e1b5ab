"""A generic oracle: goals -> the next primitive (pick-and-place with suction, or a push with the spatula),
replanned after every primitive from the live state, so a slipped block is simply picked again."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simeval.sim.goals import height, in_zone, offset_target, pose, stack_chain, unit_status
from simeval.sim.objects import SimObject
from simeval.sim.robot import Arm
from simeval.sim.spec import Instance
from simeval.sim.world import TABLE_Z, World

SAFE_Z = 0.16


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

    def pose14(self, world: World) -> np.ndarray:
        p, yaw = pose(world, self.obj)
        q0 = world.c.getQuaternionFromEuler([0, 0, yaw])
        q1 = world.c.getQuaternionFromEuler([0, 0, self.target_yaw])
        return np.r_[p, q0, self.place_xy, self.place_bottom_z, q1].astype(np.float32)

    def execute(self, arm: Arm, world: World) -> bool:
        p, yaw = pose(world, self.obj)
        sym = symmetry(self.obj)
        pick_yaw = 0.0 if sym > math.pi else _wrap(yaw, sym)
        top = p[2] + height(self.obj) / 2
        arm.move(np.r_[p[:2], SAFE_Z], pick_yaw, speed=0.6)
        arm.move(np.r_[p[:2], top + 0.03], pick_yaw, speed=0.3)
        arm.move(np.r_[p[:2], top - 0.02], pick_yaw, speed=0.08, stop_on_contact=True)
        if not arm.suction_on():
            arm.move(np.r_[p[:2], SAFE_Z], pick_yaw)
            return False
        arm.move(np.r_[p[:2], SAFE_Z], pick_yaw, speed=0.3)
        # the held object turns with the tool: choose the place yaw that lands it at the target yaw
        place_yaw = pick_yaw if sym > math.pi else pick_yaw + _wrap(self.target_yaw - yaw, sym)
        tip_z = self.place_bottom_z + height(self.obj) + 0.006
        arm.move(np.r_[self.place_xy, SAFE_Z], place_yaw, speed=0.6)
        arm.move(np.r_[self.place_xy, tip_z + 0.03], place_yaw, speed=0.3)
        arm.move(np.r_[self.place_xy, tip_z], place_yaw, speed=0.08)
        arm.suction_off()
        arm.hold(6)
        arm.move(np.r_[self.place_xy, SAFE_Z], place_yaw, speed=0.3)
        return True


@dataclass
class Push:
    start: np.ndarray  # xy
    end: np.ndarray

    def pose14(self, world: World) -> np.ndarray:
        yaw = self.yaw
        q = world.c.getQuaternionFromEuler([0, 0, yaw])
        return np.r_[self.start, TABLE_Z, q, self.end, TABLE_Z, q].astype(np.float32)

    @property
    def yaw(self) -> float:
        d = self.end - self.start
        return _wrap(math.atan2(d[1], d[0]), math.pi)  # the blade is symmetric: push with either face

    def execute(self, arm: Arm, world: World) -> bool:
        z = TABLE_Z + 0.004
        arm.move(np.r_[self.start, SAFE_Z], self.yaw, speed=0.6)
        arm.move(np.r_[self.start, z], self.yaw, speed=0.3)
        arm.move(np.r_[self.end, z], self.yaw, speed=0.15)
        arm.move(np.r_[self.end, SAFE_Z], self.yaw, speed=0.4)
        return True


def _slot(zone_xy: np.ndarray, zone_yaw: float, k: int, obj: SimObject, zone: SimObject) -> np.ndarray:
    """The k-th free spot in a zone: a small grid so several objects fit side by side."""
    per_row = max(1, int(zone.size[0] // (obj.footprint * 2 + 0.01)))
    rows = max(1, int(zone.size[1] // (obj.footprint * 2 + 0.01)))
    if per_row * rows == 1:
        return zone_xy
    i, j = k % per_row, (k // per_row) % rows
    dx = (i - (per_row - 1) / 2) * zone.size[0] / per_row
    dy = (j - (rows - 1) / 2) * zone.size[1] / rows
    return offset_target(np.r_[zone_xy, 0.0], zone_yaw, [dx, dy])


def next_primitive(world: World, inst: Instance, held_out: set | None = None):
    """The first undone unit of the first unfinished goal, as a primitive; None when every goal is done."""
    for goal in inst.spec.goals:
        status = unit_status(world, inst, goal)
        if all(status):
            continue
        if goal.type in ("in_zone", "in_container"):
            targets = [o for n in goal.where for o in inst.by_name(n)]
            movers = [o for n in goal.what for o in inst.by_name(n)]
            done = [o for o, ok in zip(movers, status) if ok]
            obj = next(o for o, ok in zip(movers, status) if not ok)
            load = {t.id: sum(in_zone(world, pose(world, d)[0], t) if goal.type == "in_zone" else
                              np.linalg.norm(pose(world, d)[0][:2] - pose(world, t)[0][:2]) < t.size[0] / 2
                              for d in done) for t in targets}
            target = min(targets, key=lambda t: load[t.id])
            tp, tyaw = pose(world, target)
            if goal.type == "in_zone":
                xy = _slot(tp[:2], tyaw, load[target.id], obj, target)
                return PickPlace(obj, xy, TABLE_Z, tyaw)
            jitter = 0.02 * load[target.id] * np.array([math.cos(2.1 * load[target.id]), math.sin(2.1 * load[target.id])])
            return PickPlace(obj, tp[:2] + jitter, TABLE_Z + 0.02, 0.0)
        if goal.type == "stack":
            chain = stack_chain(inst, goal)
            k = status.index(False)
            below, above = chain[k], chain[k + 1]
            pb, yb = pose(world, below)
            return PickPlace(above, pb[:2], pb[2] + height(below) / 2, yb)
        if goal.type == "on_objects":
            supports = [o for n in goal.where for o in inst.by_name(n)]
            sp = [pose(world, s)[0] for s in supports]
            top = max(p[2] + height(s) / 2 for p, s in zip(sp, supports))
            centre = np.mean([p[:2] for p in sp], axis=0)
            span = sp[-1][:2] - sp[0][:2]
            deck = [o for n in goal.what for o in inst.by_name(n)][status.index(False)]
            return PickPlace(deck, centre, top, math.atan2(span[1], span[0]))
        if goal.type == "at_offset":
            anchor = inst.by_name(goal.where[0])[0]
            ap, ayaw = pose(world, anchor)
            movers = [o for n in goal.what for o in inst.by_name(n)]
            i = status.index(False)
            return PickPlace(movers[i], offset_target(ap, ayaw, goal.offset[i % len(goal.offset)]), TABLE_Z, ayaw)
        if goal.type == "pile_in_zone":
            zone = inst.by_name(goal.where[0])[0]
            zp, _ = pose(world, zone)
            piles = [o for n in goal.what for o in inst.by_name(n)]
            pile = piles[status.index(False)]
            outside = np.array([pose(world, pile, k)[0][:2] for k in range(len(pile.body_ids))
                                if not in_zone(world, pose(world, pile, k)[0], zone, margin=0.01)])
            if len(outside) == 0:
                continue
            far = outside[np.argmax(np.linalg.norm(outside - zp[:2], axis=1))]
            cluster = outside[np.linalg.norm(outside - far, axis=1) < 0.07].mean(axis=0)
            d = zp[:2] - cluster
            d /= max(np.linalg.norm(d), 1e-6)
            return Push(cluster - 0.05 * d, zp[:2] - 0.01 * d)
    return None
