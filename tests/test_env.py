"""The Gymnasium environment (simeval.sim.make_env): the API contract, the oracle run as a policy through it
reproducing stored episodes, the stored 14-d actions solving the task through action_space="pick_place", and
rollouts of a policy over seeds (in parallel processes too)."""

import warnings

import numpy as np
import pytest

from simeval.errors import UserError
from simeval.sim import OraclePolicy, make_env, rollout_policy
from simeval.sim.rollout import RecordSettings, run_episode
from simeval.sim.tasks.spec import suite_dir, load_suite

SUITE = {s.name: s for s in load_suite(suite_dir("gensim"))}


@pytest.mark.parametrize("task", ["stack-two-blocks", "bbsea-open-drawer"])
def test_seeded_random_actions_keep_every_observation_inside_the_observation_space(task):
    """The xArm6 with joint targets and the Panda with ee_pose targets: random actions drive joints past their
    (soft) limits, by up to 0.19 rad in this sample; the state's bounds must hold what the physics gives (a bound
    at 0.1 rad past the limits failed gymnasium's checker on about 8% of random Panda steps)."""
    env = make_env(task, image_size=(8, 8), cameras=("top",))
    env.action_space.seed(0)
    try:
        for episode in range(30):  # xArm6: episode 22's sixth step is the 0.19 rad
            obs, _ = env.reset(seed=episode)
            for _ in range(8):
                obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
                assert env.observation_space.contains(obs), (episode, obs["state"])
                if terminated or truncated:
                    break
    finally:
        env.close()


@pytest.mark.parametrize("action_space,task", [("joint", "stack-two-blocks"), ("pick_place", "put-block-in-zone"),
                                               ("pick_place", "sweep-pile-into-zone")])
def test_env_passes_gymnasiums_checker(action_space, task):
    from gymnasium.utils.env_checker import check_env

    env = make_env(task, action_space, image_size=(16, 20), cameras=("top", "front"))
    env.action_space.seed(0)  # the checker's random actions: the same every run
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the checker warns about anything off in spaces, dtypes or determinism
        # ...except its advice to normalise Box actions: ours are physical (rad, m), as the stored episodes
        warnings.filterwarnings("ignore", message=".*symmetric and normalized space")
        check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=3)
    assert obs["rgb"]["front"].shape == (16, 20, 3) and obs["rgb"]["top"].dtype == np.uint8
    assert obs["state"].dtype == np.float32 and obs["state"].shape == (14,)
    assert set(info) >= {"progress", "success"} and info["progress"] == 0.0 and not info["success"]
    assert env.action_space.shape == ((7,) if action_space == "joint" else (14,))
    env.close()


def test_the_oracle_through_make_env_reproduces_stored_episodes(tmp_path):
    from simeval.episodes.store import EpisodeStore, read_episode

    store = EpisodeStore(tmp_path)
    settings = RecordSettings(cameras=("top",), image_size=(24, 24), scene_view_size=(16, 16))
    stored = [read_episode(store.write(run_episode(SUITE["stack-block-tower"], s, settings))) for s in (0, 1)]
    res = rollout_policy(OraclePolicy(), "stack-block-tower", [0, 1], action_space="pick_place", cameras=("top",),
                         image_size=(24, 24), video_camera="top")
    assert res["success"] == 1.0 and res["progress"] == 1.0
    for ep, got in zip(stored, res["episodes"]):
        np.testing.assert_array_equal(got["video"], ep.rgb["top"])  # every control step, frame for frame
        assert got["steps"] == len(ep.high_level_action) and got["success"] == ep.success


@pytest.mark.parametrize("task", ["build-bridge", "sweep-pile-into-zone"])
def test_stored_pick_place_actions_replayed_through_the_env_solve_the_task(task):
    ep = run_episode(SUITE[task], 2, RecordSettings(cameras=(), scene_view_size=(8, 8)))
    env = make_env(task, "pick_place", cameras=())
    env.reset(seed=2)
    for a in ep.high_level_action:
        obs, reward, terminated, truncated, info = env.step(a)
    assert terminated and info["success"] and info["progress"] == 1.0
    env.close()


def test_a_ravens_style_identity_pick_rotation_places_the_object_at_its_target():
    """Ravens' oracle picks with an identity rotation and places with the relative one: the same convention."""
    ep = run_episode(SUITE["put-block-in-zone"], 4, RecordSettings(cameras=(), scene_view_size=(8, 8)))
    (a,) = ep.high_level_action
    import pybullet as p

    from simeval.sim.core.world import yaw_of

    turn = yaw_of(a[10:14]) - yaw_of(a[3:7])
    ravens = np.r_[a[:3], 0, 0, 0, 1, a[7:10], p.getQuaternionFromEuler([0, 0, turn])].astype(np.float32)
    env = make_env("put-block-in-zone", "pick_place", cameras=())
    env.reset(seed=4)
    _, _, terminated, _, info = env.step(ravens)
    assert terminated and info["success"]
    env.close()


def test_policies_roll_out_over_seeds_in_parallel_processes():
    res = rollout_policy(OraclePolicy(), "put-block-in-zone", [0, 1, 2], action_space="pick_place", cameras=(),
                         workers=2)
    assert [e["seed"] for e in res["episodes"]] == [0, 1, 2] and res["success"] == 1.0
    assert all(e["video"] is None and e["steps"] == 1 for e in res["episodes"])

    def hold_still(obs):  # a joint policy that never moves: runs to the step limit, no success
        return np.r_[obs["state"][:6], 0.0]

    res = rollout_policy(hold_still, "put-block-in-zone", [0], cameras=("top",), image_size=(8, 8), max_steps=5,
                         video_camera="top")
    (e,) = res["episodes"]
    assert e["steps"] == 5 and not e["success"] and e["video"].shape == (6, 8, 8, 3) and res["success"] == 0.0


def test_env_errors_name_the_problem():
    with pytest.raises(UserError, match="task='juggle' is not a suite task; available: .*stack-two-blocks"):
        make_env("juggle")
    with pytest.raises(UserError, match="action_space='torque': expected one of joint, pick_place"):
        make_env("stack-two-blocks", "torque")
    with pytest.raises(UserError, match="unknown camera"):
        make_env("stack-two-blocks", cameras=("side",))
    env = make_env("stack-two-blocks", cameras=())
    with pytest.raises(UserError, match="call env.reset"):
        env.step(np.zeros(7))
    env.reset(seed=0)
    with pytest.raises(UserError, match="takes 7 values per action, got shape"):
        env.step(np.zeros(6))
    with pytest.raises(UserError, match="the oracle acts through action_space='pick_place'"):
        OraclePolicy().reset(env)
    env.close()


def test_two_tasks_with_the_same_seed_draw_their_own_pile_spread_and_home_noise():
    """The physical randomness of an episode (particle offsets within a pile, the arm's home noise) comes from
    the task's own stream (task_seed), not from the bare seed: two tasks with equally sized piles and the same
    seed spread them differently and start the arm from different homes; the same task and seed repeat."""
    def spread_and_home(task: str, seed: int):
        env = make_env(task, "pick_place", variation={"robot": {"home_noise": 0.05}}, cameras=())
        try:
            env.reset(seed=seed)
            pile = env.inst.by_name("pile")[0]
            centre = env.inst.poses[pile.id][0]
            xy = np.array([env.world.c.getBasePositionAndOrientation(b)[0][:2] for b in pile.body_ids]) - centre
            return xy, env.arm.home.copy()
        finally:
            env.close()

    a_xy, a_home = spread_and_home("sweep-pile-into-zone", 3)
    b_xy, b_home = spread_and_home("sweep-pile-into-matching-zone", 3)  # same pile size and count (0.10 m, 50)
    again_xy, again_home = spread_and_home("sweep-pile-into-zone", 3)
    assert np.abs(a_xy - b_xy).max() > 0.01 and np.abs(a_home - b_home).max() > 1e-3
    np.testing.assert_array_equal(a_home, again_home)
    np.testing.assert_allclose(a_xy, again_xy, atol=1e-9)
