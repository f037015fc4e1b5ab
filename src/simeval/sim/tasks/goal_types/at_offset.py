"""at_offset: the i-th `what` object resting at the i-th `offset` (metres, in the frame of the one `where` anchor:
its position and yaw), within XY_TOL (`upright`: standing). A spec gives one offset per instance."""

from __future__ import annotations

import numpy as np

from simeval.sim.core.geometry import XY_TOL, offset_target, placed, pose, resting, upright
from simeval.sim.core.world import TABLE_Z
from simeval.sim.tasks.goal_types import GoalKind


def units(world, inst, goal, held) -> list[bool]:
    anchor = inst.by_name(goal.where[0])[0]
    ap, ayaw = pose(world, anchor)
    out = []
    for i, obj in enumerate(o for n in goal.what for o in inst.by_name(n)):
        target = offset_target(ap, ayaw, goal.offset[i % len(goal.offset)])
        p, _ = pose(world, obj)
        ok = np.linalg.norm(p[:2] - target) < XY_TOL and resting(world, obj) and placed(world, obj, held)
        out.append(bool(ok and (not goal.upright or upright(world, obj))))
    return out


def plan(world, inst, goal, status):
    from simeval.sim.experts.pick_place import PickPlace

    anchor = inst.by_name(goal.where[0])[0]
    ap, ayaw = pose(world, anchor)
    movers = [o for n in goal.what for o in inst.by_name(n)]
    i = status.index(False)
    return PickPlace(movers[i], offset_target(ap, ayaw, goal.offset[i % len(goal.offset)]), TABLE_Z, ayaw)


GOAL = GoalKind("at_offset", units, plan=plan)
