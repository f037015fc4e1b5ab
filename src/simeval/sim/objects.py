"""Object factory: blocks, cylinders, spheres, bowls, flat zones and lines, piles of small blocks, in named
colours. Every object is a PyBullet multibody built from primitive shapes (no mesh files needed)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

COLORS = {
    "red": (0.85, 0.16, 0.16), "green": (0.18, 0.65, 0.25), "blue": (0.18, 0.38, 0.85),
    "yellow": (0.95, 0.82, 0.15), "orange": (0.95, 0.5, 0.1), "purple": (0.55, 0.25, 0.7),
    "pink": (0.95, 0.5, 0.7), "cyan": (0.2, 0.8, 0.85), "brown": (0.55, 0.35, 0.2), "gray": (0.55, 0.55, 0.55),
    "white": (0.92, 0.92, 0.92), "black": (0.12, 0.12, 0.12),
}
SHAPES = ("block", "cylinder", "sphere", "bowl", "zone", "line", "pile")
FLAT = ("zone", "line")  # drawn on the table, no collision


@dataclass
class SimObject:
    name: str  # the spec's object name (all instances share it)
    index: int  # instance number within that name
    shape: str
    color: str
    size: tuple[float, float, float]  # full extents x, y, z (bowl: outer diameter, diameter, height)
    body_ids: list[int] = field(default_factory=list)  # one body, or many for a pile

    @property
    def id(self) -> str:
        return f"{self.name}{self.index}"

    @property
    def footprint(self) -> float:
        """Radius of a circle holding the object's footprint (for placing objects apart)."""
        return 0.5 * math.hypot(self.size[0], self.size[1])


def _rgba(color: str) -> list[float]:
    if color not in COLORS:
        raise ValueError(f"unknown colour '{color}'; known: {', '.join(COLORS)}")
    return [*COLORS[color], 1.0]


def make_object(client, obj: SimObject, position: np.ndarray, yaw: float, rng: np.random.Generator,
                table_z: float) -> SimObject:
    c = client
    x, y = float(position[0]), float(position[1])
    sx, sy, sz = obj.size
    orn = c.getQuaternionFromEuler([0, 0, yaw])
    rgba = _rgba(obj.color)
    if obj.shape == "block":
        col = c.createCollisionShape(c.GEOM_BOX, halfExtents=[sx / 2, sy / 2, sz / 2])
        vis = c.createVisualShape(c.GEOM_BOX, halfExtents=[sx / 2, sy / 2, sz / 2], rgbaColor=rgba)
        obj.body_ids = [c.createMultiBody(0.05, col, vis, [x, y, table_z + sz / 2 + 1e-3], orn)]
    elif obj.shape == "cylinder":
        col = c.createCollisionShape(c.GEOM_CYLINDER, radius=sx / 2, height=sz)
        vis = c.createVisualShape(c.GEOM_CYLINDER, radius=sx / 2, length=sz, rgbaColor=rgba)
        obj.body_ids = [c.createMultiBody(0.05, col, vis, [x, y, table_z + sz / 2 + 1e-3], orn)]
    elif obj.shape == "sphere":
        col = c.createCollisionShape(c.GEOM_SPHERE, radius=sx / 2)
        vis = c.createVisualShape(c.GEOM_SPHERE, radius=sx / 2, rgbaColor=rgba)
        body = c.createMultiBody(0.05, col, vis, [x, y, table_z + sx / 2 + 1e-3], orn)
        c.changeDynamics(body, -1, rollingFriction=0.01, spinningFriction=0.01)
        obj.body_ids = [body]
    elif obj.shape == "bowl":
        obj.body_ids = [_bowl(c, obj, x, y, table_z, rgba)]
    elif obj.shape in FLAT:
        vis = c.createVisualShape(c.GEOM_BOX, halfExtents=[sx / 2, sy / 2, 5e-4], rgbaColor=rgba)
        obj.body_ids = [c.createMultiBody(0, -1, vis, [x, y, table_z + 5e-4], orn)]
    elif obj.shape == "pile":
        n = int(sz)  # for piles, size z holds the number of particles
        r = sx / 2
        col = c.createCollisionShape(c.GEOM_BOX, halfExtents=[0.006] * 3)
        vis = c.createVisualShape(c.GEOM_BOX, halfExtents=[0.006] * 3, rgbaColor=rgba)
        ids = []
        for _ in range(n):
            a, d = rng.uniform(0, 2 * np.pi), r * math.sqrt(rng.uniform())
            ids.append(c.createMultiBody(0.005, col, vis, [x + d * math.cos(a), y + d * math.sin(a), table_z + 0.007]))
        obj.body_ids = ids
    else:
        raise ValueError(f"unknown shape '{obj.shape}'; known: {', '.join(SHAPES)}")
    for b in obj.body_ids:
        if obj.shape not in FLAT:
            c.changeDynamics(b, -1, lateralFriction=0.8)
    return obj


def _bowl(c, obj: SimObject, x: float, y: float, table_z: float, rgba) -> int:
    """A container: a thin base disc and a ring of wall segments, as one static-looking but movable body."""
    outer, height = obj.size[0] / 2, obj.size[2]
    wall, n = 0.006, 12
    shapes_col, shapes_vis, pos, orns = [], [], [], []
    base_col = c.createCollisionShape(c.GEOM_CYLINDER, radius=outer, height=0.004)
    base_vis = c.createVisualShape(c.GEOM_CYLINDER, radius=outer, length=0.004, rgbaColor=rgba)
    seg = 2 * outer * math.tan(math.pi / n) + 0.002
    for k in range(n):
        a = 2 * math.pi * k / n
        shapes_col.append(c.createCollisionShape(c.GEOM_BOX, halfExtents=[wall / 2, seg / 2, height / 2]))
        shapes_vis.append(c.createVisualShape(c.GEOM_BOX, halfExtents=[wall / 2, seg / 2, height / 2], rgbaColor=rgba))
        pos.append([(outer - wall / 2) * math.cos(a), (outer - wall / 2) * math.sin(a), height / 2])
        orns.append(c.getQuaternionFromEuler([0, 0, a]))
    body = c.createMultiBody(
        baseMass=0.2, baseCollisionShapeIndex=base_col, baseVisualShapeIndex=base_vis,
        basePosition=[x, y, table_z + 0.002 + 1e-3], linkMasses=[0.01] * n, linkCollisionShapeIndices=shapes_col,
        linkVisualShapeIndices=shapes_vis, linkPositions=pos, linkOrientations=orns,
        linkInertialFramePositions=[[0, 0, 0]] * n, linkInertialFrameOrientations=[[0, 0, 0, 1]] * n,
        linkParentIndices=[0] * n, linkJointTypes=[c.JOINT_FIXED] * n, linkJointAxis=[[0, 0, 1]] * n)
    return body
