"""in_zone: each `what` object resting flat inside one of the `where` zones (with `each`: one per zone)."""

from __future__ import annotations

from simeval.sim.core.geometry import height, in_zone, pose
from simeval.sim.core.world import TABLE_Z
from simeval.sim.tasks.goal_types import GoalKind
from simeval.sim.tasks.goals import container_assignment


def inside(world, obj, zone) -> bool:
    """On the table (not on another object) within the zone's rectangle."""
    p, _ = pose(world, obj)
    return p[2] - height(obj) / 2 < TABLE_Z + 0.015 and in_zone(world, p, zone)


def container_units(inside_fn):
    def units(world, inst, goal, held) -> list[bool]:
        _, _, assigned = container_assignment(world, inst, goal, inside_fn, held)
        return [a is not None for a in assigned]

    return units


def container_plan(inside_fn, within, place):
    """The generic oracle's next pick-and-place towards an in_zone / in_container goal: an undone object (one
    already `within` a target, e.g. one of two balls in one zone, moves last) to the target the fewest count for
    (with `each`: one nothing counts for yet); place(world, inst, obj, target, k) -> the PickPlace, k the objects
    that count for that target already."""
    def plan(world, inst, goal, status):
        movers, targets, assigned = container_assignment(world, inst, goal, inside_fn)
        undone = [o for o, a in zip(movers, assigned) if a is None]
        obj = min(undone, key=lambda o: any(within(world, o, t) for t in targets))
        load = {t.id: sum(a == j for a in assigned) for j, t in enumerate(targets)}
        target = min(targets, key=lambda t: load[t.id])
        return place(world, inst, obj, target, load[target.id])

    return plan


def place_in_zone(world, inst, obj, zone, k):
    from simeval.sim.experts.pick_place import PickPlace, zone_slot

    tp, tyaw = pose(world, zone)
    return PickPlace(obj, zone_slot(tp[:2], tyaw, k, obj, zone), TABLE_Z, tyaw)


def within_zone(world, obj, zone) -> bool:
    return in_zone(world, pose(world, obj)[0], zone)


GOAL = GoalKind("in_zone", container_units(inside), plan=container_plan(inside, within_zone, place_in_zone),
                each=True)
