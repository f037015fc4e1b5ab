"""The robot registry (simeval.sim.robots): a robot is one file of that package defining ROBOT = RobotKind(...);
the task spec's `robot:` is checked against what the registry finds, and the environment builds the robot, bounds
its state and checks its action space from the registry alone."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml

import simeval.sim.robots as robots
from simeval.errors import UserError
from simeval.sim.env import make_env, state_names
from simeval.sim.tasks.spec import suite_dir, SpecError, parse_spec

TOY = '''
from simeval.sim.robots import RobotKind
from simeval.sim.robots.xarm import STATE_HIGH, STATE_LOW, STATE_NAMES, Arm


class ToyArm(Arm):
    """An xArm6 under another name that takes joint targets only."""


ROBOT = RobotKind("toy_arm", ("joint",), STATE_NAMES, STATE_LOW, STATE_HIGH,
                  lambda world, spec, home_noise, rng: ToyArm(world, spec.end_effector, home_noise, rng))
'''


@pytest.fixture
def toy_robot(tmp_path, monkeypatch):
    (tmp_path / "toy_arm.py").write_text(TOY)
    monkeypatch.setattr(robots, "__path__", [*robots.__path__, str(tmp_path)])
    robots.robot_kinds.cache_clear()
    yield
    robots.robot_kinds.cache_clear()


def test_the_two_robots_of_the_suites_are_registered_with_their_action_spaces_and_state():
    kinds = robots.robot_kinds()
    assert sorted(kinds) == ["panda", "xarm6"]
    assert kinds["panda"].action_spaces == ("ee_pose",)
    assert kinds["xarm6"].action_spaces == ("joint", "pick_place", "ee_delta")
    assert len(state_names("panda")) == 16 and len(state_names("xarm6")) == 14
    for kind in kinds.values():
        assert kind.state_low.shape == kind.state_high.shape == (len(kind.state_names),)
        assert np.all(kind.state_low < kind.state_high)


def test_a_new_robot_is_one_file_that_specs_name_and_the_environment_builds(toy_robot):
    data = yaml.safe_load((suite_dir("gensim") / "build-bridge.yaml").read_text())
    spec = parse_spec({**data, "robot": "toy_arm", "action_space": "joint"}, "toy")
    env = make_env(spec, image_size=(16, 16), cameras=("top",))
    try:
        obs, _ = env.reset(seed=0)
        assert type(env.arm).__name__ == "ToyArm"
        assert obs["state"].shape == (14,) and env.observation_space["state"].contains(obs["state"])
        obs, *_ = env.step(env.action_space.sample())
        assert obs["state"].shape == (14,)
    finally:
        env.close()
    with pytest.raises(UserError, match=r"robot toy_arm\) takes joint"):
        make_env(dataclasses.replace(spec), "pick_place")
    with pytest.raises(SpecError, match="robot 'crane' is not one of panda, toy_arm, xarm6"):
        parse_spec({**data, "robot": "crane"}, "toy")
