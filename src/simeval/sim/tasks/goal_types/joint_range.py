"""joint_range: the one `what` articulated object's joint `joint` (an index of its non-fixed joints) at a fraction
of its limits within `range: [lo, hi]`; progress is the share of the way from its initial fraction towards the
range. The joint holds by friction, so where the arm leaves it is where it stays."""

from __future__ import annotations

import numpy as np

from simeval.sim.tasks.goal_types import GoalKind


def joint_range_progress(world, inst, goal, obj) -> float:
    """1 when the joint's fraction of its limits is within the goal's range; otherwise how far it has moved from
    its initial fraction towards the range (the share of the way), clipped to [0, 1]."""
    from simeval.sim.core.articulated import joint_fraction

    lo, hi = goal.range
    f = joint_fraction(world.c, obj.body_ids[0], goal.joint)
    if lo - 1e-9 <= f <= hi + 1e-9:
        return 1.0
    f0 = inst.joints[obj.id][goal.joint]
    edge = lo if f0 < lo else hi
    if abs(edge - f0) < 1e-9:
        return 0.0
    return float(np.clip((f - f0) / (edge - f0), 0.0, 1.0))


def units(world, inst, goal, held) -> list[bool]:
    return [joint_range_progress(world, inst, goal, obj) >= 1.0 for obj in inst.by_name(goal.what[0])]


def progress(world, inst, goal) -> float:
    objs = inst.by_name(goal.what[0])
    return float(np.mean([joint_range_progress(world, inst, goal, o) for o in objs])) if objs else 1.0


def fields(g: dict, what: list, where: list, objects: dict, w: str) -> dict:
    from simeval.sim.core.objects import SimObject
    from simeval.sim.tasks.spec import JOINTED, SpecError, joint_count

    r, joint = g.get("range"), g.get("joint", 0)
    if not (isinstance(r, (list, tuple)) and len(r) == 2 and all(isinstance(x, (int, float)) for x in r)
            and 0 <= r[0] <= r[1] <= 1):
        raise SpecError(f"{w}: joint_range needs `range: [lo, hi]` with 0 <= lo <= hi <= 1, got {r!r}")
    if len(what) != 1 or where:
        raise SpecError(f"{w}: joint_range names one object in `what` (and no `where`), got what={what}")
    if isinstance(joint, bool) or not isinstance(joint, int) or joint < 0:
        raise SpecError(f"{w}: joint must be a joint index >= 0, got {joint!r}")
    o = objects[what[0]]
    if o.shape not in JOINTED:
        raise SpecError(f"{w}: joint_range needs an articulated object ({', '.join(JOINTED)}), '{o.name}' is a "
                        f"{o.shape}")
    n = joint_count(SimObject(o.name, 0, o.shape, o.colors[0], o.size))
    if joint >= n:
        raise SpecError(f"{w}: joint {joint} does not exist; a {o.shape} has {n} joint(s)")
    return {"range": (float(r[0]), float(r[1])), "joint": joint}


GOAL = GoalKind("joint_range", units, progress, fields)
