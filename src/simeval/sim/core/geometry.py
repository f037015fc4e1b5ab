"""Geometry of the live simulation that any motion or goal code reads: poses, rest, contact, containment.

No task spec is read here (simeval.sim.tasks.goals turns a task's goals into progress with these; the experts in
simeval.sim.experts.pick_place and simeval.sim.experts.plan aim with them), so goal checks and motion code share one definition
of "at rest" or "inside" without importing each other."""

from __future__ import annotations

import math

import numpy as np

from simeval.sim.core.objects import BOWL_WALL, SimObject
from simeval.sim.core.world import TABLE_Z, World, yaw_of

XY_TOL = 0.02  # an object counts at a target when its centre is within this of it (or inside a zone)
# at rest: no point of the object faster than this (|v| + r |w|, r its half-diagonal). A bounce after a release
# reaches 0.04 m/s between impacts; the solver's jitter of an object resting in a bowl stays under 0.02 m/s.
REST_SPEED = 0.025
CONTACT = 0.002  # m: closer than this two bodies touch (PyBullet's closest-point distance)
STACK_Z_TOL = 0.006  # m: an object on another sits within this of the height it has when resting on it
UPRIGHT_COS = math.cos(math.radians(12))  # upright: the object's own z axis within 12 degrees of vertical


def pose(world: World, obj: SimObject, k: int = 0) -> tuple[np.ndarray, float]:
    p, q = world.c.getBasePositionAndOrientation(obj.body_ids[k])
    return np.asarray(p), yaw_of(q)


def height(obj: SimObject) -> float:
    return obj.size[0] if obj.shape == "sphere" else obj.size[2]


def still(world: World, body: int, radius: float = 0.03) -> bool:
    lin, ang = world.c.getBaseVelocity(body)
    return bool(np.linalg.norm(lin) + radius * np.linalg.norm(ang) < REST_SPEED)


def radius(obj: SimObject) -> float:
    return 0.5 * float(np.linalg.norm(obj.size)) if obj.shape != "pile" else 0.009


def resting(world: World, obj: SimObject, floor: float = TABLE_Z, tol: float = 0.015) -> bool:
    """Near the surface below it (not held in the air) and almost still."""
    p, _ = pose(world, obj)
    return p[2] - height(obj) / 2 < floor + tol and still(world, obj.body_ids[0], radius(obj))


def upright(world: World, obj: SimObject) -> bool:
    """Standing on its base (either end for symmetric shapes): its own z axis near vertical. Spheres always."""
    if obj.shape == "sphere":
        return True
    _, q = world.c.getBasePositionAndOrientation(obj.body_ids[0])
    z_axis = np.asarray(world.c.getMatrixFromQuaternion(q)).reshape(3, 3)[:, 2]
    return bool(abs(z_axis[2]) >= UPRIGHT_COS)


def supported(world: World, body: int) -> bool:
    """In contact with something (the table, a container, another object): an object let go of is still
    for an instant before it falls, and must not count in that instant."""
    return bool(world.c.getContactPoints(bodyA=body))


def placed(world: World, obj: SimObject, held: set[int]) -> bool:
    """Let go of, supported and at rest: the condition for any placement to count."""
    b = obj.body_ids[0]
    return b not in held and still(world, b, radius(obj)) and supported(world, b)


def touching(world: World, a: SimObject, b: SimObject) -> bool:
    return bool(world.c.getClosestPoints(a.body_ids[0], b.body_ids[0], CONTACT))


def in_zone(world: World, xy: np.ndarray, zone: SimObject, margin: float = 0.0) -> bool:
    zp, zyaw = pose(world, zone)
    d = xy[:2] - zp[:2]
    local = np.array([d[0] * math.cos(-zyaw) - d[1] * math.sin(-zyaw), d[0] * math.sin(-zyaw) + d[1] * math.cos(-zyaw)])
    return bool(np.all(np.abs(local) <= np.array(zone.size[:2]) / 2 - margin))


def in_bowl(world: World, obj: SimObject, bowl: SimObject, tol: float = 0.003) -> bool:
    """Inside the wall (its centre no farther from the bowl's axis than the inner radius less its own
    half-width, so an object touching the wall counts) and below the rim's mid-height (not perched on it)."""
    p, _ = pose(world, obj)
    bp, _ = pose(world, bowl)
    inner = bowl.size[0] / 2 - BOWL_WALL
    half_width = obj.size[0] / 2 if obj.shape in ("sphere", "cylinder") else min(obj.size[:2]) / 2
    bottom = p[2] - height(obj) / 2
    return bool(np.linalg.norm(p[:2] - bp[:2]) <= inner - half_width + tol and bottom < bp[2] + bowl.size[2] / 2)


def in_container(world: World, obj: SimObject, target: SimObject) -> bool:
    """Inside a bowl, or inside a bin's or a drawer's box (simeval.sim.core.fixtures)."""
    if target.shape in ("bin", "drawer_cabinet"):
        from simeval.sim.core.fixtures import inside

        return inside(world.c, pose(world, obj)[0], target.body_ids[0], target.shape, target.size)
    return in_bowl(world, obj, target)


def offset_target(anchor_pos: np.ndarray, anchor_yaw: float, offset: list[float]) -> np.ndarray:
    dx, dy = offset[0], offset[1]
    c, s = math.cos(anchor_yaw), math.sin(anchor_yaw)
    return anchor_pos[:2] + np.array([c * dx - s * dy, s * dx + c * dy])
