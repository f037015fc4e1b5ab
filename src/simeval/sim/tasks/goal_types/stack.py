"""stack: the `what` objects, in order, each resting on and touching the one below it (`upright`: standing)."""

from __future__ import annotations

import numpy as np

from simeval.sim.core.geometry import STACK_Z_TOL, height, placed, pose, touching, upright
from simeval.sim.tasks.goal_types import GoalKind
from simeval.sim.tasks.goals import stack_chain


def units(world, inst, goal, held) -> list[bool]:
    chain = stack_chain(inst, goal)
    out = []
    for below, above in zip(chain, chain[1:]):
        pb, _ = pose(world, below)
        pa, _ = pose(world, above)
        z_ok = abs(pa[2] - (pb[2] + (height(below) + height(above)) / 2)) < STACK_Z_TOL
        xy_ok = np.linalg.norm(pa[:2] - pb[:2]) < min(below.size[:2]) / 2
        ok = z_ok and xy_ok and placed(world, above, held) and touching(world, above, below)
        out.append(bool(ok and (not goal.upright or upright(world, above))))
    return out


def plan(world, inst, goal, status):
    from simeval.sim.experts.pick_place import PickPlace

    chain = stack_chain(inst, goal)
    k = status.index(False)
    below, above = chain[k], chain[k + 1]
    pb, yb = pose(world, below)
    return PickPlace(above, pb[:2], pb[2] + height(below) / 2, yb)


GOAL = GoalKind("stack", units, plan=plan)
