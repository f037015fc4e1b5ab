"""The Franka Panda with its parallel-jaw gripper (pybullet_data's franka_panda/panda.urdf), driven by absolute
end-effector targets: the robot of the BBSEA suite (spec field `robot: panda`).

It offers what SimEnv uses of the xArm6 `Arm` (state, apply, hold, park, on_step, target) for the `ee_pose`
action space (simeval.sim.action_spaces.ee_pose_action_space):
  action (8,) = [x, y, z (m), qx, qy, qz, qw, gripper]: the pose of the grasp point (`panda_grasptarget`, between
  the finger pads, 1 cm above the finger tips) in the world frame, and the gripper command (>= 0.5: closed).
One `apply` is one control step (4 Hz by default, BBSEA's rate): inverse kinematics of the target once, then the
joint targets move from where the joints are to the solution over the first 3/4 of the physics substeps (a smooth
ramp) and hold for the rest, so the hand reaches the target within the step as BBSEA's controller did, as long as
targets are a few centimetres apart (the primitives in simeval.sim.experts.plan keep them so).

Grasping: the fingers close with a bounded force; PyBullet's friction grasps of small boxes slip under the Panda's
mesh fingers, so when the gripper is commanded closed and both fingers touch the same body (link), that body is
attached to the hand by a fixed constraint (the suction arm's approach, applied to the jaws), and released when the
gripper opens. The check runs at the end of each of the first GRASP_WINDOW control steps after the close
command (closed fingers that press or push do not grasp), from the simulator's state only: a replay of the
same actions attaches at the same step.

State (STATE_NAMES, 16): 7 joint positions (rad), 7 joint velocities (rad/s), the gripper opening (m, the sum of
both finger positions, 0..0.08) and the gripper command in force (0 open, 1 closed).
"""

from __future__ import annotations

import math

import numpy as np

from simeval.sim.core.world import TABLE_Z, World
from simeval.sim.robots import RobotKind
from simeval.sim.robots.xarm import JOINT_LIMIT_MARGIN

PANDA_URDF = "franka_panda/panda.urdf"
# what the Panda is drawn with: "collision" (its collision meshes, ~50x fewer bytes than the visual OBJs: TinyRenderer
# draws a frame several times faster; experiments/benchmarks/collect_bench.py --suite bbsea) or "visual"
RENDER_MESH = "collision"
ARM_JOINTS = tuple(range(7))
FINGER_JOINTS = (9, 10)
GRASP_LINK = 11  # panda_grasptarget
HAND_LINK = 8
# the classic Panda ready pose: grasp point at (0.31, 0, 0.49), pointing down, fingers closing along y
HOME = (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785)
# end of episode: base turned a quarter turn to the right, arm folded up: the hand leaves the workspace's views
PARK = (-1.5, -0.9, 0.0, -2.6, 0.0, 1.8, 0.785)
JOINT_LOWER = (-2.9671, -1.8326, -2.9671, -3.1416, -2.9671, -0.0873, -2.9671)
JOINT_UPPER = (2.9671, 1.8326, 2.9671, 0.0, 2.9671, 3.8223, 2.9671)
PARK_LIFT_Z = 0.3  # m: the grasp point rises to this height before the arm folds away
FINGER_OPEN = 0.04  # per finger (m)
GRIP_FORCE = 40.0  # N per finger
ARM_FORCES = (87.0,) * 4 + (12.0,) * 3  # the URDF's effort limits
GRASP_WINDOW = 2  # control steps after the close command during which a touched body is attached
RAMP = 0.75  # share of a control step over which the joint targets move to the IK solution
DOWN = (1.0, 0.0, 0.0, 0.0)  # xyzw: grasp axis pointing down, yaw 0 (fingers closing along world y)
STATE_NAMES = (*(f"q{i}" for i in range(1, 8)), *(f"dq{i}" for i in range(1, 8)), "gripper_opening",
               "gripper_closed")
# as simeval.sim.env's bounds (the joint-limit margin, velocities); the finger opening (the two finger joints' sum) dips
# a little below 0 when the fingers close on nothing (-0.0007 m seen)
STATE_LOW = np.array([x - JOINT_LIMIT_MARGIN for x in JOINT_LOWER] + [-100.0] * 7 + [-0.005, 0.0], np.float32)
STATE_HIGH = np.array([x + JOINT_LIMIT_MARGIN for x in JOINT_UPPER] + [100.0] * 7 + [0.1, 1.0], np.float32)


def render_urdf(mesh: str = "collision") -> str:
    """The Panda's URDF for loading: pybullet_data's as it is (`visual`), or a copy (written once per process
    in the temp folder) whose visual geometry is the collision meshes (`collision`), as simeval.sim.robots.xarm does
    for the xArm6. Physics is the same either way (collision geometry is untouched)."""
    import os

    import pybullet_data

    if mesh == "visual":
        return PANDA_URDF
    if mesh != "collision":
        raise ValueError(f"mesh={mesh!r}: expected 'collision' or 'visual'")
    src = os.path.join(pybullet_data.getDataPath(), PANDA_URDF)
    with open(src, encoding="utf-8") as f:
        text = f.read()
    text = text.replace("package://meshes/visual/", "package://meshes/collision/")
    text = text.replace("package://meshes/", os.path.join(os.path.dirname(src), "meshes") + os.sep)
    from simeval.sim.core.urdf_files import write_temp_urdf

    return write_temp_urdf(text, "panda-render")


def down_quat(yaw: float) -> np.ndarray:
    """The xyzw quaternion of the hand pointing down, turned by `yaw` about the vertical (fingers close along
    the direction yaw + 90 degrees)."""
    h = yaw / 2
    # rotation by pi about x, then by yaw about world z: q = (cos h, sin h about z) * (1, 0, 0, 0 about x)
    return np.array([math.cos(h), math.sin(h), 0.0, 0.0])


class Panda:

    @property
    def body_ids(self) -> tuple[int, ...]:
        """The bodies that are the robot in a segmentation image: the arm, its hand and fingers are one body."""
        return (self.body,)

    def __init__(self, world: World, home_noise: float = 0.0, rng: np.random.Generator | None = None,
                 render_mesh: str | None = None) -> None:
        self.w, c = world, world.c
        self.body = c.loadURDF(render_urdf(render_mesh or RENDER_MESH), [0, 0, TABLE_Z], useFixedBase=True)
        self.joints = list(ARM_JOINTS)
        home = np.array(HOME) + (rng.normal(0, home_noise, 7) if home_noise and rng is not None else 0.0)
        home = np.clip(home, JOINT_LOWER, JOINT_UPPER)
        for j, q in zip(ARM_JOINTS, home):
            c.resetJointState(self.body, j, float(q))
        for j in FINGER_JOINTS:
            c.resetJointState(self.body, j, FINGER_OPEN)
            c.changeDynamics(self.body, j, lateralFriction=1.0)
        self.home = home
        self.target = home.copy()  # joint targets in force
        self.closed = False  # gripper command in force
        self.closed_steps = 0  # control steps the command has been closed for, in a row
        self.grasp: int | None = None  # constraint id while something is held
        self.held: tuple[int, int] | None = None  # (body, link) held
        self.on_step = None  # callable(action (8,) float32) after every control step (set by the environment)
        self._hold_motors()
        ls = c.getLinkState(self.body, GRASP_LINK)
        self.last_action = np.r_[ls[4], ls[5], 0.0].astype(np.float32)

    # --- state -----------------------------------------------------------------------------------------------
    def state(self) -> np.ndarray:
        s = self.w.c.getJointStates(self.body, self.joints)
        f = self.w.c.getJointStates(self.body, FINGER_JOINTS)
        return np.array([x[0] for x in s] + [x[1] for x in s] + [f[0][0] + f[1][0], float(self.closed)],
                        dtype=np.float32)

    def ee_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Position and xyzw quaternion of the grasp point."""
        ls = self.w.c.getLinkState(self.body, GRASP_LINK, computeForwardKinematics=True)
        return np.asarray(ls[4]), np.asarray(ls[5])

    def joint_positions(self) -> np.ndarray:
        return np.array([s[0] for s in self.w.c.getJointStates(self.body, self.joints)])

    # --- control -----------------------------------------------------------------------------------------------
    def ik(self, pos, quat) -> np.ndarray:
        c = self.w.c
        lower, upper = list(JOINT_LOWER) + [0.0, 0.0], list(JOINT_UPPER) + [FINGER_OPEN] * 2
        q = c.calculateInverseKinematics(self.body, GRASP_LINK, list(map(float, pos)), list(map(float, quat)),
                                         lowerLimits=lower, upperLimits=upper,
                                         jointRanges=[u - l for l, u in zip(lower, upper)],
                                         restPoses=list(self.home) + [FINGER_OPEN] * 2,
                                         maxNumIterations=100, residualThreshold=1e-5)
        return np.clip(np.asarray(q[:7]), JOINT_LOWER, JOINT_UPPER)

    def apply(self, action: np.ndarray) -> np.ndarray:
        """One control step towards the 8-d ee_pose target; returns the action as applied (float32, quaternion
        normalised, gripper 0/1), which replays bit for bit."""
        a = np.asarray(action, np.float32).reshape(-1)
        if a.shape != (8,):
            raise ValueError(f"an ee_pose action has 8 values (xyz, quaternion xyzw, gripper), got shape {a.shape}")
        quat = a[3:7].astype(np.float64)
        norm = float(np.linalg.norm(quat))
        if abs(norm - 1.0) > 1e-5:  # an applied (already unit) quaternion passes unchanged: replays bit for bit
            quat = quat / norm if norm > 1e-6 else np.asarray(DOWN)
        a = np.r_[a[:3], quat, np.float32(a[7] >= 0.5)].astype(np.float32)
        goal = self.ik(a[:3].astype(np.float64), a[3:7].astype(np.float64))
        self._run(goal, bool(a[7]))
        self.last_action = a
        if self.on_step is not None:
            self.on_step(a)
        return a

    def _run(self, goal: np.ndarray, closed: bool) -> None:
        """One control step of physics: joint targets ramp from the current positions to `goal`, the gripper
        goes to its command, then the grasp is attached or released."""
        c, n = self.w.c, self.w.substeps
        self.closed = closed
        self.closed_steps = self.closed_steps + 1 if closed else 0
        if not closed and self.grasp is not None:
            self._release()
        start = self.joint_positions()
        ramp = max(1, int(n * RAMP))
        for k in range(1, n + 1):
            a = min(1.0, k / ramp)
            self.target = start + (goal - start) * (3 * a * a - 2 * a * a * a)
            self._hold_motors()
            c.stepSimulation()
        # only while the jaws are closing (the first GRASP_WINDOW steps closed): pressing a button or pushing a
        # block with the closed fingers must not pick it up
        if closed and self.grasp is None and self.closed_steps <= GRASP_WINDOW:
            self._attach()

    def _hold_motors(self) -> None:
        c = self.w.c
        c.setJointMotorControlArray(self.body, self.joints, c.POSITION_CONTROL, targetPositions=self.target.tolist(),
                                    forces=list(ARM_FORCES), positionGains=[0.2] * 7)
        finger = 0.0 if self.closed else FINGER_OPEN
        c.setJointMotorControlArray(self.body, list(FINGER_JOINTS), c.POSITION_CONTROL, targetPositions=[finger] * 2,
                                    forces=[GRIP_FORCE] * 2, positionGains=[0.2] * 2)

    def touching(self) -> tuple[int, int] | None:
        """The (body, link) both fingers touch, if any (not the robot, not the floor)."""
        c = self.w.c
        per_finger = []
        for link in FINGER_JOINTS:
            per_finger.append({(cp[2], cp[4]) for cp in c.getContactPoints(bodyA=self.body, linkIndexA=link)
                               if cp[2] not in (self.body, self.w.plane)})
        both = per_finger[0] & per_finger[1]
        return min(both) if both else None

    def _attach(self) -> None:
        c = self.w.c
        hit = self.touching()
        if hit is None:
            return
        body, link = hit
        hand = c.getLinkState(self.body, HAND_LINK)[:2]  # its centre of mass frame: constraints are relative to it
        held = c.getBasePositionAndOrientation(body) if link == -1 else c.getLinkState(body, link)[:2]
        self.grasp = self.w.weld(self.body, HAND_LINK, hand, body, link, held)
        self.held = hit

    def _release(self) -> None:
        self.w.c.removeConstraint(self.grasp)
        self.grasp, self.held = None, None

    def hold(self, steps: int) -> None:
        """Repeat the last target for `steps` control steps (each logged like any other)."""
        for _ in range(steps):
            self.apply(self.last_action)

    def park(self, steps: int = 6) -> None:
        """Out of the cameras' view at the end of an episode: the joints move smoothly to PARK over `steps`
        control steps, gripper open. Called by the environment inside the step that ends the episode, so a
        replay of the same actions parks the same way. Not logged as ee_pose actions (it is not one)."""
        c = self.w.c
        if self.grasp is not None:  # what it holds stays where it is
            self._release()
            self.closed = False
        # first straight up (the hand may still be around what it just let go of or pushed), then the joints to
        # PARK; closed fingers open only up there: opening them beside a block just pushed kicks it (a block of
        # friction 0.3 flew 0.8 m off the table)
        pos, quat = self.ee_pose()
        for z in np.linspace(pos[2], max(pos[2], PARK_LIFT_Z), 3)[1:]:
            self._run(self.ik(np.r_[pos[:2], z], quat), self.closed)
        self.closed = False
        start, n = self.joint_positions(), max(1, steps) * self.w.substeps
        for k in range(1, n + 1):
            a = k / n
            self.target = start + (np.asarray(PARK) - start) * (3 * a * a - 2 * a * a * a)
            self._hold_motors()
            c.stepSimulation()


ROBOT = RobotKind("panda", ("ee_pose",), STATE_NAMES, STATE_LOW, STATE_HIGH,
                  lambda world, spec, home_noise, rng: Panda(world, home_noise, rng))
