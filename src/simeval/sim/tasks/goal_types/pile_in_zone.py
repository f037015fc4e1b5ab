"""pile_in_zone: at least `fraction` (0.95) of each `what` pile's particles inside the `where` zones, at rest and
untouched by the spatula; progress gives partial credit per particle, as GenSim's pile rewards."""

from __future__ import annotations

import numpy as np

from simeval.sim.core.geometry import in_zone, pose
from simeval.sim.tasks.goal_types import GoalKind
from simeval.sim.tasks.goals import pile_fractions


def units(world, inst, goal, held) -> list[bool]:
    return [f >= goal.fraction - 1e-9 for f in pile_fractions(world, inst, goal, held)]


def progress(world, inst, goal) -> float:
    fracs = [min(1.0, f / goal.fraction) for f in pile_fractions(world, inst, goal)]
    return float(np.mean(fracs)) if fracs else 1.0


def plan(world, inst, goal, status):
    """Push the farthest stray particle of any unfinished pile (one stuck pile does not hold up the others)."""
    from simeval.sim.experts.pick_place import plan_push

    zone = inst.by_name(goal.where[0])[0]
    zp, _ = pose(world, zone)
    piles = [o for o, ok in zip((o for n in goal.what for o in inst.by_name(n)), status) if not ok]
    outside = np.array([pose(world, pile, k)[0][:2] for pile in piles for k in range(len(pile.body_ids))
                        if not in_zone(world, pose(world, pile, k)[0], zone, margin=0.01)])
    if len(outside) == 0:
        return None
    return plan_push(zp[:2], outside, tuple(b for pile in piles for b in pile.body_ids))


GOAL = GoalKind("pile_in_zone", units, progress, plan=plan)
