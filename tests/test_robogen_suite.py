"""The RoboGen-style suite (src/simeval/pipelines/robogen/suite/): procedurally generated articulated objects, the
joint_range goal, the ee_delta action space, RoboGen's fixed initial state, the closed-loop controller, stored
ee_delta episodes replaying exactly, and each task's test-time variation being accepted and solved."""

import warnings

import numpy as np
import pytest

from simeval.errors import UserError
from simeval.sim import make_env
from simeval.sim.action_spaces import EE_DELTA_KIND, EE_MAX_TRANSLATION
from simeval.sim.core.articulated import ARTICULATED, joint_fraction, set_joint_fraction
from simeval.sim.experts.articulation import ArticulationController
from simeval.sim.rollout import RecordSettings, run_episode
from simeval.sim.tasks.goals import task_progress
from simeval.sim.tasks.spec import suite_dir, SpecError, check_variation, load_suite, parse_spec
from simeval.sim.tasks.splits import load_heldout

SUITE = {s.name: s for s in load_suite(suite_dir("robogen"))}
HUMAN_STUDY = ["open-laptop", "change-lamp-direction", "flush-the-toilet", "extend-display-screen",
               "close-the-oven-door", "set-oven-timer", "close-the-window", "adjust-water-flow",
               "open-both-table-doors", "press-start-button"]


def _eval_variation(name: str) -> dict:
    return SUITE[name].variations["eval"]


def _solve(task: str, seed: int, variation=None, noise_std=0.002) -> dict:
    env = make_env(task, variation=variation, cameras=())
    try:
        obs, info = env.reset(seed=seed)
        policy = ArticulationController(noise_std)
        policy.reset(env)
        steps = 0
        while True:
            action = policy(obs)
            if action is None:
                break
            obs, _, terminated, truncated, info = env.step(action)
            steps += 1
            if terminated or truncated:
                break
        return {**info, "steps": steps}
    finally:
        env.close()


def test_the_suite_has_both_groups_the_human_study_tasks_and_every_articulated_kind():
    groups = {}
    for s in SUITE.values():
        groups.setdefault(s.group, []).append(s.name)
        assert s.action_space == "ee_delta" and s.initial_state == "fixed"
    assert set(groups) == {"table_top", "ground"} and all(len(v) >= 6 for v in groups.values())
    assert set(HUMAN_STUDY) <= set(SUITE)
    assert {o.shape for s in SUITE.values() for o in s.objects} >= set(ARTICULATED)
    heldout = load_heldout(suite_dir("robogen"), list(SUITE.values()))  # checked against the suite there
    assert set(heldout) == {"table_top", "ground"} and all(heldout.values())


def test_robogen_initial_states_are_identical_across_seeds_and_gensims_are_not():
    def initial(task, seed, variation=None):
        env = make_env(task, variation=variation, image_size=(32, 32), cameras=("front",))
        obs, _ = env.reset(seed=seed)
        poses = env.object_poses()
        joints = [joint_fraction(env.world.c, o.body_ids[0], k) for o in env.inst.objects
                  for k in range(len(env.inst.joints.get(o.id, [])))]
        env.close()
        return obs["rgb"]["front"], obs["state"], poses, joints, env.inst.description

    a, b = initial("close-the-oven-door", 0), initial("close-the-oven-door", 17)
    for x, y in zip(a, b):  # bit for bit: frames, arm state, object poses, joint positions, text
        np.testing.assert_array_equal(x, y) if not isinstance(x, str) else None
    assert a[4] == b[4]
    g0, g1 = initial("stack-two-blocks", 0), initial("stack-two-blocks", 17)
    assert not np.array_equal(g0[2], g1[2]) and not np.array_equal(g0[0], g1[0])
    # the test-time variation randomizes what training fixes
    var = _eval_variation("close-the-oven-door")
    r0, r1 = initial("close-the-oven-door", 0, var), initial("close-the-oven-door", 17, var)
    assert not np.array_equal(r0[2], r1[2]) and r0[3] != r1[3]


def test_episodes_of_a_fixed_task_differ_only_by_the_controllers_noise():
    def episode(seed, noise):
        return run_episode(SUITE["open-laptop"], seed, RecordSettings(cameras=(), scene_view_size=(8, 8),
                                                                      noise_std=noise), pipeline="robogen")

    a, b, again = episode(0, 0.002), episode(1, 0.002), episode(0, 0.002)
    assert a.success and b.success
    np.testing.assert_array_equal(a.state[0], b.state[0])  # the same start...
    np.testing.assert_array_equal(a.scene_views, b.scene_views)
    assert len(a.action) != len(b.action) or not np.array_equal(a.action, b.action)  # ...different actions
    np.testing.assert_array_equal(a.action, again.action)  # the seed fixes the noise
    quiet0, quiet5 = episode(0, 0.0), episode(5, 0.0)
    np.testing.assert_array_equal(quiet0.action, quiet5.action)  # without noise the seed changes nothing


@pytest.mark.parametrize("task,fraction,progress", [("open-laptop", 0.25, 0.5), ("open-laptop", 0.65, 1.0),
                                                     ("turn-off-faucet", 0.45, 0.5), ("turn-off-faucet", 0.9, 0.0),
                                                     ("press-start-button", 0.375, 0.5)])
def test_joint_range_progress_is_the_share_of_the_way_from_the_initial_fraction(task, fraction, progress):
    # open-laptop: 0 -> [0.5, 0.8]; turn-off-faucet: 0.8 -> [0, 0.1]; press-start-button: 0 -> [0.75, 1]
    env = make_env(task, cameras=())
    env.reset(seed=0)
    obj = env.inst.objects[0]
    set_joint_fraction(env.world.c, obj.body_ids[0], 0, fraction)
    got, success = task_progress(env.world, env.inst)
    env.close()
    assert got == pytest.approx(progress, abs=1e-6) and success == (progress == 1.0)


def test_ee_delta_env_passes_gymnasiums_checker_and_clips_its_steps():
    from gymnasium.utils.env_checker import check_env

    env = make_env("open-laptop", image_size=(16, 16), cameras=("front",))  # the task's native action space
    env.action_space.seed(0)  # the checker's random actions: the same every run
    assert env.mode == "ee_delta" and env.action_info["kind"] == EE_DELTA_KIND and env.action_space.shape == (7,)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=".*symmetric and normalized space")
        check_env(env, skip_render_check=True)
    env.reset(seed=0)
    start = env.ee_target
    env.step(np.array([0.5, 0, 0, 0, 0, 0, 0], np.float32))  # 50 cm asked, one step's bound given
    assert np.linalg.norm(env.ee_target - start) == pytest.approx(EE_MAX_TRANSLATION, abs=1e-6)
    for _ in range(20):
        env.step(np.array([0, 0, 0.01, 0, 0, 0, 0], np.float32))
    assert env.arm.tip()[2] - start[2] > 0.12  # the tool follows the deltas (20 x 1 cm up, a little lag)
    env.close()


def test_stored_ee_delta_episodes_replay_exactly_through_the_env():
    settings = RecordSettings(cameras=("top",), image_size=(24, 24), scene_view_size=(16, 16))
    ep = run_episode(SUITE["open-both-table-doors"], 3, settings, pipeline="robogen")
    assert ep.success and ep.action_space["kind"] == EE_DELTA_KIND and ep.high_level_action is None
    env = make_env("open-both-table-doors", cameras=("top",), image_size=(24, 24))
    obs, _ = env.reset(seed=3)
    np.testing.assert_array_equal(obs["rgb"]["top"], ep.rgb["top"][0])
    for t, a in enumerate(ep.action[:-1]):  # the last row is padding
        obs, _, terminated, truncated, info = env.step(a)
        np.testing.assert_array_equal(obs["rgb"]["top"], ep.rgb["top"][t + 1])
        np.testing.assert_array_equal(obs["state"], ep.state[t + 1])
    assert terminated and info["success"]
    env.close()


@pytest.mark.parametrize("task", sorted(SUITE))
def test_every_eval_variation_is_accepted_and_the_controller_solves_it(task):
    var = check_variation([SUITE[task]], _eval_variation(task))
    assert var["scene"] == {"initial_state": "random"}
    results = [_solve(task, seed, var) for seed in (0, 1)]
    assert all(r["success"] for r in results), results


def test_spec_and_variation_errors_name_the_problem():
    base = {"name": "t", "group": "g", "description": "d", "action_space": "ee_delta",
            "objects": [{"name": "box", "shape": "block"}, {"name": "oven", "shape": "oven"}]}
    with pytest.raises(SpecError, match="joint_range needs an articulated object"):
        parse_spec({**base, "goals": [{"type": "joint_range", "what": "box", "range": [0.5, 1]}]})
    with pytest.raises(SpecError, match="joint 2 does not exist; a oven has 2"):
        parse_spec({**base, "goals": [{"type": "joint_range", "what": "oven", "joint": 2, "range": [0.5, 1]}]})
    with pytest.raises(SpecError, match="range: \\[lo, hi\\]"):
        parse_spec({**base, "goals": [{"type": "joint_range", "what": "oven", "range": [0.8, 0.2]}]})
    with pytest.raises(SpecError, match="action_space 'torque'"):
        parse_spec({**base, "action_space": "torque", "goals": [{"type": "joint_range", "what": "oven", "range": [0, 1]}]})
    spec = SUITE["open-laptop"]
    with pytest.raises(UserError, match="variation.laptop.scale"):
        check_variation([spec], {"laptop": {"scale": [0.2, 3]}})
    with pytest.raises(UserError, match="variation.scene: unknown knob"):
        check_variation([spec], {"scene": {"shuffle": True}})
    with pytest.raises(UserError, match="articulated objects"):
        check_variation([spec], {"distractor": {"scale": 1.1}})
    with pytest.raises(UserError, match="ee_delta"):
        ArticulationController().reset(make_env("open-laptop", "joint", cameras=()))


def test_collect_stores_ee_delta_episodes_in_parallel_and_resumes(tmp_path):
    from simeval.collect import collect
    from simeval.episodes.store import EpisodeStore, read_recording

    store = EpisodeStore(tmp_path)
    specs = [SUITE["flush-the-toilet"], SUITE["pull-drawer-out"]]
    settings = RecordSettings(cameras=("front",), image_size=(16, 16), scene_view_size=(16, 16))
    first = collect(specs, [0, 1], store, settings, pipeline="robogen", workers=2, progress=False)
    assert len(first["new"]) == 4 and all(t["rate"] == 1.0 for t in first["tasks"].values())
    for path in store.paths():
        assert read_recording(path)["action_space"] == EE_DELTA_KIND
    again = collect(specs, [0, 1, 2], store, settings, pipeline="robogen", workers=2, progress=False)
    assert again["skipped"] == 4 and [(r["task"], r["seed"]) for r in again["new"]] == [
        ("flush-the-toilet", 2), ("pull-drawer-out", 2)]


def _turn(q0: np.ndarray, q1: np.ndarray) -> float:
    """The angle (radians) of the rotation between two xyzw quaternions."""
    return float(2 * np.arccos(min(1.0, abs(float(np.dot(q0, q1))))))


@pytest.mark.parametrize("task", ["pull-drawer-out", "open-laptop"])
def test_object_poses_record_each_moving_link_so_an_articulation_moves_the_objects_state(task):
    """An articulated object's base never moves; its link on the joint does. object_poses gives the base's row, then
    the link's in its joint frame: setting the joint to a fraction f of its limits slides the link f x travel
    (prismatic) or turns it f x range (revolute), read from PyBullet's joint limits, not from the poses."""
    env = make_env(task, image_size=(32, 32), cameras=("front",))
    try:
        env.reset(seed=0)
        c, body = env.world.c, env.inst.objects[0].body_ids[0]
        lo, hi = c.getJointInfo(body, 0)[8:10]
        prismatic = c.getJointInfo(body, 0)[2] == c.JOINT_PRISMATIC
        start = env.object_poses()
        set_joint_fraction(c, body, 0, joint_fraction(c, body, 0) + 0.5)
        moved = env.object_poses()
    finally:
        env.close()
    assert start.shape == moved.shape == (2, 7)
    np.testing.assert_array_equal(start[0], moved[0])  # the fixed base
    slide, turn = float(np.linalg.norm(moved[1, :3] - start[1, :3])), _turn(start[1, 3:], moved[1, 3:])
    if prismatic:
        assert slide == pytest.approx(0.5 * (hi - lo), rel=1e-4) and turn == pytest.approx(0, abs=1e-3)
    else:  # the joint frame sits on the hinge: it turns in place
        assert turn == pytest.approx(0.5 * (hi - lo), rel=1e-3) and slide == pytest.approx(0, abs=1e-5)


def test_a_stored_episode_of_an_articulation_records_its_link_moving():
    ep = run_episode(SUITE["open-laptop"], 0, RecordSettings(cameras=(), scene_view_size=(8, 8)), pipeline="robogen")
    poses = ep.object_poses  # (T + 1, 2, 7): the laptop's base, its lid
    assert ep.success and poses.shape[1:] == (2, 7)
    assert [(o["bodies"], o["links"]) for o in ep.extra["objects"].values()] == [(1, 1)]  # what the rows are
    assert np.ptp(poses[:, 0], axis=0).max() == 0  # the base stands still
    assert _turn(poses[0, 1, 3:], poses[-1, 1, 3:]) > 0.3  # the lid opened (the goal: half its range or more)
