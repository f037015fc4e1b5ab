"""The state-space reading of dynamics diversity (simeval.measures.dynamics_diversity.state_reading): baselines
computed by hand, the validation split never touches an evaluated episode, and hand-built groups whose answer is known:
a fixed linear response to the actions is learned and reads, the same response with its sign drawn per episode reads as
more diverse, and a state that is noise at every step gets no reading."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from simeval.errors import UserError
from simeval.measures.dynamics_diversity.gate import order_between_groups
from simeval.measures.dynamics_diversity.state_reading import (StateModelConfig, _steps, low_dim_state, pad_states,
                                                               split_training, state_reading)

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


def test_a_block_turning_through_180_degrees_moves_its_quaternion_a_little_each_step():
    """A block turned 1 degree per step about the vertical from 170 to 190 degrees (scipy's quaternions, whose w
    changes sign at 180): every step's quaternion change is the 1-degree turn's, 2 sin(0.25 deg), not the jump of
    ~2 a sign fixed per row by w >= 0 gives, and every row is still the block's rotation."""
    from scipy.spatial.transform import Rotation

    yaw = np.deg2rad(np.arange(170, 191))
    quats = Rotation.from_euler("z", yaw[:, None]).as_quat()  # xyzw, scipy's sign
    quats[quats[:, 3] < 0] *= -1  # the per-row canonical form the store may hold
    assert np.abs(np.diff(quats, axis=0)).max() > 1.9  # the jump this test exists for
    poses = np.zeros((len(yaw), 2, 7))
    poses[:, 0, :3] = [0.4, 0.1, 0.02]
    poses[:, 0, 3:] = quats
    poses[:, 1, 3:] = [0, 0, 0, -1]  # a second object that never turns, stored with w < 0
    out = low_dim_state(np.zeros((len(yaw), 1)), poses)[:, 1:].reshape(len(yaw), 2, 7)
    steps = np.linalg.norm(np.diff(out[:, 0, 3:], axis=0), axis=1)
    np.testing.assert_allclose(steps, 2 * np.sin(np.deg2rad(0.25)), rtol=1e-9)
    assert out[0, 0, 6] >= 0 and np.array_equal(out[:, 1, 3:], np.tile([0, 0, 0, 1.0], (len(yaw), 1)))
    np.testing.assert_allclose(Rotation.from_quat(out[:, 0, 3:]).as_matrix(), Rotation.from_euler("z", yaw[:, None]).as_matrix(),
                               atol=1e-12)
    np.testing.assert_array_equal(out[:, 0, :3], poses[:, 0, :3])


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
    assert out["reads"] == "state"
    assert out["line"].startswith("the whole state (3 values): no reading: the model does not beat the mean state")


def test_states_of_different_sizes_without_a_mask_are_a_user_error_naming_both_sizes():
    """States handed in unpadded (not through read_states) cannot be read as one vector: the error says which."""
    rng = np.random.default_rng(0)

    def episode(d):
        return rng.normal(size=(12, d)), rng.normal(size=(12, 2))

    states = {0: episode(5), 1: episode(5), 2: episode(12), 3: episode(5), 4: episode(5)}
    tasks = ["a", "a", "b", "a", "b"]
    with pytest.raises(UserError, match=r"differ in size between episodes \(5 values per step in a's, 12 in b's\)"):
        state_reading(states, tasks, [0, 1, 2], [3, 4])


def test_padding_by_hand_robot_and_objects_padded_to_the_largest_with_a_presence_mask():
    robot2, robot3 = np.ones((4, 2)), np.full((4, 3), 2.0)
    one = np.zeros((4, 1, 7))
    one[..., :3], one[..., 6] = 5.0, -1.0  # w < 0: canonicalised to the same rotation with w = 1
    two = np.zeros((4, 2, 7))
    two[..., 6] = 1.0
    a = np.zeros((4, 1))
    out = pad_states({0: (robot2, one, a), 1: (robot3, two, a), 2: (robot3, None, a)})
    s0, _, m0 = out[0]
    assert s0.shape == (4, 3 + 2 * 7)
    np.testing.assert_array_equal(s0[0], [1, 1, 0, 5, 5, 5, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(m0, [1, 1, 0] + [1] * 7 + [0] * 7)
    np.testing.assert_array_equal(out[1][2], [1] * 17)
    np.testing.assert_array_equal(out[2][2], [1] * 3 + [0] * 14)
    same = pad_states({0: (robot2, one, a), 1: (robot2, one, a)})  # one layout: no mask, no padding
    assert len(same[0]) == 2 and same[0][0].shape == (4, 9)


def _object_group(n_episodes: int = 24, n: int = 30, seed: int = 0):
    """Two tasks of one robot: 'one' moves one object, 'two' two objects, each object's x by its own fixed gain
    times the action, y and z still; the robot state follows the action. Object counts differ, so read through
    pad_states as read_states does."""
    rng = np.random.default_rng(seed)
    raw, tasks = {}, []
    for e in range(n_episodes):
        task, k = ("one", 1) if e % 2 == 0 else ("two", 2)
        a = rng.uniform(-1, 1, (n, 1))
        robot = np.zeros((n, 2))
        poses = np.zeros((n, k, 7))
        poses[..., 6] = 1.0
        poses[0, :, :2] = rng.uniform(-0.2, 0.2, (k, 2))
        for t in range(n - 1):
            robot[t + 1] = robot[t] + 0.05 * a[t]
            poses[t + 1] = poses[t]
            poses[t + 1, :, 0] += np.array([0.04, -0.02][:k]) * a[t, 0]
        raw[e], tasks = (robot, poses, a), tasks + [task]
    return pad_states(raw), tasks


def test_a_group_whose_tasks_hold_different_object_counts_reads_and_padding_costs_no_predictor_anything():
    states, tasks = _object_group()
    out = state_reading(states, tasks, list(range(16)), list(range(16, 24)), FAST)
    assert out["padded_from"] == [2 + 7, 2 + 14] and out["dims"] == 16
    assert out["gate"]["passes"], out["line"]
    assert out["summary"]["skill_vs_last_state"] > 0.8 and "the tasks' states hold 9/16 values, padded" in out["line"]
    assert out["line"].startswith("the whole state (16 values; the tasks' states hold 9/16 values, padded): reads (the "
                                  "gate: the model beats "
                                  f"the last and the mean state): one-step state error {out['summary']['model']:.3g} "
                                  "(last state")
    # a one-object episode's last-state error is that of its unpadded 9 values, by hand
    row = next(r for r in out["per_episode"] if r["task"] == "one")
    s = states[row["index"]][0][:, :9]
    t = np.arange(FAST.history, len(s) - 1)
    assert row["last_state"] == pytest.approx(((s[t + 1] - s[t]) ** 2).sum())


def test_a_value_that_stood_still_in_training_and_moves_when_held_out_does_not_blow_up_the_prediction():
    """A block's roll barely changes in the training episodes (deviation ~1e-6) and changes by 0.3 in a held-out
    one (it topples): unclipped, that input is ~1e5 deviations and every predicted value explodes; clipped to
    +-feature_clip the model still beats the last state on the moving value's neighbours."""
    rng = np.random.default_rng(0)

    def episode(topples: bool):
        a = rng.uniform(-1, 1, (30, 1))
        s = np.zeros((30, 2))
        s[:, 1] = rng.normal(0, 1e-6, 30)
        for t in range(29):
            s[t + 1, 0] = s[t, 0] + 0.1 * a[t, 0]
        if topples:
            s[15:, 1] += 0.3
        return s, a

    states = {e: episode(e >= 20 and e % 2 == 0) for e in range(30)}
    tasks = ["t"] * 30
    clipped = state_reading(states, tasks, list(range(20)), list(range(20, 30)), FAST)
    unclipped = state_reading(states, tasks, list(range(20)), list(range(20, 30)),
                              StateModelConfig(**{**FAST.__dict__, "feature_clip": None}))
    assert clipped["summary"]["model"] < clipped["summary"]["last_state"]
    assert unclipped["summary"]["model"] > 10 * clipped["summary"]["model"]
    with pytest.raises(UserError, match="feature_clip"):
        StateModelConfig(feature_clip=-1.0)


def test_validation_stops_on_the_error_in_the_states_units_the_reading_reports():
    """The stopping rule reads the validation error as the reading scores it (squared error in the state's own
    units, summed over values), per validation episode averaged over its steps, then the median over the episodes:
    checked against the kept model's own predictions by hand (numpy's median of the 4 episodes' means)."""
    from simeval.measures.dynamics_diversity.state_reading import _predict, fit_state_model

    states, _ = _linear_group(False, n_episodes=12)
    fit, val = [states[e] for e in range(8)], [states[e] for e in range(8, 12)]
    net, norm, info = fit_state_model(fit, val, FAST, seed=0)
    rows = [_steps(s, a, FAST.history) for s, a in val]
    per_episode = [((_predict(net, norm, cur, ch, act) - nxt) ** 2).sum(1) for cur, ch, act, nxt in rows]
    assert info["val_loss"] == pytest.approx(np.median([e.mean() for e in per_episode]), rel=1e-4)
    assert info["val_loss_mean_of_steps"] == pytest.approx(np.concatenate(per_episode).mean(), rel=1e-4)


def test_one_glitched_step_in_a_validation_episode_does_not_move_where_training_stops():
    """A simulator's glitch (one value jumping by 37 for one step, as a joint velocity did in a GenSim build-house
    episode) in one of 5 validation episodes: the stopping rule reads nearly the same curve as without it (the
    median moves only where the glitched episode crosses it) and keeps the model of the same step; the mean over all
    validation steps (the rule before) is moved 10^6-fold by it."""
    from simeval.measures.dynamics_diversity.state_reading import fit_state_model

    states, _ = _linear_group(False, n_episodes=13)
    fit, val = [states[e] for e in range(8)], [states[e] for e in range(8, 13)]
    s, a = val[2]
    glitched = s.copy()
    glitched[15:, 0] += 37.0  # a jump at step 15 that stays: one step's change of 37
    _, _, clean = fit_state_model(fit, val, FAST, seed=0)
    _, _, glitch = fit_state_model(fit, val[:2] + [(glitched, a)] + val[3:], FAST, seed=0)
    assert (glitch["best_step"], glitch["steps_used"]) == (clean["best_step"], clean["steps_used"])
    ratio = np.array(glitch["val_curve"])[:, 1] / np.array(clean["val_curve"])[:, 1]
    assert np.all((ratio >= 0.5) & (ratio <= 2)) and (ratio == 1.0).sum() >= len(ratio) // 2
    assert np.median(ratio) == pytest.approx(1.0, abs=0.01)
    assert glitch["val_loss_mean_of_steps"] > 1e5 * clean["val_loss_mean_of_steps"]


def test_the_state_model_runs_on_one_thread_and_gives_the_run_its_threads_back(monkeypatch):
    """A small MLP: on a loaded 2-core machine two threads made it 17x slower (a user's trial), so it trains and
    predicts on one whatever the run's `threads`, which it leaves as it found them."""
    import simeval.measures.dynamics_diversity.state_reading as sr

    seen, fit = [], sr.fit_state_models

    def counting(*args, **kwargs):
        seen.append(torch.get_num_threads())
        return fit(*args, **kwargs)

    monkeypatch.setattr(sr, "fit_state_models", counting)
    states, tasks = _object_group()
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        state_reading(states, tasks, list(range(16)), list(range(16, 24)), FAST)
        assert seen == [1] * len(FAST.seeds) and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_with_the_robots_width_the_reading_is_the_objects_and_the_parts_add_up_by_hand():
    """With the robot's width given (a store with object poses), the reading's numbers are the objects' values'
    (version 5); the robot's and the whole state's stand beside, each gated: the parts add up to the whole for the
    model and every baseline, one episode's objects' last-state error is its squared changes summed by hand, and the
    whole state's errors are those of the reading made without the split."""
    states, tasks = _object_group()
    out = state_reading(states, tasks, list(range(16)), list(range(16, 24)), FAST, robot_dims=2)
    whole = state_reading(states, tasks, list(range(16)), list(range(16, 24)), FAST)
    assert (out["reads"], whole["reads"], out["read_dims"]) == ("objects", "state", 14) and "parts" not in whole
    assert out["parts"]["robot"]["dims"] == 2 and out["parts"]["objects"]["dims"] == 14
    assert out["summary"] == out["parts"]["objects"]["summary"] and out["gate"] == out["parts"]["objects"]["gate"]
    # the whole state beside is the unsplit reading's (the model of the step that read the whole best), its gate too
    assert out["whole_state"]["summary"] == pytest.approx(whole["summary"], rel=1e-12)
    assert out["whole_state"]["gate"]["verdict"] == whole["gate"]["verdict"]
    assert [t["whole_state"]["best_step"] for t in out["training"]] == [t["best_step"] for t in whole["training"]]
    for r, w in zip(out["per_episode"], whole["per_episode"]):
        robot, objects = r["parts"]["robot"], r["parts"]["objects"]
        for b in ("last_state", "mean_state", "constant_velocity"):
            assert robot[b] + objects[b] == pytest.approx(w[b], rel=1e-12) and r[b] == objects[b]
        assert r["model"] == objects["model"] and r["parts"]["whole_state"]["model"] == pytest.approx(w["model"])
        assert robot["model"][0] <= w["model"][0] + 1e-12  # a part of the same model's error
    row = next(r for r in out["per_episode"] if r["task"] == "two")
    s, _, present = states[row["index"]]
    h = FAST.history
    change = (s[h + 1:] - s[h:-1])[:, 2:] * present[2:]
    assert row["last_state"] == pytest.approx(float((change ** 2).sum()), rel=1e-12) and row["last_state"] > 0
    assert out["summary"]["skill_vs_last_state"] == pytest.approx(
        1 - sum(np.mean(r["model"]) for r in out["per_episode"]) / sum(r["last_state"] for r in out["per_episode"]))
    assert out["line"].startswith("objects' poses (14 of 16 values; the tasks' states hold 9/16 values, padded): reads")
    assert "; beside: robot " in out["line"] and ", whole state " in out["line"]


def _arm_and_block_group(block_moves, n_episodes: int = 24, n: int = 30, seed: int = 0):
    """An arm whose 3 values jitter at random, large (sd 0.5: what no action predicts, as a controller's joint
    velocities are to a model of the task), and one block whose x moves by 0.03 times the action (or never moves):
    the whole state's error is the arm's, the block's answer is known."""
    rng = np.random.default_rng(seed)
    raw, tasks = {}, []
    for e in range(n_episodes):
        task, moves = (("t", block_moves) if isinstance(block_moves, bool) else
                       (("moves", True), ("still", False))[e % 2])
        tasks.append(task)
        a = rng.uniform(-1, 1, (n, 1))
        arm = rng.normal(0, 0.5, (n, 3))
        poses = np.zeros((n, 1, 7))
        poses[..., 6] = 1.0
        for t in range(n - 1):
            poses[t + 1] = poses[t]
            poses[t + 1, 0, 0] += 0.03 * a[t, 0] * moves
        raw[e] = (arm, poses, a)
    return pad_states(raw), tasks


def test_an_unpredictable_arm_hides_a_learned_block_in_the_whole_state_and_not_in_the_objects_reading():
    """Known answer: the block's motion is a fixed response to the action, learned, so the objects' reading reads
    (skill vs the last state near 1); the arm is noise, so the robot's part and the whole state (the arm's 3 values
    give all but 0.03% of its last-state error) get no reading beside it."""
    states, tasks = _arm_and_block_group(block_moves=True)
    out = state_reading(states, tasks, list(range(16)), list(range(16, 24)), FAST, robot_dims=3)
    assert out["reads"] == "objects" and out["gate"]["passes"], out["line"]
    assert out["summary"]["skill_vs_last_state"] > 0.9
    assert not out["parts"]["robot"]["gate"]["passes"] and not out["whole_state"]["gate"]["passes"]
    assert "robot " in out["line"] and "no reading)" in out["line"]


def test_objects_that_never_move_get_no_reading_that_says_so():
    """RoboGen's held-out steps: the arm moves, its objects do not. The last state is exact for them; the verdict
    says there is nothing to predict, not that the model failed."""
    states, tasks = _arm_and_block_group(block_moves=False)
    out = state_reading(states, tasks, list(range(16)), list(range(16, 24)), FAST, robot_dims=3)
    assert not out["gate"]["passes"] and out["summary"]["last_state"] == 0
    assert out["gate"]["verdict"] == ("no reading: the objects' poses never change in a held-out step (the last "
                                      "state is exact; nothing to predict)")
    assert out["line"].startswith("objects' poses (7 of 10 values): no reading: the objects' poses never change")


def test_the_parts_table_reads_the_runs_split_by_hand(tmp_path):
    """experiments/state_parts.py: per group, the parts' errors at the fewest and the most episodes, the objects'
    share of the last state's error and whether the objects beat the last state by the gate's margin at both."""
    import json

    from helpers import load_script

    parts = load_script(Path(__file__).resolve().parents[1] / "experiments" / "state_parts.py")

    def run(k: int, objects_model: float) -> dict:
        part = lambda model, last, dims: {"dims": dims, "model": model, "last_state": last,  # noqa: E731
                                          "skill_vs_last_state": 1 - model / last}
        state = {"gate": {"verdict": "reads"}, "summary": {"model": 0.5 + objects_model},
                 "parts": {"robot": part(0.5, 1.0, 14), "objects": part(objects_model, 0.002, 77)}}
        return {"identity": {"pipeline": "gensim_own", "task_group": "assembling", "episodes": k},
                "values": {"state": state}}

    for i, (k, objects_model) in enumerate([(10, 0.0025), (40, 0.0018)]):
        (tmp_path / str(i)).mkdir()
        (tmp_path / str(i) / "result.json").write_text(json.dumps(run(k, objects_model)))
    (tmp_path / "old").mkdir()  # a run made before the split is left out
    (tmp_path / "old" / "result.json").write_text(json.dumps({**run(20, 0.002), "values": {"state": {}}}))
    [row] = parts.rows(parts.collect([tmp_path]))
    assert row["counts"] == [10, 40] and row["objects"]["model"] == [0.0025, 0.0018]
    assert row["objects_share_of_last_state"] == pytest.approx(0.002 / 1.002)
    assert row["objects"]["skill_vs_last_state"] == pytest.approx([-0.25, 0.1])
    assert row["objects_beat_last_state"] is False  # -0.25 at 10 episodes
    assert "| gensim_own / assembling (10 -> 40) | 14 / 77 |" in parts.markdown([row])
    v5 = {"parts": {"robot": {"dims": 14, "summary": {"model": 0.5}, "gate": {}},
                    "objects": {"dims": 77, "summary": {"model": 0.002}, "gate": {}}},
          "whole_state": {"dims": 91, "summary": {"model": 0.502}}, "summary": {"model": 0.002}}
    split, whole = parts.part_summaries(v5)  # version 5 nests each part's numbers; its summary is the objects'
    assert split["objects"] == {"dims": 77, "model": 0.002} and whole == {"model": 0.502}


def test_a_task_whose_objects_stay_still_is_shown_and_not_required_by_the_gate():
    """BBSEA drawer's open/close-drawer tasks: their objects' poses never move while the other tasks' blocks do. No
    model beats an exact last state there, so the per-task check shows that task and does not require it; the
    group reads on the task that moves, the still task's errors still in its sums."""
    from simeval.measures.dynamics_diversity.gate import gate

    states, tasks = _arm_and_block_group(block_moves="by task")
    out = state_reading(states, tasks, list(range(16)), list(range(16, 24)), FAST, robot_dims=3)
    g = out["gate"]
    assert g["passes"] and g["exempt"] == ["still"] and g["tasks"] == 1, out["line"]
    assert not g["per_task"]["still"]["passes"]  # shown: the model's tiny errors against an exact last state
    assert "its objects almost motionless in 1 of 2 tasks (their checks shown, not required: still)" in out["line"]
    model = np.array([[r["model"][k] for r in out["per_episode"]] for k in range(len(FAST.seeds))])
    bases = {b: np.tile([r[b] for r in out["per_episode"]], (len(FAST.seeds), 1)) for b in ("last_state",
                                                                                             "mean_state")}
    strict = gate(model, bases, [r["task"] for r in out["per_episode"]])  # every task required: gated
    assert not strict["passes"] and strict["verdict"].endswith("on 1 of 2 tasks (still)")
    assert out["summary"]["model"] == pytest.approx(model.mean(0).sum() / out["frames"])  # still task counted


def test_the_change_target_scale_is_each_values_rms_step_by_hand_and_reads_the_known_block():
    """protocol.state_model.target_scale=change (the default): the predicted change is in units of each value's
    root mean square one-step change over the training rows (an object's millimetres weigh as the arm's joint
    velocities), a value that never changes keeps its state deviation; the learned block still reads."""
    from simeval.measures.dynamics_diversity.state_reading import _Norm

    s = np.array([[0.0, 5.0, 1.0], [1.0, 5.0, 3.0], [3.0, 5.0, 2.0]])  # changes (1, 2), (0, 0), (2, -1)
    norm = _Norm.fit([(s, np.zeros((3, 1)))], clip=10.0, target_scale="change")
    np.testing.assert_allclose(norm.unit, [np.sqrt(2.5), 1.0, np.sqrt(2.5)])  # the still value: its sd, 0 -> 1
    assert norm.clip_targets and _Norm.fit([(s, np.zeros((3, 1)))], clip=10.0, target_scale="state").target_sd is None
    assert StateModelConfig().target_scale == "change"  # the default since version 6
    with pytest.raises(UserError, match="target_scale"):
        StateModelConfig(target_scale="delta")
    old_loss = state_reading(*_object_group(), list(range(16)), list(range(16, 24)),
                             StateModelConfig(max_steps=100, eval_every=50, seeds=(0,), target_scale="state"))
    assert old_loss["target_scale"] == "state"
    assert old_loss["line"].endswith("[target_scale=state: versions 1-5's loss]")
    states, tasks = _arm_and_block_group(block_moves=True)
    cfg = StateModelConfig(max_steps=600, eval_every=50, patience=4, seeds=(0, 1), target_scale="change")
    out = state_reading(states, tasks, list(range(16)), list(range(16, 24)), cfg, robot_dims=3)
    assert out["gate"]["passes"] and out["summary"]["skill_vs_last_state"] > 0.9, out["line"]


def _arm_and_glider_group(n_episodes: int = 24, n: int = 30, seed: int = 0):
    """An arm jittering at random (sd 0.5) and a block gliding at its own constant speed per episode (steps of
    0.002-0.01, its positions spread over +-0.3): only the block's last step predicts its next one, exactly."""
    rng = np.random.default_rng(seed)
    raw = {}
    for e in range(n_episodes):
        poses = np.zeros((n, 1, 7))
        poses[..., 6] = 1.0
        poses[:, 0, 0] = rng.uniform(-0.3, 0.3) + rng.uniform(-0.01, 0.01) * np.arange(n)
        raw[e] = (rng.normal(0, 0.5, (n, 3)), poses, rng.uniform(-1, 1, (n, 1)))
    return pad_states(raw), ["t"] * n_episodes


def test_the_past_changes_enter_in_each_values_rms_step_by_hand_and_a_glider_is_read_from_its_velocity():
    """protocol.state_model.input_scale=change (version 7, the default): the past changes the model sees are in the
    same units as the change it predicts, each value's RMS step (by hand: the changes' part of the features); in
    state units (versions 1-6) a block's steps entered at 1-3% of its spread beside an arm's at 100%, and a block
    that glides at its own speed (known answer: constant velocity is exact) was read at skill 0.41 vs the last state,
    its velocity all but unseen; in step units it reads at 0.99."""
    from simeval.measures.dynamics_diversity.state_reading import _Norm

    s = np.array([[0.0, 5.0, 1.0], [1.0, 5.0, 3.0], [3.0, 5.0, 2.0]])  # changes (1, 2), (0, 0), (2, -1)
    data = [(s, np.zeros((3, 1)))]
    rms, sd = np.array([np.sqrt(2.5), 1.0, np.sqrt(2.5)]), s.std(0)
    sd[1] = 1.0  # a value that never changes: deviation 1, and its step unit that deviation
    changes = np.array([[[2.0, 0.0, -1.0]]])  # one row, one past change
    x = _Norm.fit(data, clip=None).features(s[:1], changes, np.zeros((1, 1, 1)))
    np.testing.assert_allclose(x[0, 3:6], changes[0, 0] / rms)
    x_old = _Norm.fit(data, clip=None, input_scale="state").features(s[:1], changes, np.zeros((1, 1, 1)))
    np.testing.assert_allclose(x_old[0, 3:6], changes[0, 0] / sd)
    assert StateModelConfig().input_scale == "change"
    with pytest.raises(UserError, match="input_scale"):
        StateModelConfig(input_scale="rms")
    states, tasks = _arm_and_glider_group()
    read = {scale: state_reading(states, tasks, list(range(16)), list(range(16, 24)),
                                 StateModelConfig(**{**FAST.__dict__, "input_scale": scale}), robot_dims=3)
            for scale in ("state", "change")}
    assert read["change"]["summary"]["skill_vs_last_state"] > 0.95, read["change"]["line"]
    assert read["state"]["summary"]["skill_vs_last_state"] < 0.7, read["state"]["line"]
    assert read["state"]["input_scale"] == "state"
    assert "[input_scale=state: versions 1-6's inputs]" in read["state"]["line"]


def test_a_piles_particles_are_read_by_position_their_quaternions_absent_by_hand():
    """pad_states with a 4th item (the pose rows that are a pile's particles): their quaternion values are 0 and
    absent, their positions present; a block's pose stays whole; particles force the mask on a group of one layout."""
    poses = np.zeros((3, 3, 7))
    poses[..., :3] = 0.5
    poses[..., 3:] = [0.0, 0.6, 0.0, 0.8]
    robot, a = np.ones((3, 2)), np.zeros((3, 1))
    out = pad_states({0: (robot, poses, a, (1, 2)), 1: (robot, poses, a, (1, 2))})
    s, _, present = out[0]
    np.testing.assert_array_equal(present, [1, 1] + [1] * 7 + [1, 1, 1, 0, 0, 0, 0] * 2)
    np.testing.assert_array_equal(s[0], [1, 1] + [0.5] * 3 + [0, 0.6, 0, 0.8] + [0.5, 0.5, 0.5, 0, 0, 0, 0] * 2)
    assert len(pad_states({0: (robot, poses, a, ()), 1: (robot, poses, a)})[0]) == 2  # no particles: as before


def _pile_group(n_episodes: int = 24, n: int = 30, seed: int = 0):
    """One task: a block standing still and a pile of 4 particles, each particle's x pushed by 0.02 times the
    action while its orientation tumbles at random (a fresh unit quaternion every step, as a pushed bead's)."""
    rng = np.random.default_rng(seed)
    raw = {}
    for e in range(n_episodes):
        a = rng.uniform(-1, 1, (n, 1))
        poses = np.zeros((n, 5, 7))
        poses[..., 6] = 1.0
        poses[0, 1:, :2] = rng.uniform(-0.1, 0.1, (4, 2))
        for t in range(n - 1):
            poses[t + 1, :, :3] = poses[t, :, :3]
            poses[t + 1, 1:, 0] += 0.02 * a[t, 0]
        q = rng.normal(size=(n, 4, 4))
        poses[:, 1:, 3:] = q / np.linalg.norm(q, axis=-1, keepdims=True)
        raw[e] = (np.zeros((n, 1)), poses, a)
    return raw


def test_a_pile_whose_particles_tumble_reads_by_position_and_not_with_their_quaternions():
    """The answer is known: the particles' positions follow the action (learnable), their orientations are noise.
    Read by position, the objects' last-state error is the particles' squared position changes by hand (the block
    stands still; no quaternion counted) and the model beats it; with the quaternions read (the rows not marked as
    a pile's), the tumbling is most of the error and no model beats the last state."""
    raw = _pile_group()
    tasks = ["pile"] * len(raw)
    marked = pad_states({e: (*v, (1, 2, 3, 4)) for e, v in raw.items()})
    out = state_reading(marked, tasks, list(range(16)), list(range(16, 24)), FAST, robot_dims=1, particles=4)
    assert out["gate"]["passes"] and out["summary"]["skill_vs_last_state"] > 0.8, out["line"]
    assert "; a pile's 4 particles by position" in out["line"] and out["particles"] == 4
    row = out["per_episode"][0]
    p = raw[row["index"]][1]
    t = np.arange(FAST.history, len(p) - 1)
    assert row["last_state"] == pytest.approx(float(((p[t + 1, 1:, :3] - p[t, 1:, :3]) ** 2).sum()), rel=1e-12)
    whole = state_reading(pad_states(raw), tasks, list(range(16)), list(range(16, 24)), FAST, robot_dims=1)
    assert not whole["gate"]["passes"] and whole["summary"]["last_state"] > 50 * out["summary"]["last_state"]


STATE_RESUME_SCRIPT = """
import json, logging, os, signal, sys
import numpy as np
import torch
torch.set_num_threads(1)
logging.basicConfig(level=logging.INFO)
import simeval.measures.dynamics_diversity.state_reading as S
kill_at, reads = int(sys.argv[2]), 0
read = S.median_episode_error

def read_or_die(rows, episode):  # a kill -9 as the training reaches its `kill_at`-th validation read: mid-seed
    global reads
    reads += 1
    if reads == kill_at:
        os.kill(os.getpid(), signal.SIGKILL)
    return read(rows, episode)

S.median_episode_error = read_or_die
rng = np.random.default_rng(0)
states = {}
for e in range(16):
    a = rng.uniform(-1, 1, (20, 2))
    states[e] = (np.cumsum(np.r_[np.zeros((1, 2)), 0.1 * a[:-1]], 0), a)
out = S.state_reading(states, ["t"] * 16, list(range(12)), list(range(12, 16)),
                      S.StateModelConfig(max_steps=200, eval_every=20, seeds=(0, 1)),
                      checkpoints=None if sys.argv[1] == "-" else sys.argv[1])
print(json.dumps({k: out[k] for k in ("summary", "per_episode", "training")}))
"""


def test_a_state_reading_killed_mid_training_resumes_where_it_stopped_and_ends_as_an_uninterrupted_one(tmp_path):
    """kill -9 in the second seed's training (its 4th of 10 validation reads): the first seed's training is kept
    whole, the second resumes from its 3rd read, and the reading equals one never interrupted, to the bit. A save
    that cannot be read (cut short; or weights that load before an optimiser that does not) trains afresh."""
    import json
    import os
    import signal
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root / "src")}
    script = tmp_path / "read.py"
    script.write_text(STATE_RESUME_SCRIPT)
    ck = tmp_path / "ck"
    whole = subprocess.run([sys.executable, str(script), "-", "-1"], env=env, capture_output=True, text=True,
                           check=True)
    killed = subprocess.run([sys.executable, str(script), str(ck), "14"], env=env, capture_output=True, text=True)
    assert killed.returncode == -signal.SIGKILL and killed.stdout == ""
    first, second = (torch.load(ck / f"seed-{s}.pt", weights_only=True) for s in (0, 1))
    assert first["step"] == 200 and second["step"] == 60  # seed 0 done; seed 1 saved at its 3rd read
    resumed = subprocess.run([sys.executable, str(script), str(ck), "-1"], env=env, capture_output=True, text=True,
                             check=True)
    assert "resumed from" in resumed.stderr and "at step 60" in resumed.stderr
    assert json.loads(resumed.stdout) == json.loads(whole.stdout)
    import io

    def mended(files: dict[str, bytes]) -> str:  # a reading from saves `files`: the uninterrupted one; its log
        folder = tmp_path / f"damaged-{len(list(tmp_path.glob('damaged-*')))}"
        folder.mkdir()
        for name, data in files.items():
            (folder / name).write_bytes(data)
        r = subprocess.run([sys.executable, str(script), str(folder), "-1"], env=env, capture_output=True, text=True,
                           check=True)
        assert json.loads(r.stdout) == json.loads(whole.stdout)
        return r.stderr

    saves = {name: (ck / name).read_bytes() for name in ("seed-0.pt", "seed-1.pt")}
    log = mended({"seed-0.pt": b"not a checkpoint", "seed-1.pt": saves["seed-1.pt"][:3000]})  # garbage; cut short
    assert log.count("unreadable") == 2 and "Re-running" not in log  # torch's advice to load unsafely: not ours
    partial = torch.load(ck / "seed-0.pt", weights_only=True)  # weights that load, then an optimiser that does not
    partial["net"] = {k: v + 1 for k, v in partial["net"].items()}
    partial["opt"] = {"not": "adam's"}
    buffer = io.BytesIO()
    torch.save(partial, buffer)
    assert mended({"seed-0.pt": buffer.getvalue()}).count("unreadable") == 1
    log = mended({"seed-0.pt": saves["seed-1.pt"]})  # another seed's save copied over this one's
    assert "unreadable (ValueError: saved by seed 1, not 0)" in log
