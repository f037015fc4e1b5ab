"""Goal checks on the live simulation: each goal gives a progress in [0, 1] (the share of its units done);
the task's partial reward is the mean over goals and success is every goal done."""

from __future__ import annotations

import math

import numpy as np

from simeval.sim.objects import SimObject
from simeval.sim.spec import GoalSpec, Instance
from simeval.sim.world import TABLE_Z, World, yaw_of

XY_TOL = 0.02  # an object counts at a target when its centre is within this of it (or inside a zone)


def pose(world: World, obj: SimObject, k: int = 0) -> tuple[np.ndarray, float]:
    p, q = world.c.getBasePositionAndOrientation(obj.body_ids[k])
    return np.asarray(p), yaw_of(q)


def height(obj: SimObject) -> float:
    return obj.size[0] if obj.shape == "sphere" else obj.size[2]


def resting(world: World, obj: SimObject, floor: float = TABLE_Z, tol: float = 0.015) -> bool:
    """Near the surface below it (not held in the air) and almost still."""
    p, _ = pose(world, obj)
    v = np.linalg.norm(world.c.getBaseVelocity(obj.body_ids[0])[0])
    return p[2] - height(obj) / 2 < floor + tol and v < 0.05


def in_zone(world: World, xy: np.ndarray, zone: SimObject, margin: float = 0.0) -> bool:
    zp, zyaw = pose(world, zone)
    d = xy[:2] - zp[:2]
    local = np.array([d[0] * math.cos(-zyaw) - d[1] * math.sin(-zyaw), d[0] * math.sin(-zyaw) + d[1] * math.cos(-zyaw)])
    return bool(np.all(np.abs(local) <= np.array(zone.size[:2]) / 2 - margin))


def stack_chain(inst: Instance, goal: GoalSpec) -> list[SimObject]:
    return [o for name in goal.what for o in inst.by_name(name)]


def unit_status(world: World, inst: Instance, goal: GoalSpec) -> list[bool]:
    """Per unit of the goal: done or not."""
    if goal.type in ("in_zone", "in_container"):
        targets = [o for n in goal.where for o in inst.by_name(n)]
        out = []
        for obj in (o for n in goal.what for o in inst.by_name(n)):
            p, _ = pose(world, obj)
            if goal.type == "in_zone":
                ok = any(in_zone(world, p, z) for z in targets) and resting(world, obj)
            else:
                ok = any(np.linalg.norm(p[:2] - pose(world, t)[0][:2]) < 0.8 * t.size[0] / 2 - 0.01
                         and p[2] < TABLE_Z + t.size[2] + height(obj) for t in targets)
            out.append(bool(ok))
        return out
    if goal.type == "stack":
        chain = stack_chain(inst, goal)
        out = []
        for below, above in zip(chain, chain[1:]):
            pb, _ = pose(world, below)
            pa, _ = pose(world, above)
            z_ok = abs(pa[2] - (pb[2] + (height(below) + height(above)) / 2)) < 0.015
            out.append(bool(np.linalg.norm(pa[:2] - pb[:2]) < min(below.size[:2]) / 2 and z_ok))
        return out
    if goal.type == "on_objects":
        supports = [o for n in goal.where for o in inst.by_name(n)]
        out = []
        for deck in (o for n in goal.what for o in inst.by_name(n)):
            pd, _ = pose(world, deck)
            sp = [pose(world, s)[0] for s in supports]
            top = max(p[2] + height(s) / 2 for p, s in zip(sp, supports))
            centre = np.mean([p[:2] for p in sp], axis=0)
            on = abs(pd[2] - height(deck) / 2 - top) < 0.015 and np.linalg.norm(pd[:2] - centre) < 0.03
            out.append(bool(on))
        return out
    if goal.type == "at_offset":
        anchor = inst.by_name(goal.where[0])[0]
        ap, ayaw = pose(world, anchor)
        out = []
        for i, obj in enumerate(o for n in goal.what for o in inst.by_name(n)):
            target = offset_target(ap, ayaw, goal.offset[i % len(goal.offset)])
            p, _ = pose(world, obj)
            out.append(bool(np.linalg.norm(p[:2] - target) < XY_TOL and resting(world, obj)))
        return out
    if goal.type == "pile_in_zone":
        zones = [o for n in goal.where for o in inst.by_name(n)]
        out = []
        for pile in (o for n in goal.what for o in inst.by_name(n)):
            inside = sum(any(in_zone(world, pose(world, pile, k)[0], z) for z in zones) for k in range(len(pile.body_ids)))
            out.append(inside / len(pile.body_ids) >= goal.fraction)
        return out
    raise ValueError(f"unknown goal type {goal.type}")


def offset_target(anchor_pos: np.ndarray, anchor_yaw: float, offset: list[float]) -> np.ndarray:
    dx, dy = offset[0], offset[1]
    c, s = math.cos(anchor_yaw), math.sin(anchor_yaw)
    return anchor_pos[:2] + np.array([c * dx - s * dy, s * dx + c * dy])


def goal_progress(world: World, inst: Instance, goal: GoalSpec) -> float:
    if goal.type == "pile_in_zone":  # partial credit per particle, as GenSim's pile rewards
        zones = [o for n in goal.where for o in inst.by_name(n)]
        fracs = []
        for pile in (o for n in goal.what for o in inst.by_name(n)):
            inside = sum(any(in_zone(world, pose(world, pile, k)[0], z) for z in zones) for k in range(len(pile.body_ids)))
            fracs.append(min(1.0, inside / len(pile.body_ids) / goal.fraction))
        return float(np.mean(fracs)) if fracs else 1.0
    units = unit_status(world, inst, goal)
    return float(np.mean(units)) if units else 1.0


def task_progress(world: World, inst: Instance) -> tuple[float, bool]:
    progress = [goal_progress(world, inst, g) for g in inst.spec.goals]
    return float(np.mean(progress)), all(p >= 1.0 for p in progress)
