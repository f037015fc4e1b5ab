"""The action spaces an episode can be recorded in, as the descriptions stored with it (attrs action_space):
kind, dimension names, units, control rate. The conventions are documented in simeval.sim.env. A reader never mixes
two kinds in one training set (simeval.episodes.store.iter_windows). No gymnasium or PyBullet needed here."""

from __future__ import annotations

import numpy as np

from simeval.sim.robots.xarm import JOINT_ACTION_NAMES, JOINT_LOWER, JOINT_UPPER

JOINT_KIND, PICK_PLACE_KIND, EE_POSE_KIND = "joint_pos+suction", "pick_place_14d", "ee_pose+gripper"
EE_POSE_NAMES = ("x", "y", "z", "qx", "qy", "qz", "qw", "gripper")
EE_POSE_HZ = 4.0  # BBSEA's end-effector control rate
# bounds of the ee_pose action: a box around the workspace and the drawer cabinet, quaternion components in [-1, 1]
EE_POSE_LOW = np.array([-0.2, -0.6, 0.0, -1, -1, -1, -1, 0.0], np.float32)
EE_POSE_HIGH = np.array([0.9, 0.6, 0.8, 1, 1, 1, 1, 1.0], np.float32)
POSE14_NAMES = ("pose0_x", "pose0_y", "pose0_z", "pose0_qx", "pose0_qy", "pose0_qz", "pose0_qw",
                "pose1_x", "pose1_y", "pose1_z", "pose1_qx", "pose1_qy", "pose1_qz", "pose1_qw")
# bounds of the pick_place action: positions inside a box around the workspace, quaternion components in [-1, 1]
POSE_LOW = np.array([0.1, -0.5, -0.05, -1, -1, -1, -1] * 2, np.float32)
POSE_HIGH = np.array([0.9, 0.5, 0.4, 1, 1, 1, 1] * 2, np.float32)


def joint_action_space(control_hz: float) -> dict:
    """The description stored with every low-level episode (and what a reader compares before mixing)."""
    return {"kind": JOINT_KIND, "dims": list(JOINT_ACTION_NAMES), "units": ["rad"] * 6 + ["on=1/off=0"],
            "control_hz": float(control_hz), "low": [*JOINT_LOWER, 0.0], "high": [*JOINT_UPPER, 1.0]}


def pick_place_action_space(control_hz: float | None = None) -> dict:
    """One pick-and-place (or push) per step; `control_hz` is the low-level rate the primitive ran at, if any."""
    return {"kind": PICK_PLACE_KIND, "dims": list(POSE14_NAMES), "units": (["m"] * 3 + ["quat_xyzw"] * 4) * 2,
            "control_hz": None if control_hz is None else float(control_hz),
            "convention": "Ravens: pose0 = pick point (push start), pose1 = place point of the grasp (push end)"}




EE_DELTA_KIND = "ee_delta+suction"
EE_DELTA_NAMES = ("dx", "dy", "dz", "droll", "dpitch", "dyaw", "suction")
# per-control-step bounds of ee_delta (at 30 Hz: 0.3 m/s and 1.5 rad/s at most): RoboGen's end-effector deltas are
# small per step; these keep one step inside what the arm follows in one control period
EE_MAX_TRANSLATION = 0.01  # m per step
EE_MAX_ROTATION = 0.05  # rad per step
EE_LOW = np.array([-EE_MAX_TRANSLATION] * 3 + [-EE_MAX_ROTATION] * 3 + [0.0], np.float32)
EE_HIGH = np.array([EE_MAX_TRANSLATION] * 3 + [EE_MAX_ROTATION] * 3 + [1.0], np.float32)


def ee_delta_action_space(control_hz: float) -> dict:
    """End-effector deltas with suction (RoboGen's low-level action), per control step; see simeval.sim.env."""
    return {"kind": EE_DELTA_KIND, "dims": list(EE_DELTA_NAMES), "units": ["m"] * 3 + ["rad"] * 3 + ["on=1/off=0"],
            "control_hz": float(control_hz), "low": EE_LOW.tolist(), "high": EE_HIGH.tolist(),
            "convention": "tool tip translation in the world frame; rotation: a small rotation about the world x, y, "
                          "z axes (Euler XYZ of the increment) applied to the commanded tool orientation; both "
                          "clipped to low/high; the commanded pose is integrated and reached by IK"}


def ee_pose_action_space(control_hz: float = EE_POSE_HZ) -> dict:
    """The Panda's absolute end-effector target per control step (simeval.sim.robots.panda): grasp-point position,
    orientation, gripper command."""
    return {"kind": EE_POSE_KIND, "dims": list(EE_POSE_NAMES), "units": ["m"] * 3 + ["quat_xyzw"] * 4 + ["closed=1/open=0"],
            "control_hz": float(control_hz), "low": EE_POSE_LOW.tolist(), "high": EE_POSE_HIGH.tolist(),
            "frame": "world; the pose of panda_grasptarget (between the finger pads)"}
