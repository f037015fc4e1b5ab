"""BBSEA's fixtures as URDF written at run time from their parameters: a drawer cabinet, a bin (tote) and a push
button. Each is a fixed-base body whose base frame sits on the table at the object's (x, y, yaw).

Conventions (the object's `size` is its outer extents x, y, z in its own frame):
  drawer_cabinet  a cabinet open towards its local -x (face it to the robot with yaw 0 and the robot at smaller x); the
          drawer slides out along local -x on a prismatic joint from 0 (closed) to DRAWER_TRAVEL (open) and has
          a vertical fin as its handle on the front panel, to be pinched from above with the fingers closing along
          local y. Holding friction (a velocity motor with a small force) keeps it where it is left.
  bin     an open box: floor and four walls, WALL thick.
  button  a housing with a cap on a prismatic joint pressed down by BUTTON_TRAVEL; it stays pressed (friction).
The articulation of each (joint 0, its only joint) is what the `joint_range` goal measures, as a fraction of its
limits (simeval.sim.core.articulated.joint_fraction): 0 closed / not pressed, 1 open / pressed; `joint_init` sets it. Files go to the temp folder, named by a hash of their
text (written once per parameter set, atomically, so parallel workers never read a half-written file).
"""

from __future__ import annotations

import math

import numpy as np

FIXTURE_SHAPES = ("drawer_cabinet", "bin", "button")
WALL = 0.01  # cabinet and bin wall thickness (m)
DRAWER_TRAVEL = 0.18  # m: how far the drawer slides out
DRAWER_INNER_H = 0.06  # m: height of the drawer box's walls
HANDLE = (0.04, 0.012, 0.03)  # the fin: length out of the panel (x), thickness (y), height (z)
BUTTON_TRAVEL = 0.012
HOLD_FORCE = {"drawer_cabinet": 3.0, "button": 4.0}  # N: the friction that keeps the articulation where it is left


def _box(xyz, size, rgba, name: str) -> str:
    o = " ".join(f"{v:.5f}" for v in xyz)
    s = " ".join(f"{v:.5f}" for v in size)
    geom = f'<origin xyz="{o}"/><geometry><box size="{s}"/></geometry>'
    c = " ".join(f"{v:.4f}" for v in rgba)
    return (f'<visual>{geom}<material name="{name}"><color rgba="{c}"/></material></visual>'
            f'<collision>{geom}</collision>')


def _link(name: str, boxes: list[str], mass: float) -> str:
    return (f'<link name="{name}"><inertial><mass value="{mass}"/><inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" '
            f'iyz="0" izz="0.001"/></inertial>{"".join(boxes)}</link>')


def drawer_geometry(size) -> dict:
    """The drawer box in the drawer link's frame (origin: the centre of its floor's top face when closed, in the
    cabinet frame `origin`): inner half extents x, y and the wall height."""
    d, w, h = size
    inner_x, inner_y = d - 2 * WALL - 0.01, w - 2 * WALL - 0.01
    return {"origin": (-0.005, 0.0, WALL + 0.003 + WALL), "half": (inner_x / 2 - WALL, inner_y / 2 - WALL),
            "height": DRAWER_INNER_H, "outer": (inner_x, inner_y), "front_x": -d / 2}


def drawer_urdf(size, rgba) -> str:
    d, w, h = size
    dark = [0.25, 0.25, 0.27, 1.0]
    shell = [_box((0, 0, WALL / 2), (d, w, WALL), rgba, "shell"),
             _box((0, 0, h - WALL / 2), (d, w, WALL), rgba, "shell"),
             _box((0, w / 2 - WALL / 2, h / 2), (d, WALL, h), rgba, "shell"),
             _box((0, -w / 2 + WALL / 2, h / 2), (d, WALL, h), rgba, "shell"),
             _box((d / 2 - WALL / 2, 0, h / 2), (WALL, w, h), rgba, "shell")]
    g = drawer_geometry(size)
    ox, oy = g["outer"]
    front = [0.45 * v + 0.55 for v in rgba[:3]] + [1.0]
    panel_h = h - 2 * WALL - 0.006
    box = [_box((0, 0, -WALL / 2), (ox, oy, WALL), rgba, "drawer"),
           _box((0, oy / 2 - WALL / 2, g["height"] / 2), (ox, WALL, g["height"]), rgba, "drawer"),
           _box((0, -oy / 2 + WALL / 2, g["height"] / 2), (ox, WALL, g["height"]), rgba, "drawer"),
           _box((ox / 2 - WALL / 2, 0, g["height"] / 2), (WALL, oy, g["height"]), rgba, "drawer"),
           # the front panel closes the cabinet's opening: from the drawer's front to the cabinet's front face
           _box((-ox / 2 - 0.0025, 0, panel_h / 2 - WALL - 0.001), (0.015, w - 0.004, panel_h), front, "front"),
           _box((-ox / 2 - 0.01 - HANDLE[0] / 2, 0, panel_h - WALL - 0.001 - HANDLE[2] / 2 - 0.004), HANDLE, dark,
                "handle")]
    o = " ".join(f"{v:.5f}" for v in g["origin"])
    return (f'<robot name="drawer">{_link("cabinet", shell, 0.0)}{_link("drawer", box, 0.5)}'
            f'<joint name="slide" type="prismatic"><parent link="cabinet"/><child link="drawer"/>'
            f'<origin xyz="{o}"/><axis xyz="-1 0 0"/><limit lower="0" upper="{DRAWER_TRAVEL}" effort="100" '
            f'velocity="1"/></joint></robot>')


def handle_point(c, body: int, size) -> np.ndarray:
    """World position of the middle of the drawer's handle fin (where the fingers pinch it)."""
    g = drawer_geometry(size)
    ox, _ = g["outer"]
    panel_h = size[2] - 2 * WALL - 0.006
    local = (-ox / 2 - 0.01 - HANDLE[0] / 2 + 0.004, 0.0, panel_h - WALL - 0.001 - HANDLE[2] / 2 - 0.004)
    ls = c.getLinkState(body, 0, computeForwardKinematics=True)
    # link frame = the URDF link frame: getLinkState's [4], [5]
    return np.asarray(c.multiplyTransforms(ls[4], ls[5], local, [0, 0, 0, 1])[0])


def bin_urdf(size, rgba) -> str:
    sx, sy, sz = size
    boxes = [_box((0, 0, WALL / 2), (sx, sy, WALL), rgba, "bin"),
             _box((sx / 2 - WALL / 2, 0, sz / 2), (WALL, sy, sz), rgba, "bin"),
             _box((-sx / 2 + WALL / 2, 0, sz / 2), (WALL, sy, sz), rgba, "bin"),
             _box((0, sy / 2 - WALL / 2, sz / 2), (sx, WALL, sz), rgba, "bin"),
             _box((0, -sy / 2 + WALL / 2, sz / 2), (sx, WALL, sz), rgba, "bin")]
    return f'<robot name="bin">{_link("bin", boxes, 0.0)}</robot>'


def button_urdf(size, rgba) -> str:
    d, _, h = size
    housing = [_box((0, 0, h / 2), (d, d, h), [0.3, 0.3, 0.32, 1.0], "housing")]
    cap = [_box((0, 0, 0.01), (d * 0.6, d * 0.6, 0.02), rgba, "cap")]
    return (f'<robot name="button">{_link("housing", housing, 0.0)}{_link("cap", cap, 0.05)}'
            f'<joint name="press" type="prismatic"><parent link="housing"/><child link="cap"/>'
            f'<origin xyz="0 0 {h:.5f}"/><axis xyz="0 0 -1"/><limit lower="0" upper="{BUTTON_TRAVEL}" effort="50" '
            f'velocity="1"/></joint></robot>')


def _write(text: str, kind: str) -> str:
    from simeval.sim.core.urdf_files import write_temp_urdf

    return write_temp_urdf(text, kind)


def make_fixture(c, shape: str, size, rgba, x: float, y: float, yaw: float, table_z: float) -> int:
    """Load the fixture at (x, y, yaw) on the table, its joint (if any) at its lower limit, held by friction."""
    urdf = {"drawer_cabinet": drawer_urdf, "bin": bin_urdf, "button": button_urdf}[shape](size, rgba)
    body = c.loadURDF(_write(urdf, shape), [x, y, table_z], c.getQuaternionFromEuler([0, 0, yaw]),
                      useFixedBase=True)
    if shape in HOLD_FORCE:
        c.setJointMotorControl2(body, 0, c.VELOCITY_CONTROL, targetVelocity=0.0, force=HOLD_FORCE[shape])
    return body


def inside(c, point, container_body: int, shape: str, size) -> bool:
    """Whether a world point lies in the inner volume of a bin (its base) or a drawer (its sliding box)."""
    if shape == "bin":
        pos, orn = c.getBasePositionAndOrientation(container_body)
        half = (size[0] / 2 - WALL, size[1] / 2 - WALL)
        floor, top = WALL, size[2]
    elif shape == "drawer_cabinet":
        ls = c.getLinkState(container_body, 0, computeForwardKinematics=True)
        pos, orn = ls[4], ls[5]
        g = drawer_geometry(size)
        half, floor, top = g["half"], 0.0, g["height"]
    else:
        return False
    inv_p, inv_o = c.invertTransform(pos, orn)
    local = np.asarray(c.multiplyTransforms(inv_p, inv_o, list(map(float, point)), [0, 0, 0, 1])[0])
    return bool(abs(local[0]) <= half[0] and abs(local[1]) <= half[1] and floor - 0.005 <= local[2] <= top)


def drawer_drop_point(c, body: int, size) -> np.ndarray:
    """World point above the middle of the part of the drawer's box that is out of the cabinet (where an object
    dropped from above lands in it), at the box's floor."""
    g = drawer_geometry(size)
    ls = c.getLinkState(body, 0, computeForwardKinematics=True)
    q = c.getJointState(body, 0)[0]
    # the part out of the cabinet: local x from the box's front wall to front + opening (the cabinet front)
    lo = -g["half"][0]
    cabinet_front = -size[0] / 2 - g["origin"][0] + q  # the cabinet's front face in the drawer link's frame
    hi = max(lo, min(g["half"][0], cabinet_front - 0.02))
    local = ((lo + hi) / 2, 0.0, 0.0)
    return np.asarray(c.multiplyTransforms(ls[4], ls[5], local, [0, 0, 0, 1])[0])


def yaw_of_body(c, body: int) -> float:
    x, y, z, w = c.getBasePositionAndOrientation(body)[1]
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
