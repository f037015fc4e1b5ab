"""on_objects: each `what` object (a deck) resting on top of all the `where` objects (its supports), centred
between them and touching each."""

from __future__ import annotations

import math

import numpy as np

from simeval.sim.core.geometry import STACK_Z_TOL, height, placed, pose, touching
from simeval.sim.tasks.goal_types import GoalKind


def _supports(world, inst, goal):
    supports = [o for n in goal.where for o in inst.by_name(n)]
    sp = [pose(world, s)[0] for s in supports]
    top = max(p[2] + height(s) / 2 for p, s in zip(sp, supports))
    return supports, sp, top, np.mean([p[:2] for p in sp], axis=0)


def units(world, inst, goal, held) -> list[bool]:
    supports, _, top, centre = _supports(world, inst, goal)
    out = []
    for deck in (o for n in goal.what for o in inst.by_name(n)):
        pd, _ = pose(world, deck)
        on = abs(pd[2] - height(deck) / 2 - top) < STACK_Z_TOL and np.linalg.norm(pd[:2] - centre) < 0.03
        on = on and placed(world, deck, held) and all(touching(world, deck, s) for s in supports)
        out.append(bool(on))
    return out


def plan(world, inst, goal, status):
    from simeval.sim.experts.pick_place import PickPlace

    _, sp, top, centre = _supports(world, inst, goal)
    span = sp[-1][:2] - sp[0][:2]
    deck = [o for n in goal.what for o in inst.by_name(n)][status.index(False)]
    return PickPlace(deck, centre, top, math.atan2(span[1], span[0]))


GOAL = GoalKind("on_objects", units, plan=plan)
