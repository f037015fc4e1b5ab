"""Procedurally generated articulated objects for the RoboGen-style suite: parameters -> URDF text -> loadURDF.
No asset is copied: every part is a box or a cylinder whose dimensions follow from the object's overall size.

Conventions:
- An object's frame: origin at the centre of its footprint on the floor (or on its table board), x towards the back,
  so its front faces -x, towards the arm at the origin when its yaw is 0; z up. `SimObject.size` is the overall
  (depth x, width y, height z) of the object itself (a table board, if any, adds ON_TABLE_Z below it).
- One fixed base link holds every static part; each moving part is a link on a revolute or prismatic joint whose
  positive direction opens / extends / presses (so a joint fraction 0 = lower limit = closed, 1 = upper = open).
  Joint index k is link index k (there are no fixed joints), which is what `joint` in a goal counts.
- Each moving link has grip points (a point and its outward normal in the link's URDF frame): where a suction cup
  coming from above can seize it (the top of a handle, the top of a lid). `grip_points` gives them in the world;
  a controller takes the one whose normal points most upwards now.
- Joints hold their position against gravity by friction (a velocity motor with target 0 and a small maximum force,
  FRICTION), which the suction grip overcomes.
- URDFs are written once per distinct text to the temp folder (named by their hash), never into the source tree.

Kinds (`ARTICULATED`): laptop (hinged lid), lamp (head swivels about the pole), display (screen slides up its
stand), faucet (lever turns about the vertical), drawer (cabinet with a drawer sliding out), oven (door hinged at the
bottom, joint 0; timer knob, joint 1), window (lower sash slides up), toilet (flush lever), dishwasher (start button
pressed down), table_doors (two doors hinged at the sides, joints 0 and 1)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from simeval.sim.core.colors import COLORS

ON_TABLE_Z = 0.03  # thickness of the wooden board a table-top object stands on (shows it is on a table)
WOOD = (0.62, 0.45, 0.30, 1.0)
DARK = (0.15, 0.15, 0.17, 1.0)
STEEL = (0.72, 0.73, 0.76, 1.0)
WHITE = (0.93, 0.93, 0.92, 1.0)
GLASS = (0.62, 0.80, 0.90, 1.0)
# joint friction: N m for revolute joints, N for prismatic ones (holds a lid or door against gravity)
FRICTION = {"revolute": 1.5, "prismatic": 6.0}


@dataclass
class Part:
    geom: str  # box | cylinder
    xyz: tuple[float, float, float]
    dims: tuple[float, ...]  # box: full extents; cylinder: (radius, length)
    rgba: tuple[float, float, float, float]
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    collide: bool = True


@dataclass
class Joint:
    type: str  # revolute | prismatic
    origin: tuple[float, float, float]  # in the base frame
    axis: tuple[float, float, float]
    limits: tuple[float, float]
    parts: list[Part] = field(default_factory=list)  # in the joint (= child link) frame
    grips: list[tuple[tuple[float, float, float], tuple[float, float, float]]] = field(default_factory=list)
    mass: float = 0.2


@dataclass
class Design:
    base: list[Part]
    joints: list[Joint]


def _box(xyz, dims, rgba, collide=True) -> Part:
    return Part("box", tuple(xyz), tuple(dims), rgba, collide=collide)


def _cyl(xyz, radius, length, rgba, rpy=(0.0, 0.0, 0.0), collide=True) -> Part:
    return Part("cylinder", tuple(xyz), (radius, length), rgba, tuple(rpy), collide)


def _laptop(D: float, W: float, H: float, rgba: tuple) -> Design:
    """Base with a keyboard; lid hinged at the back edge, screen on its inner face."""
    tb, tl = 0.35 * H, 0.3 * H
    base = [_box((0, 0, tb / 2), (D, W, tb), rgba), _box((-0.05 * D, 0, tb), (0.6 * D, 0.85 * W, 0.002), DARK, False)]
    lid = [_box((-D / 2, 0, tl / 2 + 0.001), (D, W, tl), rgba),
           _box((-D / 2, 0, 0.0008), (0.9 * D, 0.9 * W, 0.0012), DARK, False)]
    return Design(base, [Joint("revolute", (D / 2, 0, tb), (0, 1, 0), (0.0, 1.9), lid,
                               [((-D + 0.025, 0, tl + 0.001), (0, 0, 1))], 0.15)])


def _lamp(D: float, W: float, H: float, rgba: tuple) -> Design:
    """Round foot, pole, head arm that swivels about the pole, shade at the arm's end."""
    r_foot, arm = 0.45 * min(D, W), 0.55 * max(D, W)
    base = [_cyl((0, 0, 0.01), r_foot, 0.02, rgba), _cyl((0, 0, H / 2), 0.011, H - 0.04, STEEL)]
    head = [_cyl((0, 0, 0.0), 0.018, 0.04, rgba), _box((-arm / 2, 0, 0.0), (arm, 0.022, 0.018), STEEL),
            _cyl((-arm, 0, -0.01), 0.035, 0.05, rgba), _cyl((-arm, 0, -0.036), 0.028, 0.004, (1.0, 0.95, 0.7, 1.0), collide=False)]
    return Design(base, [Joint("revolute", (0, 0, H - 0.04), (0, 0, 1), (-1.6, 1.6), head,
                               [((-arm, 0, 0.015), (0, 0, 1))], 0.15)])


def _display(D: float, W: float, H: float, rgba: tuple) -> Design:
    """Foot, post, screen that slides up the post."""
    sh, st = 0.55 * H, 0.025
    base = [_box((0.2 * D, 0, 0.01), (0.6 * D, 0.5 * W, 0.02), DARK), _box((0.3 * D, 0, (0.06 + sh / 2) / 2), (0.02, 0.06, 0.06 + sh / 2), STEEL)]  # hidden behind the screen
    screen = [_box((0, 0, sh / 2), (st, W, sh), rgba), _box((-st / 2 - 0.0006, 0, sh / 2), (0.001, 0.92 * W, 0.88 * sh), DARK, False)]
    return Design(base, [Joint("prismatic", (0.3 * D - 0.01 - st / 2, 0, 0.06), (0, 0, 1), (0.0, 0.4 * H), screen,
                               [((0, 0, sh), (0, 0, 1))], 0.2)])


def _faucet(D: float, W: float, H: float, rgba: tuple) -> Design:
    """A basin counter, the faucet's body and spout, a lever on top that turns about z."""
    ch, lever = 0.4 * H, 0.6 * D
    base = [_box((0, 0, ch / 2), (D, W, ch), WHITE), _box((-0.1 * D, 0, ch + 0.001), (0.5 * D, 0.6 * W, 0.002), STEEL, False),
            _cyl((0.3 * D, 0, ch + 0.35 * H / 2), 0.02, 0.35 * H, rgba),
            _box((0.05 * D, 0, ch + 0.35 * H - 0.01), (0.5 * D, 0.025, 0.02), rgba)]
    handle = [_cyl((0, 0, 0.01), 0.018, 0.02, rgba), _box((-lever / 2, 0, 0.02), (lever, 0.022, 0.016), STEEL)]
    return Design(base, [Joint("revolute", (0.3 * D, 0, ch + 0.35 * H), (0, 0, 1), (0.0, 1.4), handle,
                               [((-lever + 0.012, 0, 0.028), (0, 0, 1))], 0.1)])


def _drawer(D: float, W: float, H: float, rgba: tuple) -> Design:
    """A cabinet box open at the front; a drawer with a handle bar slides out (-x)."""
    t = 0.012
    base = [_box((0, 0, t / 2), (D, W, t), rgba), _box((0, 0, H - t / 2), (D, W, t), rgba),
            _box((0, W / 2 - t / 2, H / 2), (D, t, H), rgba), _box((0, -W / 2 + t / 2, H / 2), (D, t, H), rgba),
            _box((D / 2 - t / 2, 0, H / 2), (t, W, H), rgba)]
    dh, dw, dd = H - 2 * t - 0.01, W - 2 * t - 0.008, D - t - 0.01
    off = 0.06  # the handle stands well off the drawer: the arm's wrist above the cup clears the cabinet top
    drawer = [_box((0, 0, 0), (t, dw + 0.006, dh + 0.004), WOOD), _box((dd / 2, 0, -dh / 2 + t / 2), (dd, dw, t), WOOD),
              _box((dd / 2, dw / 2 - t / 2, 0), (dd, t, dh), WOOD), _box((dd / 2, -dw / 2 + t / 2, 0), (dd, t, dh), WOOD),
              _box((dd, 0, 0), (t, dw, dh), WOOD), _box((-off, 0, 0.15 * dh), (0.016, 0.45 * dw, 0.016), STEEL),
              _box((-off / 2 - 0.004, 0.2 * dw, 0.15 * dh), (off, 0.012, 0.012), STEEL),
              _box((-off / 2 - 0.004, -0.2 * dw, 0.15 * dh), (off, 0.012, 0.012), STEEL)]
    return Design(base, [Joint("prismatic", (-D / 2 + t / 2, 0, H / 2), (-1, 0, 0), (0.0, 0.65 * D), drawer,
                               [((-off, 0, 0.15 * dh + 0.008), (0, 0, 1))], 0.3)])


def _oven(D: float, W: float, H: float, rgba: tuple) -> Design:
    """A box open at the front, a door hinged at its bottom edge, a control panel with a timer knob."""
    t, panel = 0.015, 0.22 * H
    body_h = H - panel
    base = [_box((0, 0, t / 2), (D, W, t), rgba), _box((0, 0, body_h - t / 2), (D, W, t), rgba),
            _box((0, W / 2 - t / 2, body_h / 2), (D, t, body_h), rgba), _box((0, -W / 2 + t / 2, body_h / 2), (D, t, body_h), rgba),
            _box((D / 2 - t / 2, 0, body_h / 2), (t, W, body_h), rgba), _box((0.05, 0, body_h + panel / 2), (D - 0.1, W, panel), DARK),
            _box((0, 0, t + 0.003), (D - 2 * t, W - 2 * t, 0.004), DARK, False)]
    dh = body_h - 0.02
    door = [_box((-t / 2, 0, dh / 2), (t, W - 0.01, dh), rgba), _box((-t - 0.0006, 0, 0.55 * dh), (0.001, 0.6 * W, 0.45 * dh), DARK, False),
            _box((-t - 0.03, 0, dh - 0.03), (0.016, 0.7 * W, 0.016), STEEL),
            _box((-t - 0.015, 0.3 * W, dh - 0.03), (0.03, 0.012, 0.012), STEEL),
            _box((-t - 0.015, -0.3 * W, dh - 0.03), (0.03, 0.012, 0.012), STEEL)]
    kr = 0.28 * panel
    knob = [_cyl((-0.014, 0, 0), kr, 0.028, WHITE, rpy=(0, math.pi / 2, 0)),
            _box((-0.02, 0, kr - 0.004), (0.024, 0.01, 0.016), DARK)]
    return Design(base, [
        Joint("revolute", (-D / 2, 0, 0.01), (0, -1, 0), (0.0, math.pi / 2), door,
              [((-t - 0.03, 0, dh - 0.022), (0, 0, 1)), ((0, 0, dh - 0.03), (1, 0, 0))], 0.3),
        Joint("revolute", (-D / 2 + 0.1, 0.25 * W, body_h + panel / 2), (-1, 0, 0), (0.0, math.pi), knob,
              [((-0.02, 0, kr + 0.004), (0, 0, 1))], 0.05)])


def _window(D: float, W: float, H: float, rgba: tuple) -> Design:
    """A frame standing on the floor; the upper pane is fixed, the lower sash slides up."""
    t, fd = 0.025, D
    base = [_box((0, 0, t / 2), (fd, W, t), rgba), _box((0, 0, H - t / 2), (fd, W, t), rgba),
            _box((0, W / 2 - t / 2, H / 2), (fd, t, H), rgba), _box((0, -W / 2 + t / 2, H / 2), (fd, t, H), rgba),
            _box((fd / 4, 0, 0.75 * H), (0.006, W - 2 * t, H / 2 - t), GLASS), _box((0.01, 0, 0.55 * H), (0.01, W - 2 * t, 0.02), rgba),
            _box((-fd / 2 - 0.05, 0, 0.01), (0.1, W, 0.02), rgba)]
    sh, sw = H / 2 - t, W - 2 * t - 0.004
    sash = [_box((0, 0, 0.012), (0.02, sw, 0.024), rgba), _box((0, 0, sh - 0.012), (0.02, sw, 0.024), rgba),
            _box((0, sw / 2 - 0.012, sh / 2), (0.02, 0.024, sh), rgba), _box((0, -sw / 2 + 0.012, sh / 2), (0.02, 0.024, sh), rgba),
            _box((0, 0, sh / 2), (0.006, sw - 0.048, sh - 0.048), GLASS),
            _box((-0.085, 0, 0.05), (0.016, 0.3 * sw, 0.016), STEEL),  # a handle standing well off the sash:
            _box((-0.047, 0.12 * sw, 0.05), (0.075, 0.012, 0.012), STEEL),  # the wrist clears the frame above
            _box((-0.047, -0.12 * sw, 0.05), (0.075, 0.012, 0.012), STEEL)]
    return Design(base, [Joint("prismatic", (-fd / 4, 0, t), (0, 0, 1), (0.0, 0.38 * H), sash,
                               [((-0.085, 0, 0.058), (0, 0, 1))], 0.25)])


def _toilet(D: float, W: float, H: float, rgba: tuple) -> Design:
    """Bowl with a seat, tank at the back, flush lever on the tank's front that turns down."""
    tank_d, bowl_h = 0.3 * D, 0.45 * H
    base = [_cyl((-0.1 * D, 0, bowl_h / 2), 0.33 * min(D, W), bowl_h, WHITE),
            _cyl((-0.1 * D, 0, bowl_h + 0.008), 0.36 * min(D, W), 0.016, rgba),
            _cyl((-0.1 * D, 0, bowl_h + 0.0165), 0.22 * min(D, W), 0.001, DARK, collide=False),
            _box((D / 2 - tank_d / 2, 0, H / 2), (tank_d, 0.8 * W, H), WHITE),
            _box((D / 2 - tank_d / 2, 0, H + 0.008), (tank_d + 0.01, 0.82 * W, 0.016), rgba)]
    # the lever stands 7 cm off the tank on a shaft, so the arm's wrist above the cup clears the tank's lid
    lever, off = 0.22 * W, 0.07
    handle = [_cyl((-off / 2, 0, 0), 0.01, off, STEEL, rpy=(0, math.pi / 2, 0)),
              _box((-off, -lever / 2, 0), (0.016, lever, 0.016), STEEL)]
    return Design(base, [Joint("revolute", (D / 2 - tank_d, 0.32 * W, 0.85 * H), (1, 0, 0), (0.0, 0.7), handle,
                               [((-off, -lever + 0.01, 0.008), (0, 0, 1))], 0.05)])


def _dishwasher(D: float, W: float, H: float, rgba: tuple) -> Design:
    """A box with a front door outline and a control strip; start button pressed down."""
    base = [_box((0, 0, H / 2), (D, W, H), rgba), _box((-D / 2 - 0.0006, 0, 0.42 * H), (0.001, 0.92 * W, 0.8 * H), STEEL, False),
            _box((-D / 2 + 0.04, 0, H + 0.004), (0.08, 0.9 * W, 0.008), DARK),
            _box((-D / 2 - 0.012, 0, 0.8 * H), (0.02, 0.5 * W, 0.018), STEEL)]
    button = [_cyl((0, 0, 0.006), 0.018, 0.012, (0.30, 0.75, 0.35, 1.0))]
    return Design(base, [Joint("prismatic", (-D / 2 + 0.04, -0.25 * W, H + 0.008), (0, 0, -1), (0.0, 0.008), button,
                               [((0, 0, 0.012), (0, 0, 1))], 0.03)])


def _table_doors(D: float, W: float, H: float, rgba: tuple) -> Design:
    """A low table (top, sides, back) with two doors hinged at the sides."""
    t, dw = 0.015, W / 2 - 0.012
    base = [_box((0, 0, H - t / 2), (D + 0.02, W + 0.02, t), WOOD), _box((0, W / 2 - t / 2, (H - t) / 2), (D, t, H - t), rgba),
            _box((0, -W / 2 + t / 2, (H - t) / 2), (D, t, H - t), rgba), _box((D / 2 - t / 2, 0, (H - t) / 2), (t, W, H - t), rgba),
            _box((0, 0, 0.02), (D, W, 0.04), rgba)]
    dh = H - t - 0.05
    off = 0.07  # handles stand well off the doors: the arm's wrist above the cup clears the table top

    def door(sign: float) -> list[Part]:  # sign +1: hinge on the +y side, the door spans towards -y
        return [_box((-t / 2, -sign * dw / 2, dh / 2), (t, dw - 0.004, dh), rgba),
                _box((-off, -sign * (dw - 0.03), 0.75 * dh), (0.016, 0.016, 0.14 * dh), STEEL),
                _box((-off / 2 - 0.004, -sign * (dw - 0.03), 0.75 * dh + 0.05 * dh), (off, 0.012, 0.012), STEEL),
                _box((-off / 2 - 0.004, -sign * (dw - 0.03), 0.75 * dh - 0.05 * dh), (off, 0.012, 0.012), STEEL)]
    grips = [[((-off, -s * (dw - 0.03), 0.75 * dh + 0.07 * dh), (0, 0, 1))] for s in (1, -1)]
    return Design(base, [Joint("revolute", (-D / 2, W / 2 - 0.004, 0.045), (0, 0, -1), (0.0, 1.6), door(1), grips[0], 0.3),
                         Joint("revolute", (-D / 2, -W / 2 + 0.004, 0.045), (0, 0, 1), (0.0, 1.6), door(-1), grips[1], 0.3)])


DESIGNS = {"laptop": _laptop, "lamp": _lamp, "display": _display, "faucet": _faucet, "drawer": _drawer, "oven": _oven, "window": _window, "toilet": _toilet, "dishwasher": _dishwasher, "table_doors": _table_doors}
ARTICULATED = tuple(DESIGNS)  # a new kind is one function above and its entry here


def design(kind: str, size, rgba) -> Design:
    """The parts and joints of one object of `kind` with overall size (depth, width, height) and main colour."""
    if kind not in DESIGNS:
        raise ValueError(f"unknown articulated kind '{kind}'; known: {', '.join(ARTICULATED)}")
    depth, width, height = (float(v) for v in size)
    return DESIGNS[kind](depth, width, height, tuple(rgba))


def _parts_xml(parts: list[Part], tag: str) -> str:
    out = []
    for k, p in enumerate(parts):
        geom = (f'<box size="{p.dims[0]:.5f} {p.dims[1]:.5f} {p.dims[2]:.5f}"/>' if p.geom == "box"
                else f'<cylinder radius="{p.dims[0]:.5f}" length="{p.dims[1]:.5f}"/>')
        origin = f'<origin xyz="{p.xyz[0]:.5f} {p.xyz[1]:.5f} {p.xyz[2]:.5f}" rpy="{p.rpy[0]:.5f} {p.rpy[1]:.5f} {p.rpy[2]:.5f}"/>'
        color = " ".join(f"{v:.4f}" for v in p.rgba)
        out.append(f'<visual>{origin}<geometry>{geom}</geometry><material name="{tag}_m{k}"><color rgba="{color}"/>'
                   f'</material></visual>')
        if p.collide:
            out.append(f"<collision>{origin}<geometry>{geom}</geometry></collision>")
    return "".join(out)


def _inertial(mass: float) -> str:
    return (f'<inertial><origin xyz="0 0 0"/><mass value="{mass}"/>'
            '<inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial>')


def urdf_text(d: Design, name: str) -> str:
    links = [f'<link name="base">{_inertial(1.0)}{_parts_xml(d.base, "base")}</link>']
    joints = []
    for k, j in enumerate(d.joints):
        links.append(f'<link name="part{k}">{_inertial(j.mass)}{_parts_xml(j.parts, f"part{k}")}</link>')
        joints.append(f'<joint name="joint{k}" type="{j.type}"><parent link="base"/><child link="part{k}"/>'
                      f'<origin xyz="{j.origin[0]:.5f} {j.origin[1]:.5f} {j.origin[2]:.5f}" rpy="0 0 0"/>'
                      f'<axis xyz="{j.axis[0]} {j.axis[1]} {j.axis[2]}"/>'
                      f'<limit lower="{j.limits[0]}" upper="{j.limits[1]}" effort="100" velocity="3"/></joint>')
    return f'<?xml version="1.0"?><robot name="{name}">{"".join(links)}{"".join(joints)}</robot>'


def _with_board(d: Design, size) -> Design:
    """The object raised onto a wooden board (a table top) that sticks out around its footprint."""
    D, W, _ = size
    lift = lambda p: Part(p.geom, (p.xyz[0], p.xyz[1], p.xyz[2] + ON_TABLE_Z), p.dims, p.rgba, p.rpy, p.collide)  # noqa: E731
    base = [_box((0, 0, ON_TABLE_Z / 2), (D + 0.08, W + 0.08, ON_TABLE_Z), WOOD)] + [lift(p) for p in d.base]
    joints = [Joint(j.type, (j.origin[0], j.origin[1], j.origin[2] + ON_TABLE_Z), j.axis, j.limits, j.parts, j.grips, j.mass)
              for j in d.joints]
    return Design(base, joints)


def write_urdf(text: str) -> str:
    """The URDF in the temp folder, once per distinct text (simeval.sim.core.urdf_files)."""
    from simeval.sim.core.urdf_files import write_temp_urdf

    return write_temp_urdf(text, "artic")


def object_design(obj) -> Design:
    """The design of a SimObject of an articulated shape (its size, colour and whether it stands on a table)."""
    d = design(obj.shape, obj.size, (*COLORS[obj.color], 1.0))
    return _with_board(d, obj.size) if getattr(obj, "on_table", False) else d


def make_articulated(c, obj, x: float, y: float, yaw: float, table_z: float) -> int:
    """Load the object as a fixed-base multibody at (x, y) with its front turned by `yaw`; joints at their lower
    limit, each held by its friction."""
    d = object_design(obj)
    body = c.loadURDF(write_urdf(urdf_text(d, obj.shape)), [x, y, table_z], c.getQuaternionFromEuler([0, 0, yaw]),
                      useFixedBase=True)
    for k, j in enumerate(d.joints):
        c.setJointMotorControl2(body, k, c.VELOCITY_CONTROL, targetVelocity=0.0, force=FRICTION[j.type])
        c.changeDynamics(body, k, lateralFriction=0.8, jointDamping=0.05)
    return body


def joint_limits(c, body: int, k: int) -> tuple[float, float]:
    info = c.getJointInfo(body, k)
    return float(info[8]), float(info[9])


def joint_fraction(c, body: int, k: int) -> float:
    """The joint's position as a fraction of its limits: 0 at the lower (closed), 1 at the upper (open)."""
    lo, hi = joint_limits(c, body, k)
    return (float(c.getJointState(body, k)[0]) - lo) / (hi - lo)


def set_joint_fraction(c, body: int, k: int, fraction: float) -> None:
    lo, hi = joint_limits(c, body, k)
    c.resetJointState(body, k, lo + float(fraction) * (hi - lo))


def moving_links(c, body: int) -> list[int]:
    """The body's links on revolute or prismatic joints (a link index is its joint's), in index order."""
    moving = (c.JOINT_REVOLUTE, c.JOINT_PRISMATIC)
    return [k for k in range(c.getNumJoints(body)) if c.getJointInfo(body, k)[2] in moving]


def n_joints(obj) -> int:
    return len(design(obj.shape, obj.size, (0, 0, 0, 1)).joints)


def link_frame(c, body: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """World position and rotation matrix of link k's URDF frame (= its joint's frame)."""
    pos, orn = c.getLinkState(body, k, computeForwardKinematics=True)[4:6]
    return np.asarray(pos), np.asarray(c.getMatrixFromQuaternion(orn)).reshape(3, 3)


def joint_axis_world(c, body: int, k: int) -> tuple[np.ndarray, np.ndarray, str]:
    """The joint's pivot (a point on its axis), unit axis in the world, and type ('revolute' | 'prismatic')."""
    info = c.getJointInfo(body, k)
    pos, rot = link_frame(c, body, k)
    axis = rot @ np.asarray(info[13], float)
    return pos, axis / np.linalg.norm(axis), "revolute" if info[2] == c.JOINT_REVOLUTE else "prismatic"


def grip_points(c, obj, k: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Link k's grip points (point, outward normal) in the world, now."""
    grips = object_design(obj).joints[k].grips
    pos, rot = link_frame(c, obj.body_ids[0], k)
    return [(pos + rot @ np.asarray(p, float), rot @ np.asarray(n, float)) for p, n in grips]
