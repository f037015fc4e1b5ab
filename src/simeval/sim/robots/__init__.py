"""The robots the suites drive: xarm (the xArm6 of the GenSim- and RoboGen-style suites: joint control, a suction
cup or a spatula) and panda (the Franka Panda of the BBSEA-style suite). Both act in a core.world.World and meet
`Robot`, what the environment (simeval.sim.env) asks of either; their action-space-specific primitives (the
xArm's pick_place / push / ik_pose, the Panda's end-effector targets) are called only where the task's robot is
known.

A robot is one file of this package that defines `ROBOT = RobotKind(...)`: its name (a task spec's `robot:`), the
action spaces it takes, its state's names and bounds, and how to build it in a world. `robot_kinds()` finds every
such file; nothing else names a robot."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Robot(Protocol):
    body: int  # the PyBullet body of the arm
    on_step: Callable[[np.ndarray], None] | None  # called with the action after every control step (the recorder)
    held: object  # what it holds (a body, or (body, link)), None when nothing

    @property
    def body_ids(self) -> tuple[int, ...]:
        """Every PyBullet body drawn as the robot (its robot mask)."""

    def state(self) -> np.ndarray:
        """The proprioceptive state stored with each frame (simeval.sim.env's state_names)."""

    def apply(self, action: np.ndarray) -> np.ndarray:
        """One control step of its low-level action; returns the action as applied (replays bit for bit)."""

    def hold(self, steps: int) -> None:
        """Repeat the last target for `steps` control steps, each logged like any other."""

    def park(self, steps: int) -> None:
        """Move out of the cameras' view at the end of an episode, letting go of what it holds."""


@dataclass(frozen=True)
class RobotKind:
    """What the environment needs to know of a robot before it exists: its name (a task spec's `robot:`), the action
    spaces it takes (simeval.sim.action_spaces), its state's names and bounds (the observation space), and `build`:
    (world, task spec, home_noise, rng) -> a Robot in that world."""

    name: str
    action_spaces: tuple[str, ...]
    state_names: tuple[str, ...]
    state_low: np.ndarray
    state_high: np.ndarray
    build: Callable[[Any, Any, float, np.random.Generator], Robot]


@functools.cache
def robot_kinds() -> dict[str, RobotKind]:
    """{name: RobotKind} of every module of this package that defines ROBOT."""
    import sys

    from simeval.sim.registry import modules_defining

    return modules_defining(sys.modules[__name__], "ROBOT", RobotKind)


def robot_kind(name: str) -> RobotKind:
    from simeval.errors import UserError

    kinds = robot_kinds()
    if name not in kinds:
        raise UserError(f"robot {name!r} is not one of {', '.join(sorted(kinds))} (simeval/sim/robots/)")
    return kinds[name]
