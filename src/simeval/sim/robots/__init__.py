"""The robots the suites drive: xarm (the xArm6 of the GenSim- and RoboGen-style suites: joint control, a suction
cup or a spatula) and panda (the Franka Panda of the BBSEA-style suite). Both act in a core.world.World and meet
`Robot`, what the environment (simeval.sim.env) asks of either; their action-space-specific primitives (the
xArm's pick_place / push / ik_pose, the Panda's end-effector targets) are called only where the task's robot is
known."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

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
