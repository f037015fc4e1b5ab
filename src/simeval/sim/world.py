"""A PyBullet world per process (DIRECT, its own client): the table, the arm with its end-effector, the
objects of one task instance, cameras, and a fixed-rate control loop that logs every low-level step."""

from __future__ import annotations

import contextlib
import math
import os
import sys
from dataclasses import dataclass

import numpy as np

TABLE_Z = 0.0
WORKSPACE = ((0.30, 0.62), (-0.26, 0.26))  # x, y ranges reachable top-down by the xArm6 at the base origin


@dataclass(frozen=True)
class Camera:
    name: str
    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov: float = 60.0


OBS_CAMERAS = {
    "top": Camera("top", (0.46, 0.0, 0.75), (0.46, 0.0, 0.0), (-1.0, 0.0, 0.0), 45.0),
    "front": Camera("front", (0.95, 0.0, 0.40), (0.40, 0.0, 0.02), (0.0, 0.0, 1.0), 50.0),
}
# 4 fixed views of the initial scene for the scene-alignment judges: front, left, right, top-down.
SCENE_VIEWS = (
    Camera("view_front", (0.90, 0.0, 0.42), (0.42, 0.0, 0.0), fov=50.0),
    Camera("view_left", (0.50, 0.50, 0.40), (0.45, 0.0, 0.0), fov=55.0),
    Camera("view_right", (0.50, -0.50, 0.40), (0.45, 0.0, 0.0), fov=55.0),
    Camera("view_top", (0.46, 0.0, 0.75), (0.46, 0.0, 0.0), (-1.0, 0.0, 0.0), fov=45.0),
)


class World:
    def __init__(self, control_hz: float = 30.0, physics_hz: float = 240.0) -> None:
        import pybullet as p
        import pybullet_data
        from pybullet_utils import bullet_client

        if physics_hz % control_hz:
            raise ValueError(f"physics_hz ({physics_hz}) must be a multiple of control_hz ({control_hz})")
        self.p = p
        with _quiet_stdout():  # the C library prints its argv and build time on every connect
            self.c = bullet_client.BulletClient(connection_mode=p.DIRECT)
        self.c.setAdditionalSearchPath(pybullet_data.getDataPath())
        self.control_hz, self.substeps = control_hz, int(physics_hz // control_hz)
        self.c.setTimeStep(1.0 / physics_hz)
        self.c.setPhysicsEngineParameter(numSolverIterations=50)
        self.c.setGravity(0, 0, -9.81)
        self.plane = self.c.loadURDF("plane.urdf", [0, 0, TABLE_Z - 1e-3])
        self.c.changeVisualShape(self.plane, -1, rgbaColor=[0.72, 0.58, 0.42, 1.0], textureUniqueId=-1)  # a wooden table
        self.c.changeDynamics(self.plane, -1, lateralFriction=0.6)

    def step(self, n: int | None = None) -> None:
        for _ in range(n or self.substeps):
            self.c.stepSimulation()

    def settle(self, steps: int = 120) -> None:
        self.step(steps)

    def render(self, cam: Camera, size: tuple[int, int]) -> np.ndarray:
        h, w = size
        view = self.c.computeViewMatrix(cam.eye, cam.target, cam.up)
        proj = self.c.computeProjectionMatrixFOV(cam.fov, w / h, 0.01, 5.0)
        _, _, rgba, _, _ = self.c.getCameraImage(w, h, view, proj, renderer=self.p.ER_TINY_RENDERER,
                                                 flags=self.p.ER_NO_SEGMENTATION_MASK)
        return np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4)[..., :3]

    def close(self) -> None:
        try:
            self.c.disconnect()
        except Exception:  # already disconnected: nothing left to release
            pass

    def __enter__(self) -> "World":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@contextlib.contextmanager
def _quiet_stdout():
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # no real stdout (e.g. captured): nothing to silence
        yield
        return
    sys.stdout.flush()
    saved = os.dup(fd)
    with open(os.devnull, "w") as devnull:
        os.dup2(devnull.fileno(), fd)
    try:
        yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


def yaw_of(quat) -> float:
    x, y, z, w = quat
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
