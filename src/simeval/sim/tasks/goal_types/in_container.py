"""in_container: each `what` object inside one of the `where` bowls, measured from the bowl's real wall (with
`each`: one per bowl)."""

from __future__ import annotations

from simeval.sim.core.geometry import in_bowl, in_container
from simeval.sim.core.world import TABLE_Z
from simeval.sim.tasks.goal_types import GoalKind
from simeval.sim.tasks.goal_types.in_zone import container_plan, container_units


def place_in_bowl(world, inst, obj, bowl, k):
    from simeval.sim.experts.pick_place import PickPlace, bowl_spot

    others = tuple(b for o in inst.objects if o.shape != "pile" for b in o.body_ids)
    return PickPlace(obj, bowl_spot(world, inst, bowl, obj), TABLE_Z + 0.008, 0.0, others)


GOAL = GoalKind("in_container", container_units(in_container),
                plan=container_plan(in_container, in_bowl, place_in_bowl), each=True)
