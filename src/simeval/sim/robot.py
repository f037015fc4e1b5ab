"""The arm: an xArm6 from pybullet_data (6 joint positions + 6 velocities = the 12-d state the paper's authors
logged for the UR5), driven top-down by inverse kinematics, with a suction cup (a fixed constraint on contact,
as Ravens/GenSim) or a spatula for pushing piles. Motions are Cartesian straight lines executed at the control
rate; each control step calls the world's logger with the joint targets as the low-level action."""

from __future__ import annotations

import math
import re

import numpy as np

from simeval.sim.world import TABLE_Z, World

HOME = (0.0, -0.35, -0.9, 0.0, 1.25, 0.0)  # joints: tool above the workspace, pointing down
# joints: out of every camera's view of the workspace at the end of an episode (see Arm.park): the base turned
# half a turn so the arm points away from the workspace (x < 0), folded up behind the base; from the front camera
# it sits behind its own base, the top camera does not see it at all (tested in tests/test_sim_look.py)
PARK = (math.pi, -0.35, -0.9, 0.0, 1.25, 0.0)
TOOL_LENGTH = {"suction": 0.06, "spatula": 0.09}
ARM_URDF = "xarm/xarm6_robot_white.urdf"
RENDER_MESH = "collision"  # what Arm draws by default: "collision" (fast) or "visual" (pybullet_data's STLs)


def render_urdf(mesh: str = "collision") -> str:
    """The arm's URDF for loading. `mesh="collision"` writes (once per process, in the temp folder) a copy whose
    visual geometry points at the collision meshes (convex decompositions, about 100x fewer triangles than the
    visual STLs): TinyRenderer then draws the arm several times faster and the image barely changes (the
    collection benchmark measures both). `mesh="visual"` returns pybullet_data's URDF as it is."""
    import hashlib
    import os
    import tempfile

    import pybullet_data

    if mesh == "visual":
        return ARM_URDF
    if mesh != "collision":
        raise ValueError(f"mesh={mesh!r}: expected 'collision' or 'visual'")
    src = os.path.join(pybullet_data.getDataPath(), ARM_URDF)
    text = open(src, encoding="utf-8").read()
    meshes = os.path.join(os.path.dirname(src), "xarm_description") + os.sep
    # each <visual> mesh <X>.stl -> the link's collision mesh; package:// paths made absolute (the copy lives
    # outside pybullet_data)
    text = re.sub(r"package://xarm_description/meshes/xarm6/visual/(\w+)\.stl",
                  r"package://xarm_description/meshes/xarm6/collision/\1_vhacd.obj", text)
    text = text.replace("package://xarm_description/", meshes)
    out = os.path.join(tempfile.gettempdir(), f"simeval-xarm6-render-{hashlib.sha1(text.encode()).hexdigest()[:12]}.urdf")
    if not os.path.exists(out):
        tmp = f"{out}.{os.getpid()}.tmp"
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, out)  # atomic: parallel workers never read a half-written file
    return out


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
        self.logger = None  # callable(action (6,)) set by the episode runner

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
        return np.array([x[0] for x in s] + [x[1] for x in s], dtype=np.float32)

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

    def _command(self, q: np.ndarray) -> None:
        c = self.w.c
        self.target = q
        c.setJointMotorControlArray(self.body, self.joints, c.POSITION_CONTROL, targetPositions=q.tolist(),
                                    forces=[300.0] * len(self.joints), positionGains=[0.3] * len(self.joints))
        self.w.step()
        if self.logger is not None:
            self.logger(q.astype(np.float32))

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
        for cp in self.w.c.getContactPoints(bodyA=self.tool):
            if cp[2] not in (self.body, self.w.plane):
                return cp[2]
        return None

    def suction_on(self) -> bool:
        c = self.w.c
        other = self.touching()
        if other is None or self.kind != "suction":
            return False
        tp, to = c.getBasePositionAndOrientation(self.tool)
        op, oo = c.getBasePositionAndOrientation(other)
        inv_p, inv_o = c.invertTransform(tp, to)
        rel_p, rel_o = c.multiplyTransforms(inv_p, inv_o, op, oo)
        self.grasp = c.createConstraint(self.tool, -1, other, -1, c.JOINT_FIXED, [0, 0, 0], rel_p, [0, 0, 0],
                                        rel_o, [0, 0, 0, 1])
        c.changeConstraint(self.grasp, maxForce=200)
        self.held = other
        return True

    def suction_off(self) -> None:
        if self.grasp is not None:
            self.w.c.removeConstraint(self.grasp)
        self.grasp, self.held = None, None

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
