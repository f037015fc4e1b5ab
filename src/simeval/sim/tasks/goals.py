"""Goal checks on the live simulation: each goal gives a progress in [0, 1] (the share of its units done, unless
its type says otherwise); the task's partial reward is the mean over goals and success is every goal done. What a
goal type checks is in its own file (simeval.sim.tasks.goal_types); here are the checks several types share.

A unit counts as done only as strictly as the task's text reads: an object still on the suction cup, touched by
the spatula or the arm, or still moving is never placed; "each" goals need a one-to-one assignment; `upright`
goals need the object standing on its base; stacks need the object resting on (in contact with) the one below;
a bowl's inside is measured from its real wall. An articulation (joint_range) counts by its joint's position alone:
the joint holds by friction, so where the arm leaves it is where it stays."""

from __future__ import annotations

import math

import numpy as np

from simeval.sim.core.geometry import placed, pose, radius, still, supported, upright
from simeval.sim.core.objects import SimObject
from simeval.sim.core.world import World
from simeval.sim.tasks.goal_types import goal_kind
from simeval.sim.tasks.spec import GoalSpec, Instance


def held_bodies(world: World, inst: Instance) -> set[int]:
    """Bodies of the instance attached to or touched by the robot (suction constraint, spatula, arm links):
    whatever the robot holds or pushes is not placed yet. The robot is every body that is neither the table
    nor one of the instance's objects, so this needs no handle on the arm."""
    c = world.c
    objs = {b for o in inst.objects for b in o.body_ids}
    robot = {c.getBodyUniqueId(i) for i in range(c.getNumBodies())} - objs - {world.plane}
    out: set[int] = set()
    for i in range(c.getNumConstraints()):
        info = c.getConstraintInfo(c.getConstraintUniqueId(i))
        parent, child = info[0], info[2]
        if parent in robot and child in objs:
            out.add(child)
        if child in robot and parent in objs:
            out.add(parent)
    for r in robot:
        out.update(cp[2] for cp in c.getContactPoints(bodyA=r) if cp[2] in objs)
    return out


def _matching(ok: list[list[bool]]) -> list[int | None]:
    """Maximum one-to-one assignment of rows (objects) to columns (targets) where ok[i][j]; row -> column."""
    match_col: dict[int, int] = {}

    def augment(i: int, seen: set[int]) -> bool:
        for j, good in enumerate(ok[i]):
            if good and j not in seen:
                seen.add(j)
                if j not in match_col or augment(match_col[j], seen):
                    match_col[j] = i
                    return True
        return False

    for i in range(len(ok)):
        augment(i, set())
    row = [None] * len(ok)
    for j, i in match_col.items():
        row[i] = j
    return row


def stack_chain(inst: Instance, goal: GoalSpec) -> list[SimObject]:
    return [o for name in goal.what for o in inst.by_name(name)]


def container_assignment(world: World, inst: Instance, goal: GoalSpec, inside, held: set[int] | None = None):
    """For in_zone / in_container goals: the movers, the targets, and per mover the target it counts for (None if
    it counts for none); inside(world, obj, target) -> bool is the type's test. Without `each` any target will do;
    with `each` it is a maximum one-to-one assignment, so two balls in one zone fill one zone, not two."""
    held = held_bodies(world, inst) if held is None else held
    targets = [o for n in goal.where for o in inst.by_name(n)]
    movers = [o for n in goal.what for o in inst.by_name(n)]
    ok = []
    for obj in movers:
        good = placed(world, obj, held) and (not goal.upright or upright(world, obj))
        ok.append([good and inside(world, obj, t) for t in targets])
    if goal.each:
        return movers, targets, _matching(ok)
    return movers, targets, [next((j for j, g in enumerate(row) if g), None) for row in ok]


def unit_status(world: World, inst: Instance, goal: GoalSpec) -> list[bool]:
    """Per unit of the goal: done or not (its type's `units`)."""
    return goal_kind(goal.type).units(world, inst, goal, held_bodies(world, inst))


def particle_placed(world: World, pile: SimObject, zones: list[SimObject], held: set[int]) -> list[bool]:
    """Per particle: inside a zone, not touched by the spatula and at rest."""
    xy = np.array([world.c.getBasePositionAndOrientation(b)[0][:2] for b in pile.body_ids]).reshape(-1, 2)
    inside = np.zeros(len(xy), bool)
    for z in zones:  # in_zone for every particle at once (the zone's pose read once, not once per particle)
        zp, zyaw = pose(world, z)
        d = xy - zp[:2]
        c, s = math.cos(-zyaw), math.sin(-zyaw)
        local = np.stack([d[:, 0] * c - d[:, 1] * s, d[:, 0] * s + d[:, 1] * c], axis=1)
        inside |= np.all(np.abs(local) <= np.array(z.size[:2]) / 2, axis=1)
    return [bool(b not in held and inside[k] and still(world, b, radius(pile)) and supported(world, b))
            for k, b in enumerate(pile.body_ids)]


def pile_fractions(world: World, inst: Instance, goal: GoalSpec, held: set[int] | None = None) -> list[float]:
    held = held_bodies(world, inst) if held is None else held
    zones = [o for n in goal.where for o in inst.by_name(n)]
    return [float(np.mean(particle_placed(world, pile, zones, held)))
            for pile in (o for n in goal.what for o in inst.by_name(n))]


def goal_progress(world: World, inst: Instance, goal: GoalSpec) -> float:
    kind = goal_kind(goal.type)
    if kind.progress is not None:
        return kind.progress(world, inst, goal)
    units = unit_status(world, inst, goal)
    return float(np.mean(units)) if units else 1.0


def task_progress(world: World, inst: Instance) -> tuple[float, bool]:
    progress = [goal_progress(world, inst, g) for g in inst.spec.goals]
    return float(np.mean(progress)), all(p >= 1.0 for p in progress)
