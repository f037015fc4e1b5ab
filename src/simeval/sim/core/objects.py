"""Object factory: blocks, cylinders, spheres, bowls, flat zones and lines, piles of small blocks, in named
colours. Every object is a PyBullet multibody built from primitive shapes (no mesh files needed)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from simeval.sim.core.articulated import ARTICULATED  # articulated objects: simeval.sim.core.articulated
from simeval.sim.core.colors import COLORS

OUTLINE = 0.004  # width (m) of the lighter border drawn around zones and lines, as Ravens' zones are outlined
SHAPES = ("block", "cylinder", "sphere", "bowl", "zone", "line", "pile")
FIXTURES = ("drawer_cabinet", "bin", "button")  # the BBSEA suite's fixtures (simeval.sim.core.fixtures)
SHAPES = SHAPES + ARTICULATED + FIXTURES
FLAT = ("zone", "line")  # drawn on the table, no collision
BOWL_WALL = 0.006  # thickness of a bowl's wall: its inner radius is size[0] / 2 - BOWL_WALL
PARTICLE = 0.010  # edge of a pile's particle (Ravens' sweeping piles: 50 blocks of about 1 cm)
# particles as plain rigid bodies (maximal coordinates), which Bullet steps more cheaply than one-link multibodies
# (experiments/benchmarks/pile_bench.py measures it)
PARTICLE_MAXIMAL = True


@dataclass
class SimObject:
    name: str  # the spec's object name (all instances share it)
    index: int  # instance number within that name
    shape: str
    color: str
    size: tuple[float, float, float]  # full extents x, y, z (bowl: outer diameter, diameter, height)
    body_ids: list[int] = field(default_factory=list)  # one body, or many for a pile
    on_table: bool = False  # articulated objects: stands on a wooden table board (simeval.sim.core.articulated)

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


def outline_rgba(color: str) -> list[float]:
    """The border of a zone or line: its colour mixed half-way to white (white stays white), visible on the dark
    tile whatever the fill colour (a black line included)."""
    return [0.45 * v + 0.55 for v in COLORS[color]] + [1.0]


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
        obj.body_ids = [_flat(c, obj, x, y, yaw, table_z)]
    elif obj.shape in ARTICULATED:
        from simeval.sim.core.articulated import make_articulated

        obj.body_ids = [make_articulated(c, obj, x, y, yaw, table_z)]
    elif obj.shape in FIXTURES:
        from simeval.sim.core.fixtures import make_fixture

        obj.body_ids = [make_fixture(c, obj.shape, obj.size, rgba, x, y, yaw, table_z)]
    elif obj.shape == "pile":
        n = int(sz)  # for piles, size z holds the number of particles
        col = c.createCollisionShape(c.GEOM_BOX, halfExtents=[PARTICLE / 2] * 3)
        vis = c.createVisualShape(c.GEOM_BOX, halfExtents=[PARTICLE / 2] * 3, rgbaColor=rgba)
        ids = []
        for _ in range(n):  # spread as Ravens' sweeping piles: uniform over a square, each particle at a random yaw
            dx, dy = rng.uniform(-sx / 2, sx / 2), rng.uniform(-sy / 2, sy / 2)
            q = c.getQuaternionFromEuler([0, 0, rng.uniform(0, 2 * np.pi)])
            ids.append(c.createMultiBody(0.005, col, vis, [x + dx, y + dy, table_z + PARTICLE / 2 + 1e-3], q,
                                         useMaximalCoordinates=PARTICLE_MAXIMAL))
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
    wall, n = BOWL_WALL, 12
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


def _flat(c, obj: SimObject, x: float, y: float, yaw: float, table_z: float) -> int:
    """A zone or line drawn on the table (no collision, static): the filled rectangle and a lighter border of
    width OUTLINE around it, one body whose base pose is the object's pose."""
    sx, sy = obj.size[0], obj.size[1]
    fill = c.createVisualShape(c.GEOM_BOX, halfExtents=[sx / 2, sy / 2, 5e-4], rgbaColor=_rgba(obj.color))
    rgba, w = outline_rgba(obj.color), min(OUTLINE, sx / 4, sy / 4)
    bars = [([sx / 2 - w / 2, 0, 0], [w / 2, sy / 2, 6e-4]), ([-sx / 2 + w / 2, 0, 0], [w / 2, sy / 2, 6e-4]),
            ([0, sy / 2 - w / 2, 0], [sx / 2, w / 2, 6e-4]), ([0, -sy / 2 + w / 2, 0], [sx / 2, w / 2, 6e-4])]
    vis = [c.createVisualShape(c.GEOM_BOX, halfExtents=h, rgbaColor=rgba) for _, h in bars]
    n = len(bars)
    return c.createMultiBody(
        baseMass=0, baseCollisionShapeIndex=-1, baseVisualShapeIndex=fill, basePosition=[x, y, table_z + 5e-4],
        baseOrientation=c.getQuaternionFromEuler([0, 0, yaw]), linkMasses=[0] * n,
        linkCollisionShapeIndices=[-1] * n, linkVisualShapeIndices=vis, linkPositions=[p for p, _ in bars],
        linkOrientations=[[0, 0, 0, 1]] * n, linkInertialFramePositions=[[0, 0, 0]] * n,
        linkInertialFrameOrientations=[[0, 0, 0, 1]] * n, linkParentIndices=[0] * n,
        linkJointTypes=[c.JOINT_FIXED] * n, linkJointAxis=[[0, 0, 1]] * n)
