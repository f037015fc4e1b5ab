"""The arm: an xArm6 from pybullet_data (6 joint positions + 6 velocities = the 12-d state the paper's authors
logged for the UR5), driven top-down by inverse kinematics, with a suction cup (a fixed constraint on contact,
as Ravens/GenSim) or a spatula for pushing piles. Motions are Cartesian straight lines executed at the control
rate.

The low-level action (kind `joint_pos+suction`, 7-d): the 6 joint position targets (rad) and the suction command
(1 = on, 0 = off). `Arm.apply` is the one low-level step every path goes through (a learned policy through the
environment, the oracle's primitives, a replay): it applies the suction command to the current state (on and
nothing held: attach what the cup touches, if anything; off: release), sends the joint targets, and runs physics
for one control period. The spatula has no actuation: its tasks use the same 7-d action with the suction channel
always 0 (a 1 is ignored). The state (14-d): 6 joint positions, 6 joint velocities (the 12-d state the authors
logged), the suction command in force (0/1) and whether an object is held (0/1)."""

from __future__ import annotations

import math
import re

import numpy as np

from simeval.sim.core.world import TABLE_Z, World
from simeval.sim.robots import RobotKind

HOME = (0.0, -0.35, -0.9, 0.0, 1.25, 0.0)  # joints: tool above the workspace, pointing down
# joints: out of every camera's view of the workspace at the end of an episode (see Arm.park): the base turned
# half a turn so the arm points away from the workspace (x < 0), folded up behind the base; from the front camera
# it sits behind its own base, the top camera does not see it at all (tested in tests/test_sim_look.py)
PARK = (math.pi, -0.35, -0.9, 0.0, 1.25, 0.0)
TOOL_LENGTH = {"suction": 0.06, "spatula": 0.09}
# The blade's commanded height above the table during a push. The arm tracks about 3 mm above its target here, so
# 4 mm (as before) ran the blade at 7-8 mm, above the middle of the 1 cm particles: it tipped them over instead of
# sliding them, passed over them, and the oracle repeated the same push (sweep-pile-* failed 1-4 of 7 seeds).
# 1 mm runs it at about 4 mm, below their middle.
BLADE_Z = 0.001
ARM_URDF = "xarm/xarm6_robot_white.urdf"
RENDER_MESH = "collision"  # what Arm draws by default: "collision" (fast) or "visual" (pybullet_data's STLs)
SAFE_Z = 0.16  # tool-tip height for moves across the workspace
# joint limits of pybullet_data's xarm6_robot_white.urdf (rad), the bounds of the joint action space
JOINT_LOWER = (-6.28318530718, -2.059, -3.927, -6.28318530718, -1.69297, -6.28318530718)
JOINT_UPPER = (6.28318530718, 2.0944, 0.19198, 6.28318530718, 3.14159265359, 6.28318530718)
# How far past its limits a joint is observed (the observation spaces' bounds, simeval.sim.env and .panda): PyBullet's
# joint limits are soft, and seeded random actions drive joints past them by up to 0.19 rad (xArm6, joint targets)
# and 0.12 rad (Panda, ee_pose targets; tests/test_env.py samples such steps). The 0.1 used before let gymnasium's
# checker fail now and then on an observation outside the space.
JOINT_LIMIT_MARGIN = 0.3
JOINT_ACTION_NAMES = ("joint1", "joint2", "joint3", "joint4", "joint5", "joint6", "suction")
STATE_NAMES = (*(f"q{i}" for i in range(1, 7)), *(f"dq{i}" for i in range(1, 7)), "suction", "holding")
# state bounds: the joint limits with a margin, |velocity| <= 100 rad/s (PyBullet's default maximum joint velocity),
# flags in [0, 1]
STATE_LOW = np.array([x - JOINT_LIMIT_MARGIN for x in JOINT_LOWER] + [-100.0] * 6 + [0.0, 0.0], np.float32)
STATE_HIGH = np.array([x + JOINT_LIMIT_MARGIN for x in JOINT_UPPER] + [100.0] * 6 + [1.0, 1.0], np.float32)


def render_urdf(mesh: str = "collision") -> str:
    """The arm's URDF for loading. `mesh="collision"` writes (once per process, in the temp folder) a copy whose
    visual geometry points at the collision meshes (convex decompositions, about 100x fewer triangles than the
    visual STLs): TinyRenderer then draws the arm several times faster and the image barely changes (the
    collection benchmark measures both). `mesh="visual"` returns pybullet_data's URDF as it is."""
    import os

    import pybullet_data

    if mesh == "visual":
        return ARM_URDF
    if mesh != "collision":
        raise ValueError(f"mesh={mesh!r}: expected 'collision' or 'visual'")
    src = os.path.join(pybullet_data.getDataPath(), ARM_URDF)
    with open(src, encoding="utf-8") as f:  # closed here: an unclosed file warns at exit (a "Traceback" in logs)
        text = f.read()
    meshes = os.path.join(os.path.dirname(src), "xarm_description") + os.sep
    # each <visual> mesh <X>.stl -> the link's collision mesh; package:// paths made absolute (the copy lives
    # outside pybullet_data)
    text = re.sub(r"package://xarm_description/meshes/xarm6/visual/(\w+)\.stl",
                  r"package://xarm_description/meshes/xarm6/collision/\1_vhacd.obj", text)
    text = text.replace("package://xarm_description/", meshes)
    from simeval.sim.core.urdf_files import write_temp_urdf

    return write_temp_urdf(text, "xarm6-render")


class Arm:
    def __init__(self, world: World, end_effector: str = "suction", home_noise: float = 0.0,
                 rng: np.random.Generator | None = None, render_mesh: str | None = None) -> None:
        if end_effector not in TOOL_LENGTH:
            raise ValueError(f"end_effector={end_effector!r}: expected one of {', '.join(TOOL_LENGTH)}")
        self.w, c = world, world.c
        self.body = c.loadURDF(render_urdf(render_mesh or RENDER_MESH), [0, 0, TABLE_Z], useFixedBase=True)
        self.joints = [j for j in range(c.getNumJoints(self.body)) if c.getJointInfo(self.body, j)[2] == c.JOINT_REVOLUTE]
        self.ee = self.joints[-1]
        self.lower = [c.getJointInfo(self.body, j)[8] for j in self.joints]
        self.upper = [c.getJointInfo(self.body, j)[9] for j in self.joints]
        home = np.array(HOME) + (rng.normal(0, home_noise, 6) if home_noise and rng is not None else 0.0)
        for j, q in zip(self.joints, home):
            c.resetJointState(self.body, j, float(q))
        self.home = home
        self.kind, self.tool_length = end_effector, TOOL_LENGTH[end_effector]
        self.tool = self._make_tool()
        self.target = np.array(home, dtype=float)
        self.grasp = None  # constraint id while something is held
        self.held: int | None = None
        self.held_link: int = -1  # the moving link held (articulated objects), -1: a whole body
        self.suction_cmd = False  # the suction command in force (applied by the next low-level step)
        self.on_step = None  # callable(action (7,) float32) after every low-level step (set by the environment)

    @property
    def body_ids(self) -> tuple[int, ...]:
        """The bodies that are the robot in a segmentation image: the arm and its tool (suction cup or spatula)."""
        return (self.body, self.tool)

    def _make_tool(self) -> int:
        c = self.w.c
        if self.kind == "suction":
            col = c.createCollisionShape(c.GEOM_CYLINDER, radius=0.012, height=self.tool_length)
            vis = c.createVisualShape(c.GEOM_CYLINDER, radius=0.012, length=self.tool_length, rgbaColor=[0.2, 0.2, 0.2, 1])
        else:
            half = [0.005, 0.05, self.tool_length / 2]  # a blade across y, pushing along x
            col = c.createCollisionShape(c.GEOM_BOX, halfExtents=half)
            vis = c.createVisualShape(c.GEOM_BOX, halfExtents=half, rgbaColor=[0.3, 0.3, 0.35, 1])
        pos, orn = c.getLinkState(self.body, self.ee)[4:6]
        tool = c.createMultiBody(0.05, col, vis, pos, orn)
        # constraint frames are relative to the link's centre of mass, not its URDF frame: convert the offset
        com_pos, com_orn = c.getDynamicsInfo(self.body, self.ee)[3:5]
        inv_pos, inv_orn = c.invertTransform(com_pos, com_orn)
        in_com, orn_com = c.multiplyTransforms(inv_pos, inv_orn, [0, 0, self.tool_length / 2], [0, 0, 0, 1])
        c.createConstraint(self.body, self.ee, tool, -1, c.JOINT_FIXED, [0, 0, 0], in_com, [0, 0, 0], orn_com)
        c.setCollisionFilterPair(self.body, tool, self.ee, -1, 0)
        return tool

    # --- state -----------------------------------------------------------------------------------------------
    def state(self) -> np.ndarray:
        s = self.w.c.getJointStates(self.body, self.joints)
        ee = [float(self.suction_cmd), float(self.held is not None)]
        return np.array([x[0] for x in s] + [x[1] for x in s] + ee, dtype=np.float32)

    def tip(self) -> np.ndarray:
        c = self.w.c
        pos, orn = c.getLinkState(self.body, self.ee)[4:6]
        down = np.array(c.getMatrixFromQuaternion(orn)).reshape(3, 3)[:, 2]
        return np.asarray(pos) + self.tool_length * down

    # --- control -------------------------------------------------------------------------------------------
    def _ik(self, tip: np.ndarray, yaw: float) -> np.ndarray:
        c = self.w.c
        orn = c.getQuaternionFromEuler([math.pi, 0.0, yaw])
        flange = np.asarray(tip) + np.array([0.0, 0.0, self.tool_length])
        q = c.calculateInverseKinematics(self.body, self.ee, flange.tolist(), orn, lowerLimits=self.lower,
                                         upperLimits=self.upper, jointRanges=[u - l for l, u in zip(self.lower, self.upper)],
                                         restPoses=list(self.home), maxNumIterations=100, residualThreshold=1e-5)
        return np.asarray(q[: len(self.joints)])

    def apply(self, action: np.ndarray) -> np.ndarray:
        """One low-level step: the suction command, the joint targets, one control period of physics. The action
        is clipped to the joint limits and cast to float32 first, so that a stored action replays bit for bit.
        Returns the action as applied."""
        c = self.w.c
        a = np.asarray(action, np.float32).reshape(-1)
        if a.shape != (7,):
            raise ValueError(f"a joint action has 7 values (6 joint targets, suction), got shape {a.shape}")
        a = np.r_[np.clip(a[:6], JOINT_LOWER, JOINT_UPPER), np.float32(a[6] >= 0.5)].astype(np.float32)
        self.suction_cmd = bool(a[6]) and self.kind == "suction"
        if not self.suction_cmd:
            a[6] = 0.0
            if self.grasp is not None:
                self._release()
        elif self.grasp is None:
            self._attach()
        q = a[:6].astype(np.float64)
        self.target = q
        c.setJointMotorControlArray(self.body, self.joints, c.POSITION_CONTROL, targetPositions=q.tolist(),
                                    forces=[300.0] * len(self.joints), positionGains=[0.3] * len(self.joints))
        self.w.step()
        if self.on_step is not None:
            self.on_step(a)
        return a

    def _command(self, q: np.ndarray) -> None:
        self.apply(np.r_[q, float(self.suction_cmd)])

    def move(self, tip: np.ndarray, yaw: float, speed: float = 0.4, settle_tol: float = 0.004,
             stop_on_contact: bool = False) -> bool:
        """Straight line to `tip` (tool tip position) at `speed` m/s. Returns True if contact stopped it."""
        start = self.tip()
        dist = float(np.linalg.norm(np.asarray(tip) - start))
        n = max(1, int(math.ceil(dist / (speed / self.w.control_hz))))
        for k in range(1, n + 1):
            self._command(self._ik(start + (np.asarray(tip) - start) * k / n, yaw))
            if stop_on_contact and self.touching() is not None:
                return True
        for _ in range(15):  # let the joints catch up with the last target
            if np.linalg.norm(self.tip() - np.asarray(tip)) < settle_tol:
                break
            if stop_on_contact and self.touching() is not None:
                return True
            self._command(self.target)
        return False

    def touching(self) -> int | None:
        """The body the tool touches (not the arm, not the table), if any."""
        hit = self.touching_link()
        return None if hit is None else hit[0]

    def touching_link(self) -> tuple[int, int] | None:
        """(body, link) the tool touches (not the arm, not the table), if any."""
        for cp in self.w.c.getContactPoints(bodyA=self.tool):
            if cp[2] not in (self.body, self.w.plane):
                return cp[2], cp[4]
        return None

    def ik_pose(self, tip: np.ndarray, orn) -> np.ndarray:
        """Joint targets that put the tool tip at `tip` with the tool's frame at quaternion `orn` (xyzw; the tool
        points along its z axis: (pi, 0, yaw) Euler angles point it down)."""
        c = self.w.c
        down = np.asarray(c.getMatrixFromQuaternion(orn)).reshape(3, 3)[:, 2]
        flange = np.asarray(tip, float) - self.tool_length * down
        q = c.calculateInverseKinematics(self.body, self.ee, flange.tolist(), list(orn), lowerLimits=self.lower,
                                         upperLimits=self.upper, jointRanges=[u - l for l, u in zip(self.lower, self.upper)],
                                         restPoses=list(self.home), maxNumIterations=100, residualThreshold=1e-5)
        return np.asarray(q[: len(self.joints)])

    def suction_on(self) -> bool:
        """Turn the suction on if the cup touches something and attach it now; otherwise leave it off. Returns
        whether it holds. The command stays on for the next low-level steps, whose `apply` finds it met (the same
        attach `apply` would make on this state: a replay of the recorded actions attaches at the same step)."""
        if self.kind != "suction" or self.touching() is None:
            return False
        self.suction_cmd = True
        if self.grasp is None:
            self._attach()
        return True

    def suction_off(self) -> None:
        """Turn the suction off and release what is held, now (as `apply` with the command off would)."""
        self.suction_cmd = False
        if self.grasp is not None:
            self._release()

    def _attach(self) -> None:
        c = self.w.c
        hit = self.touching_link()
        if hit is None:
            return
        other, link = hit
        if link >= 0 and c.getJointInfo(other, link)[2] != c.JOINT_FIXED:
            self._attach_link(other, link)
            return
        self.grasp = self.w.weld(self.tool, -1, c.getBasePositionAndOrientation(self.tool), other, -1,
                                 c.getBasePositionAndOrientation(other))
        self.held = other

    def _attach_link(self, body: int, link: int) -> None:
        """Grip a moving link of an articulated object: a point constraint at the cup's tip (the seal turns freely,
        so the tool can stay pointing down while a lid or door turns under it), and no contact between the cup and
        that link while it holds (the point constraint stands in for the seal; contact would fight it as the
        surface turns)."""
        c = self.w.c
        tp, to = c.getBasePositionAndOrientation(self.tool)
        tip = self.tip()
        inv_p, inv_o = c.invertTransform(tp, to)
        in_tool, _ = c.multiplyTransforms(inv_p, inv_o, tip.tolist(), [0, 0, 0, 1])
        lp, lo = c.getLinkState(body, link, computeForwardKinematics=True)[0:2]  # the link's centre-of-mass frame
        inv_p, inv_o = c.invertTransform(lp, lo)
        in_link, _ = c.multiplyTransforms(inv_p, inv_o, tip.tolist(), [0, 0, 0, 1])
        self.grasp = c.createConstraint(self.tool, -1, body, link, c.JOINT_POINT2POINT, [0, 0, 0], in_tool, in_link)
        c.changeConstraint(self.grasp, maxForce=200)
        c.setCollisionFilterPair(self.tool, body, -1, link, 0)
        self.held, self.held_link = body, link

    def _release(self) -> None:
        self.w.c.removeConstraint(self.grasp)
        if self.held_link >= 0:
            self.w.c.setCollisionFilterPair(self.tool, self.held, -1, self.held_link, 1)
        self.grasp, self.held, self.held_link = None, None, -1

    def hold(self, steps: int) -> None:
        for _ in range(steps):
            self._command(self.target)

    def park(self, steps: int = 45) -> None:
        """Move out of the cameras' view to PARK, so that the last frames of an episode show the result instead
        of the arm above the last object. Two joint-space moves, each control step logged like any other: first
        fold up (every joint but the base to PARK, a third of `steps`), then turn the base half a turn (the rest),
        so the tool never sweeps low over the objects. Call at the end of an episode, with nothing held."""
        q = np.array([s[0] for s in self.w.c.getJointStates(self.body, self.joints)])
        base = PARK[0] if abs(PARK[0] - q[0]) <= abs(-PARK[0] - q[0]) else -PARK[0]  # the shorter way round
        folded = np.r_[q[0], PARK[1:]]
        goal = np.r_[base, PARK[1:]]
        n1 = max(1, steps // 3)
        for start, end, n in ((q, folded, n1), (folded, goal, max(1, steps - n1))):
            for k in range(1, n + 1):
                a = k / n
                self._command(start + (end - start) * (3 * a * a - 2 * a * a * a))  # smooth start and stop

    # --- primitives of the 14-d action (see simeval.sim.env for the convention) -----------------------------
    def pick_place(self, pose14: np.ndarray) -> bool:
        """Ravens' pick-and-place: above the pick point, down until the cup touches, suction on, up, over the
        place point at its yaw, down until the pick point is at the place position, suction off, up. Returns
        whether something was picked."""
        from simeval.sim.core.world import yaw_of

        a = np.asarray(pose14, np.float64)
        p0, yaw0, p1, yaw1 = a[0:3], yaw_of(a[3:7]), a[7:10], yaw_of(a[10:14])
        self.move(np.r_[p0[:2], SAFE_Z], yaw0, speed=0.6)
        self.move(np.r_[p0[:2], p0[2] + 0.03], yaw0, speed=0.3)
        self.move(np.r_[p0[:2], p0[2] - 0.02], yaw0, speed=0.08, stop_on_contact=True)
        if not self.suction_on():
            self.move(np.r_[p0[:2], SAFE_Z], yaw0)
            return False
        self.move(np.r_[p0[:2], SAFE_Z], yaw0, speed=0.3)
        tip_z = p1[2] + 0.006  # a few mm above the target: the object settles the rest of the way
        self.move(np.r_[p1[:2], SAFE_Z], yaw1, speed=0.6)
        self.move(np.r_[p1[:2], tip_z + 0.03], yaw1, speed=0.3)
        self.move(np.r_[p1[:2], tip_z], yaw1, speed=0.08)
        self.suction_off()
        self.hold(6)
        self.move(np.r_[p1[:2], SAFE_Z], yaw1, speed=0.3)
        return True

    def push(self, pose14: np.ndarray) -> bool:
        """A spatula push from pose0's xy to pose1's xy (z ignored: the blade runs along the table), the blade
        across the direction of the push."""
        a = np.asarray(pose14, np.float64)
        start, end = a[0:2], a[7:9]
        d = end - start
        yaw = (math.atan2(d[1], d[0]) + math.pi / 2) % math.pi - math.pi / 2  # the blade is symmetric
        z = TABLE_Z + BLADE_Z
        self.move(np.r_[start, SAFE_Z], yaw, speed=0.6)
        self.move(np.r_[start, z], yaw, speed=0.3)
        self.move(np.r_[end, z], yaw, speed=0.15)
        self.move(np.r_[end, SAFE_Z], yaw, speed=0.4)
        return True


ROBOT = RobotKind("xarm6", ("joint", "pick_place", "ee_delta"), STATE_NAMES, STATE_LOW, STATE_HIGH,
                  lambda world, spec, home_noise, rng: Arm(world, spec.end_effector, home_noise, rng))
