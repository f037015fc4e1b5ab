"""The state-space reading of dynamics diversity (simeval.measures.dynamics_diversity.state_reading): baselines
computed by hand, the validation split never touches an evaluated episode, and hand-built groups whose answer is known:
a fixed linear response to the actions is learned and reads, the same response with its sign drawn per episode reads as
more diverse, and a state that is noise at every step gets no reading."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from simeval.errors import UserError
from simeval.measures.dynamics_diversity.gate import order_between_groups
from simeval.measures.dynamics_diversity.state_reading import (StateModelConfig, _steps, low_dim_state, split_training,
                                           state_reading)

torch.set_num_threads(1)
FAST = StateModelConfig(max_steps=600, eval_every=50, patience=4, seeds=(0, 1))


def test_baselines_by_hand_on_an_accelerating_point():
    s = np.array([[0.0], [1.0], [3.0], [6.0], [10.0], [15.0]])  # changes 1, 2, 3, 4, 5
    a = np.zeros((6, 1))
    states = {0: (s, a), 1: (s, a), 2: (s + 1, a)}
    out = state_reading(states, ["t", "t", "t"], [0, 1], [2], StateModelConfig(history=1, max_steps=10,
                                                                                  eval_every=5, seeds=(0,)))
    row = out["per_episode"][0]
    # t = 1..4 predict s_{t+1}: last state misses by the next change, constant velocity by 1 every step
    assert row["frames"] == 4
    assert row["last_state"] == pytest.approx(2**2 + 3**2 + 4**2 + 5**2)
    assert row["constant_velocity"] == pytest.approx(4.0)
    mean = s.mean()  # the task's mean over its training rows (episodes 0 and 1: the same rows)
    assert row["mean_state"] == pytest.approx(sum((v + 1 - mean) ** 2 for v in (3.0, 6.0, 10.0, 15.0)))


def test_history_steps_by_hand():
    s = np.arange(6, dtype=float)[:, None] ** 2
    a = np.arange(6, dtype=float)[:, None]
    cur, changes, actions, nxt = _steps(s, a, 2)
    np.testing.assert_array_equal(cur[:, 0], [4, 9, 16])  # t = 2, 3, 4
    np.testing.assert_array_equal(changes[:, :, 0], [[3, 1], [5, 3], [7, 5]])  # s_t - s_{t-1}, s_{t-1} - s_{t-2}
    np.testing.assert_array_equal(actions[:, :, 0], [[2, 1], [3, 2], [4, 3]])
    np.testing.assert_array_equal(nxt[:, 0], [9, 16, 25])
    with pytest.raises(UserError, match="state_model.history"):
        _steps(s[:3], a[:3], 2)


def test_quaternion_sign_is_canonical_and_poses_follow_the_state():
    poses = np.zeros((2, 1, 7))
    poses[0, 0, 3:] = [0, 0, 0, 1]
    poses[1, 0, 3:] = [0, 0, 0, -1]  # the same rotation
    out = low_dim_state(np.ones((2, 2)), poses)
    assert out.shape == (2, 9) and np.array_equal(out[0], out[1])


def test_validation_episodes_come_from_the_training_split_only():
    tasks = ["a"] * 5 + ["b"] * 5
    fit, val = split_training(tasks, [0, 1, 2, 3, 5, 6, 7, 8], 0.25)
    assert val == [3, 8] and fit == [0, 1, 2, 5, 6, 7]


def _linear_group(varied: bool, n_episodes: int = 30, n: int = 30, seed: int = 0):
    """s_{t+1} = s_t + B a_t with B = [[0.1, 0], [0, 0.05]]; varied: B's sign drawn per episode."""
    rng = np.random.default_rng(seed)
    states, tasks = {}, []
    for e in range(n_episodes):
        B = np.diag([0.1, 0.05]) * (rng.choice([-1, 1]) if varied else 1)
        a = rng.uniform(-1, 1, (n, 2))
        s = np.zeros((n, 2))
        for t in range(n - 1):
            s[t + 1] = s[t] + B @ a[t]
        states[e] = (s, a)
        tasks.append("task")
    return states, tasks


def test_a_fixed_response_reads_and_a_response_drawn_per_episode_reads_as_more_diverse():
    readings = {}
    for varied in (False, True):
        states, tasks = _linear_group(varied)
        readings[varied] = state_reading(states, tasks, list(range(20)), list(range(20, 30)), FAST)
    shared, diverse = readings[False], readings[True]
    assert shared["gate"]["passes"] and shared["summary"]["skill_vs_last_state"] > 0.9
    assert all(t["steps_used"] <= FAST.max_steps for t in shared["training"])

    def group(r):
        model = np.array([[row["model"][k] for row in r["per_episode"]] for k in range(len(r["seeds"]))])
        base = np.tile([row["constant_velocity"] for row in r["per_episode"]], (len(r["seeds"]), 1))
        return model, base, [row["task"] for row in r["per_episode"]]

    assert order_between_groups(group(diverse), group(shared))["order"] == "a > b"


def test_a_state_that_is_noise_at_every_step_gets_no_reading():
    rng = np.random.default_rng(0)
    states = {e: (rng.normal(size=(30, 3)), rng.uniform(-1, 1, (30, 2))) for e in range(30)}
    out = state_reading(states, ["t"] * 30, list(range(20)), list(range(20, 30)), FAST)
    assert not out["gate"]["passes"]
    assert out["line"].startswith("no reading: the model does not beat the mean state")


def test_states_of_different_sizes_between_episodes_are_no_reading_naming_both_not_a_crash():
    """A scene whose object count varies per episode records object poses of varying size (a BBSEA group did): the
    state model reads one size, so the reading is a UserError the run reports as "no reading", naming both sizes."""
    rng = np.random.default_rng(0)

    def episode(d):
        return rng.normal(size=(12, d)), rng.normal(size=(12, 2))

    states = {0: episode(5), 1: episode(5), 2: episode(12), 3: episode(5), 4: episode(5)}
    tasks = ["a", "a", "b", "a", "b"]
    with pytest.raises(UserError, match=r"differ in size between episodes \(5 values per step in a's, 12 in b's"):
        state_reading(states, tasks, [0, 1, 2], [3, 4])
