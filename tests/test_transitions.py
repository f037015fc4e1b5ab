"""Stored transitions mean what they say (simeval.episodes.store's convention): row 0 is the reset observation,
action t was taken after observing row t and produced row t + 1, and the end-effector is part of both the action
and the state. Replaying a stored episode's actions from reset reproduces it bit for bit."""

import h5py
import numpy as np
import pytest

from simeval.episodes.store import (
    EpisodeFormatError,
    EpisodeStore,
    WindowSpec,
    iter_windows,
    read_episode,
    read_meta,
    write_episode,
)
from simeval.errors import UserError
from simeval.sim.env import make_env
from simeval.sim.rollout import RecordSettings, run_episode
from simeval.sim.tasks.spec import suite_dir, load_suite

SUITE = {s.name: s for s in load_suite(suite_dir("gensim"))}
SMALL = RecordSettings(cameras=("top",), image_size=(24, 24), scene_view_size=(16, 16))


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    """Oracle episodes written to and read back from a store: a suction task and a spatula (pile) task."""
    store = EpisodeStore(tmp_path_factory.mktemp("store"))
    out = {}
    for task in ("stack-two-blocks", "sweep-pile-into-zone"):
        out[task] = read_episode(store.write(run_episode(SUITE[task], 0, SMALL)))
    out["store"] = store
    return out


@pytest.mark.parametrize("task", ["stack-two-blocks", "sweep-pile-into-zone"])
def test_replaying_stored_actions_from_reset_reproduces_the_episode_exactly(stored, task):
    ep = stored[task]
    assert ep.action_space["kind"] == "joint_pos+suction" and ep.action.shape == (ep.n_steps, 7)
    env = make_env(task, "joint", image_size=(24, 24), cameras=("top",))
    obs, info = env.reset(seed=ep.seed)
    np.testing.assert_array_equal(obs["rgb"]["top"], ep.rgb["top"][0])  # row 0: the observation before any action
    np.testing.assert_array_equal(obs["state"], ep.state[0])
    for t in range(ep.n_actions):
        obs, reward, terminated, truncated, info = env.step(ep.action[t])
        np.testing.assert_array_equal(obs["state"], ep.state[t + 1], err_msg=f"state, step {t}")
        np.testing.assert_array_equal(obs["rgb"]["top"], ep.rgb["top"][t + 1], err_msg=f"frame, step {t}")
        assert reward == pytest.approx(ep.reward[t], abs=1e-6) and info["progress"] == pytest.approx(ep.progress[t + 1])
    env.close()
    assert info["success"] == ep.success is True


def test_rows_actions_and_rewards_follow_the_documented_convention(stored):
    ep = stored["stack-two-blocks"]
    t = ep.n_actions
    assert ep.n_steps == t + 1 and len(ep.rgb["top"]) == len(ep.state) == len(ep.reward) == t + 1
    np.testing.assert_array_equal(ep.action[t], ep.action[t - 1])  # the last row's action is padding ("hold")
    assert ep.is_first.tolist() == [True] + [False] * t and ep.is_terminal.tolist() == [False] * t + [True]
    np.testing.assert_allclose(ep.reward[:t], np.diff(ep.progress), atol=1e-6)
    assert ep.reward[t] == 0 and ep.progress[0] == 0 and ep.progress[-1] == 1.0
    assert ep.high_level_step[0] == 0 and ep.high_level_space["kind"] == "pick_place_14d"
    meta = read_meta(stored["store"].path_for("gensim", "stack-two-blocks", 0))
    assert meta["n_steps"] == t + 1 and meta["n_actions"] == t and meta["state_names"][-2:] == ["suction", "holding"]
    assert meta["action_space"]["dims"][-1] == "suction" and meta["action_space"]["control_hz"] == 30.0


def test_the_suction_command_is_in_the_action_and_the_grasp_in_the_state(stored):
    ep = stored["stack-two-blocks"]
    on = ep.action[:-1, 6]
    assert set(np.unique(on)) == {0.0, 1.0}
    switches = np.flatnonzero(np.diff(on))
    assert len(switches) == 2  # one pick: suction on once, off once
    # the grasp takes effect at the step whose action turns the suction on, and ends with the one that turns it off
    np.testing.assert_array_equal(ep.state[1:, 12], on)  # state: the command in force after the action
    np.testing.assert_array_equal(ep.state[1:, 13], on)  # state: something held (every suction-on here grasps)
    assert ep.state[0, 12:].tolist() == [0, 0]
    pile = stored["sweep-pile-into-zone"]
    assert not pile.action[:, 6].any() and not pile.state[:, 12:].any()  # the spatula has no actuation


def test_a_one_step_predictor_using_the_action_beats_copying_the_state():
    eps = [run_episode(SUITE["put-block-in-zone"], s, RecordSettings(cameras=(), scene_view_size=(8, 8)))
           for s in (0, 1, 2)]

    def pairs(ep, use_action):
        x = [np.ones((ep.n_actions, 1)), ep.state[:-1, :12]] + ([ep.action[:-1, :6]] if use_action else [])
        return np.hstack(x), ep.state[1:, :6]  # predict the next joint positions

    def held_out_error(use_action):
        x, y = (np.vstack(v) for v in zip(*(pairs(e, use_action) for e in eps[:2])))
        w = np.linalg.lstsq(x, y, rcond=None)[0]
        xt, yt = pairs(eps[2], use_action)
        return float(np.mean((xt @ w - yt) ** 2))

    copy = float(np.mean((eps[2].state[1:, :6] - eps[2].state[:-1, :6]) ** 2))
    with_action, state_only = held_out_error(True), held_out_error(False)
    assert with_action < 1e-3 * copy and with_action < 1e-3 * state_only  # measured: ~1e-9 vs ~1e-3


def test_old_format_files_are_refused_with_a_re_collect_hint(tmp_path):
    with h5py.File(tmp_path / "episode_000000.h5", "w") as f:
        f.attrs.update({"schema": 1, "complete": True})
    with pytest.raises(EpisodeFormatError, match=r"episode_000000.h5: episode format 1 .* re-collect"):
        read_episode(tmp_path / "episode_000000.h5")


def test_a_training_set_never_mixes_action_spaces(stored, tmp_path):
    low = stored["stack-two-blocks"]
    high = read_episode(stored["store"].path_for("gensim", "sweep-pile-into-zone", 0))
    high.action = np.concatenate([high.high_level_action, high.high_level_action[-1:]])
    high.rgb = {k: v[: len(high.action)] for k, v in high.rgb.items()}
    high.robot_mask = {k: v[: len(high.action)] for k, v in (high.robot_mask or {}).items()} or None
    for name in ("state", "reward", "progress", "is_first", "is_terminal", "object_poses"):
        setattr(high, name, getattr(high, name)[: len(high.action)])
    from simeval.sim.action_spaces import pick_place_action_space

    high.action_space = pick_place_action_space()
    paths = [write_episode(tmp_path / "a.h5", low), write_episode(tmp_path / "b.h5", high)]
    with pytest.raises(UserError, match="mixes action spaces 'joint_pos[+]suction' .* and 'pick_place_14d'"):
        list(iter_windows(paths, WindowSpec(length=2)))
    assert len(list(iter_windows(paths[:1], WindowSpec(length=2)))) == low.n_steps // 2


def test_varied_episodes_are_stored_beside_the_plain_ones_never_over_them(tmp_path):
    from simeval.collect import collect

    store = EpisodeStore(tmp_path)
    spec = SUITE["stack-two-blocks"]
    settings = RecordSettings(cameras=(), scene_view_size=(8, 8))
    plain = collect([spec], [0], store, settings, workers=1, progress=False)
    varied = collect([spec], [0], store, settings, workers=1, progress=False,
                     variation={"top": {"colors": ["white"]}})
    assert len(plain["new"]) == 1 and len(varied["new"]) == 1 and varied["skipped"] == 0
    metas = sorted(store.index(), key=lambda m: m["variation_id"])
    assert [m["variation"] for m in metas] == [{}, {"top": {"colors": ["white"]}}]
    assert "white" in metas[1]["description"] and "white" not in metas[0]["description"]
    assert metas[1]["path"].endswith(f"episode_000000.v{metas[1]['variation_id']}.h5")
    assert [m["variation_id"] for m in store.first_k_per_task(1, variation_id="")] == [""]
    again = collect([spec], [0], store, settings, workers=1, progress=False, variation={"top": {"colors": ["white"]}})
    assert again["skipped"] == 1 and again["tasks"]["stack-two-blocks"]["success"] == 1


def test_ravens_import_keeps_the_solved_scene_sub_goals_poses_and_the_task_description(tmp_path):
    import pickle

    from simeval.pipelines.importers import import_ravens

    d, t = tmp_path / "build-car-train", 2
    goals = ["put the red block on the base", "put the blue block on top", "done"]
    poses = [{5: ((0.4, 0.1 * i, 0.02), (0, 0, 0, 1), (0.04, 0.04, 0.04)), 6: ((0.5, 0.0, 0.02), (0, 0, 0, 1), (1, 1, 1)),
              "lang_goal": g} for i, g in enumerate(goals)]
    parts = {"color": np.arange(t + 1, dtype=np.uint8)[:, None, None, None, None] * np.ones((1, 1, 4, 4, 3), np.uint8),
             "action": [{"pose0": ((0.4, 0, 0.04), (0, 0, 0, 1)), "pose1": ((0.5, 0, 0.08), (0, 0, 0, 1))}] * t + [None],
             "reward": [0.0, 0.5, 0.5], "info": poses}
    for key, value in parts.items():
        (d / key).mkdir(parents=True)
        (d / key / "000000-7.pkl").write_bytes(pickle.dumps(value))
    ep = next(import_ravens(tmp_path, descriptions={"build-car": "Build a car from blocks."}))
    assert ep.n_steps == t + 1 and ep.rgb["color_0"][-1].max() == t  # the final, solved observation is there
    assert ep.success and ep.progress[-1] == 1.0 and ep.description == "Build a car from blocks."
    assert ep.language == goals and ep.object_poses.shape == (t + 1, 2, 7) and ep.object_poses[2, 0, 1] == pytest.approx(0.2)
    assert ep.depth is None and ep.extra["object_ids"] == [5, 6]
    assert next(import_ravens(tmp_path)).description == "build car"  # sub-goals differ: never one of them
    back = read_episode(write_episode(tmp_path / "e.h5", ep))
    assert back.language == goals and back.action_space["kind"] == "pick_place_14d"
