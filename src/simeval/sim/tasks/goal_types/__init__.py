"""Goal types: one file per type in this package, each defining `GOAL = GoalKind(...)`; `goal_kinds()` finds them.
A task spec's goal names its type (`type: in_zone`), and everything that depends on the type comes from its file:
which extra fields the spec may give, when a unit of the goal is done, its progress, and the generic oracle's next
primitive towards it (simeval.sim.experts.pick_place). The checks shared by several types (what the robot holds, the
one-to-one assignment of `each`) are in simeval.sim.tasks.goals."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class GoalKind:
    """One goal type.

    units     (world, instance, goal, held bodies) -> [done] per unit of the goal (an object placed, a pair stacked)
    progress  (world, instance, goal) -> its progress in [0, 1]; None: the share of its units done
    fields    (the spec's goal mapping, its what, its where, {name: ObjectSpec} of the task, where-for-messages)
              -> extra GoalSpec fields ({"range": ..., "joint": ...}; a new type's own values under "params"),
              raising SpecError on a bad value; None: no fields of its own
    plan      (world, instance, goal, unit status) -> the generic oracle's next primitive (PickPlace or Push of
              simeval.sim.experts.pick_place) or None where it has none to give; None: the generic oracle cannot
              reach this type (a suite's own expert must)
    each      whether the spec's `each: true` (one `what` per `where` instance) applies"""

    name: str
    units: Callable[[Any, Any, Any, set], list[bool]]
    progress: Callable[[Any, Any, Any], float] | None = None
    fields: Callable[[dict, list, list, dict, str], dict] | None = None
    plan: Callable[[Any, Any, Any, list], Any] | None = None
    each: bool = False


@functools.cache
def goal_kinds() -> dict[str, GoalKind]:
    """{name: GoalKind} of every module of this package that defines GOAL."""
    import sys

    from simeval.sim.registry import modules_defining

    return modules_defining(sys.modules[__name__], "GOAL", GoalKind)


def goal_kind(name: str) -> GoalKind:
    kinds = goal_kinds()
    if name not in kinds:
        raise ValueError(f"unknown goal type {name!r}; known: {', '.join(sorted(kinds))}")
    return kinds[name]
