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


# The look of Ravens/GenSim scenes: a dark workspace tile (Ravens' ur5/workspace.urdf is rgba 0.2 0.2 0.2) on a
# light floor, lit from one side with shadows (TinyRenderer's shadow map).
FLOOR_RGB = (0.86, 0.86, 0.84)
TILE_RGB = (0.2, 0.2, 0.2)
TILE = ((-0.12, 0.82), (-0.46, 0.46))  # x, y extent of the dark tile: the workspace, the arm's base, a margin
LIGHT_DIRECTION = (0.6, 0.35, 1.0)  # towards the light (from above, a little in front and to the side)
# The solver's early stop for worlds with piles (World's `solver_residual`). 1e-5 measured on sweep-pile-into-zone
# seed 0 (experiments/benchmarks/pile_bench.py): about 2.3x less physics per control step than Bullet's 1e-7, particle
# penetration into the table within 0.3 mm of it and rest drift no larger; 1e-4 was faster still but let
# resting particles creep (0.6 mm per second against 0.3).
PILE_SOLVER_RESIDUAL = 1e-5


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: `fov` is the vertical field of view in degrees (PyBullet's convention; the horizontal
    one follows from the image's aspect ratio)."""
    name: str
    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov: float = 60.0

    def project(self, points, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """World points (N, 3) -> pixel coordinates (N, 2) as (column, row) with (0, 0) the top-left corner of
        the image and (W, H) the bottom-right, and the depth along the optical axis (N,) (negative: behind the
        camera). The same projection as `World.render` (PyBullet's view and projection matrices), in numpy."""
        h, w = size
        eye = np.asarray(self.eye, float)
        f = np.asarray(self.target, float) - eye
        f /= np.linalg.norm(f)
        s = np.cross(f, self.up)
        s /= np.linalg.norm(s)
        u = np.cross(s, f)
        d = np.atleast_2d(np.asarray(points, float)) - eye
        depth = d @ f
        t = math.tan(math.radians(self.fov) / 2)
        x_ndc = (d @ s) / (depth * t * (w / h))
        y_ndc = (d @ u) / (depth * t)
        return np.stack([(x_ndc + 1) / 2 * w, (1 - y_ndc) / 2 * h], axis=1), depth


# GenSim/CLIPort/Ravens record from RealSenseD415.CONFIG's front camera: at (1, 0, 0.75) m, 1 m in front of the
# robot's base, pitched 45 degrees down towards the base (Euler (pi/4, pi, -pi/2): looking along (-1, 0, -1)),
# vertical field of view 2*atan(240/450) = 56.1 degrees (focal length 450 px at 480x640). "front" is that camera:
# same eye, direction and vertical field of view, so the arm is in the upper half of the image and the workspace
# in the lower half, as in GenSim's frames. Our workspace (x 0.30-0.62 m) lies inside Ravens' (0.25-0.75), so every
# object of every task is inside the frame with a margin, square images included (whose horizontal field of view
# is narrower than Ravens' 4:3); tests/test_sim_look.py projects seeds 0-99 of every task.
_GENSIM_PITCH = math.radians(45.0)
_GENSIM_FOV = 2 * math.degrees(math.atan(240 / 450))


def _gensim_front(name: str, eye: tuple[float, float, float]) -> Camera:
    look = (-math.cos(_GENSIM_PITCH), 0.0, -math.sin(_GENSIM_PITCH))
    return Camera(name, eye, tuple(e + k for e, k in zip(eye, look)), (0.0, 0.0, 1.0), _GENSIM_FOV)


FRONT_EYE = (1.0, 0.0, 0.75)
OBS_CAMERAS = {
    "front": _gensim_front("front", FRONT_EYE),  # the default observation camera (see the comment above)
    # straight down over the workspace centre, high enough that objects near its edge stay inside the frame;
    # the arm crosses this view while it works (it starts above the workspace and parks out of view at the end)
    "top": Camera("top", (0.46, 0.0, 0.85), (0.46, 0.0, 0.0), (-1.0, 0.0, 0.0), 45.0),
}
# 4 fixed views of the initial scene for the scene-alignment judges: front (= the front observation camera),
# left, right (after Ravens' left/right cameras: beside the base, looking diagonally across the workspace),
# top-down.
SCENE_VIEWS = (
    _gensim_front("view_front", FRONT_EYE),
    Camera("view_left", (0.46, 0.62, 0.50), (0.46, 0.0, 0.0), fov=55.0),
    Camera("view_right", (0.46, -0.62, 0.50), (0.46, 0.0, 0.0), fov=55.0),
    Camera("view_top", (0.46, 0.0, 0.85), (0.46, 0.0, 0.0), (-1.0, 0.0, 0.0), fov=45.0),
)


class World:
    def __init__(self, control_hz: float = 30.0, physics_hz: float = 240.0, shadows: bool = True,
                 solver_residual: float | None = None) -> None:
        """`shadows`: draw TinyRenderer's shadows in every frame (the look of GenSim's frames; they cost about
        1.8x the render time of a frame without, measured at 64x64 and 128x128).
        `solver_residual`: let the contact solver stop before its 50 iterations once the residual is below this
        (Bullet's solverResidualThreshold; None: Bullet's 1e-7, which in practice runs all 50). Worlds with piles
        pass PILE_SOLVER_RESIDUAL: hundreds of particle contacts at rest converge in a few iterations, and the
        full 50 made a pile episode 2-3x slower (experiments/benchmarks/pile_bench.py)."""
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
        self.shadows = shadows
        self.c.setTimeStep(1.0 / physics_hz)
        self.c.setPhysicsEngineParameter(numSolverIterations=50)
        if solver_residual is not None:
            self.c.setPhysicsEngineParameter(solverResidualThreshold=float(solver_residual))
        self.c.setGravity(0, 0, -9.81)
        self.plane = self.c.loadURDF("plane.urdf", [0, 0, TABLE_Z - 1e-3])
        self.c.changeVisualShape(self.plane, -1, rgbaColor=[*FLOOR_RGB, 1.0], textureUniqueId=-1)
        self.c.changeDynamics(self.plane, -1, lateralFriction=0.6)
        (x0, x1), (y0, y1) = TILE  # the dark workspace tile: drawn only (no collision), just above the floor
        half = [(x1 - x0) / 2, (y1 - y0) / 2, 2e-4]
        vis = self.c.createVisualShape(self.c.GEOM_BOX, halfExtents=half, rgbaColor=[*TILE_RGB, 1.0])
        self.tile = self.c.createMultiBody(0, -1, vis, [(x0 + x1) / 2, (y0 + y1) / 2, TABLE_Z - 7e-4])

    def step(self, n: int | None = None) -> None:
        for _ in range(n or self.substeps):
            self.c.stepSimulation()

    def settle(self, steps: int = 120) -> None:
        self.step(steps)

    def render(self, cam: Camera, size: tuple[int, int], shadows: bool | None = None) -> np.ndarray:
        h, w = size
        shadows = self.shadows if shadows is None else shadows
        view = self.c.computeViewMatrix(cam.eye, cam.target, cam.up)
        proj = self.c.computeProjectionMatrixFOV(cam.fov, w / h, 0.01, 5.0)
        _, _, rgba, _, _ = self.c.getCameraImage(w, h, view, proj, renderer=self.p.ER_TINY_RENDERER,
                                                 flags=self.p.ER_NO_SEGMENTATION_MASK, shadow=int(shadows),
                                                 lightDirection=LIGHT_DIRECTION)
        return np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4)[..., :3]

    def render_with_bodies(self, cam: Camera, size: tuple[int, int],
                           shadows: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
        """`render` and the body id seen at each pixel (H, W) int64 (-1: nothing) from the same call: the image is
        the one `render` gives (the renderer draws it the same way with or without the segmentation buffer;
        tests/test_sim.py compares them), and each id belongs to exactly the pixel drawn."""
        h, w = size
        shadows = self.shadows if shadows is None else shadows
        view = self.c.computeViewMatrix(cam.eye, cam.target, cam.up)
        proj = self.c.computeProjectionMatrixFOV(cam.fov, w / h, 0.01, 5.0)
        _, _, rgba, _, seg = self.c.getCameraImage(w, h, view, proj, renderer=self.p.ER_TINY_RENDERER,
                                                   shadow=int(shadows), lightDirection=LIGHT_DIRECTION)
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4)[..., :3]
        return rgb, np.asarray(seg, dtype=np.int64).reshape(h, w)

    def segmentation(self, cam: Camera, size: tuple[int, int]) -> np.ndarray:
        """Body id seen at each pixel (H, W) (-1: nothing), e.g. to measure how much of a view the arm covers."""
        h, w = size
        view = self.c.computeViewMatrix(cam.eye, cam.target, cam.up)
        proj = self.c.computeProjectionMatrixFOV(cam.fov, w / h, 0.01, 5.0)
        seg = self.c.getCameraImage(w, h, view, proj, renderer=self.p.ER_TINY_RENDERER)[4]
        return np.asarray(seg, dtype=np.int64).reshape(h, w)

    def weld(self, parent: int, parent_link: int, parent_frame, child: int, child_link: int, child_frame,
             max_force: float = 200) -> int:
        """A fixed constraint holding `child` (its link's frame `child_frame`, (position, xyzw)) where it is
        relative to `parent`'s link (frame `parent_frame`): how both robots grasp, the xArm6's suction cup and the
        Panda's hand. Returns the constraint id."""
        c = self.c
        inv_p, inv_o = c.invertTransform(*parent_frame)
        rel_p, rel_o = c.multiplyTransforms(inv_p, inv_o, *child_frame)
        grasp = c.createConstraint(parent, parent_link, child, child_link, c.JOINT_FIXED, [0, 0, 0], rel_p,
                                   [0, 0, 0], rel_o, [0, 0, 0, 1])
        c.changeConstraint(grasp, maxForce=max_force)
        return grasp

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
