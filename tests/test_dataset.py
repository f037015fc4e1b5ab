"""Windows over episodes (simeval.episodes.dataset): the o_t, a_t, o_{t+1} alignment, padding, the first-k protocol,
normalisation and the refusal to mix action spaces, checked against episodes whose dynamics are known by hand."""

from __future__ import annotations

import numpy as np
import pytest

from simeval.episodes.dataset import (ArraySource, EpisodeInfo, NormStats, WindowDataset, WindowSpec, build_index,
                                      episode_ranks, rank_mask, window_starts)
from simeval.errors import UserError

SPACE = {"kind": "test_2d", "dims": ["a", "b"]}


def integrator_episode(n_actions: int, seed: int) -> dict:
    """o_{t+1} = o_t + a_t (state and a 1-pixel image whose red channel is the step index): the store's convention,
    n_actions + 1 rows, the last row's action a copy of the one before (padding)."""
    rng = np.random.default_rng(seed)
    a = rng.integers(-3, 4, size=(n_actions, 2)).astype(np.float32)
    s = np.concatenate([rng.integers(0, 5, size=(1, 2)), np.zeros((n_actions, 2))]).astype(np.float32)
    for t in range(n_actions):
        s[t + 1] = s[t] + a[t]
    image = np.zeros((n_actions + 1, 4, 4, 3), np.uint8)
    image[:, :, :, 0] = np.arange(n_actions + 1)[:, None, None]
    return {"image": image, "state": s, "action": np.concatenate([a, a[-1:]])}


def source(lengths=(12, 7, 20), tasks=("a", "a", "b"), space=SPACE) -> ArraySource:
    arrays = [integrator_episode(n, i) for i, n in enumerate(lengths)]
    infos = [EpisodeInfo(task=t, seed=i, group="g", n_rows=n + 1, action_space=space)
             for i, (t, n) in enumerate(zip(tasks, lengths))]
    return ArraySource(infos, arrays)


def test_window_starts_by_hand():
    assert window_starts(10, WindowSpec(length=4)).tolist() == [0, 1, 2, 3, 4, 5, 6]
    assert window_starts(10, WindowSpec(length=4, stride=3, offset=1)).tolist() == [1, 4]
    assert window_starts(10, WindowSpec(length=4, stride=4, pad_end=True)).tolist() == [0, 4, 8]
    assert window_starts(10, WindowSpec(length=4, stride=2, pad_start=2)).tolist() == [-2, 0, 2, 4, 6]
    assert window_starts(3, WindowSpec(length=4)).tolist() == []  # too short, no padding: no window
    assert build_index([10, 3], WindowSpec(length=4, stride=4, pad_end=True)).tolist() == [[0, 0], [0, 4], [0, 8],
                                                                                          [1, 0]]


def test_windows_align_observation_action_and_next_observation_as_stored():
    src = source()
    ds = WindowDataset(src, WindowSpec(length=5, stride=2, pad_start=2, pad_end=True))
    seen = 0
    for e, s in ds.windows(0):
        w = ds[(e, s)]
        ep = src.arrays[e]
        for i in range(5):
            r = s + i
            if not w["mask"][i]:
                assert r < 0 or r >= src.infos[e].n_rows
                assert not w["is_first"][i] and not w["image"][i].any()
                continue
            assert w["image"][i, 0, 0, 0] == r  # the frame of row r
            np.testing.assert_array_equal(w["state"][i], ep["state"][r])
            np.testing.assert_array_equal(w["action"][i], ep["action"][r])  # a_r follows o_r
            assert w["is_first"][i] == (r == 0)
            if r == 0:
                assert not w["prev_action"][i].any()  # nothing led to the reset observation
            else:  # the action that produced o_r: o_r = o_{r-1} + a_{r-1}
                np.testing.assert_array_equal(w["state"][i], ep["state"][r - 1] + w["prev_action"][i])
            if i + 1 < 5 and w["mask"][i + 1]:  # o_{r+1} = o_r + a_r within the window
                np.testing.assert_array_equal(w["state"][i + 1], w["state"][i] + w["action"][i])
            seen += 1
    assert seen > 40


def test_eval_windows_cover_every_row_once():
    src = source()
    ds = WindowDataset(src, WindowSpec(length=6, stride=6, pad_end=True))
    rows = [(int(w["episode"][i]), int(w["row"][i])) for e, s in ds.windows(0) for w in [ds[(e, s)]]
            for i in range(6) if w["mask"][i]]
    assert sorted(rows) == [(e, r) for e, n in enumerate([13, 8, 21]) for r in range(n)]


def test_first_k_per_task_by_seed_and_ranges():
    tasks = ["a", "b", "a", "a", "b"]
    seeds = [7, 3, 2, 9, 1]
    ranks = episode_ranks(tasks, seeds)
    assert ranks.tolist() == [1, 1, 0, 2, 0]
    assert rank_mask(ranks, 0, 2).tolist() == [True, True, True, False, True]
    assert rank_mask(ranks, 2, 3).tolist() == [False, False, False, True, False]


def test_random_offset_changes_per_epoch_and_is_seeded():
    src = source(lengths=(40,), tasks=("a",))
    spec = WindowSpec(length=5, stride=10, random_offset=True)
    a, b = WindowDataset(src, spec, seed=3), WindowDataset(src, spec, seed=3)
    offsets = {int(a.windows(e)[0, 1]) for e in range(20)}
    assert len(offsets) > 3 and offsets <= set(range(10))
    assert all((a.windows(e) == b.windows(e)).all() for e in range(5))


def test_normalisation_statistics_use_real_actions_only_and_are_applied():
    src = source(lengths=(3,), tasks=("a",))
    ep = src.arrays[0]
    ds = WindowDataset(src, WindowSpec(length=4))
    st = ds.fit_stats()
    np.testing.assert_allclose(st.action_mean, ep["action"][:3].mean(0), rtol=1e-6)  # row 3's padding left out
    np.testing.assert_allclose(st.state_std, np.where(ep["state"].std(0) < 1e-6, 1, ep["state"].std(0)), rtol=1e-6)
    ds.stats = st
    w = ds[(0, 0)]
    np.testing.assert_allclose(w["state"], (ep["state"] - st.state_mean) / st.state_std, rtol=1e-5)
    assert NormStats.from_dict(st.to_dict()).to_dict() == st.to_dict()


def test_mixed_action_spaces_are_refused_naming_both():
    src = source()
    src.infos[2].action_space = {"kind": "pick_place_14d", "dims": list("abcdefghijklmn")}
    with pytest.raises(UserError, match="test_2d.*pick_place_14d"):
        WindowDataset(src, WindowSpec(length=4))
    WindowDataset(src, WindowSpec(length=4), episodes=np.array([True, True, False]))  # one kind selected: fine


def test_store_windows_match_the_stored_rows(tmp_path):
    """The HDF5 reader returns what the store holds (same alignment as the in-memory source)."""
    from simeval.episodes.dataset import StoreSource
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    paths = write_group(tmp_path, "diverse", n_tasks=2, episodes=2, n_actions=9, size=16)
    ds = WindowDataset(StoreSource(paths, "front"), WindowSpec(length=4, stride=3, pad_end=True))
    mem = ds.source.preload()
    for e, s in ds.windows(0):
        a, b = ds[(e, s)], WindowDataset(mem, ds.spec)[(e, s)]
        for k in a:
            np.testing.assert_array_equal(a[k], b[k])


def test_an_episode_whose_data_is_damaged_behind_a_readable_header_is_named_with_its_remedy(tmp_path):
    """Bytes of an image chunk overwritten, the header intact (read_meta and so collect.py still pass it): a read
    of that episode names the file and what to do, as a user error, instead of h5py's bare OSError."""
    import h5py

    from simeval.episodes.dataset import StoreSource
    from simeval.episodes.episode import EpisodeFormatError
    from simeval.episodes.store import read_meta
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    paths = write_group(tmp_path, "diverse", n_tasks=1, episodes=2, n_actions=9, size=16)
    with h5py.File(paths[1], "r") as f:
        chunk = f["obs/rgb/front"].id.get_chunk_info(0)
    with open(paths[1], "r+b") as f:
        f.seek(chunk.byte_offset)
        f.write(b"\xff" * chunk.size)
    read_meta(paths[1])  # the header still reads
    src = StoreSource(paths, "front")
    np.testing.assert_array_equal(src.read(0, 0, 3)["state"], src.read_full(0, "state")[:3])  # the intact one
    for read in (lambda: src.read(1, 0, 3), lambda: src.read_full(1, "image")):
        with pytest.raises(EpisodeFormatError) as err:
            read()
        assert str(paths[1]) in str(err.value) and "delete it and re-run" in str(err.value)
        assert isinstance(err.value, UserError)


def test_windows_of_collected_episodes_pair_row_t_action_t_and_row_t1_as_the_simulator_does(tiny_sim_store):
    """On real episodes (src/collect.py, format 2): every window of two rows is (o_t, a_t, o_{t+1}), and feeding the
    stored a_t to make_env(..., action_space="joint") from reset reproduces the o_{t+1} the dataset returns, state
    and frame, bit for bit; the final row's padding action never starts a transition."""
    from simeval.episodes.dataset import StoreSource, store_paths_for
    from simeval.sim.env import make_env

    paths = store_paths_for(tiny_sim_store, "gensim", "stacking")
    src = StoreSource(paths[:1], "front")
    info = src.infos[0]
    assert info.action_space["kind"] == "joint_pos+suction" and info.n_rows > 50
    ds = WindowDataset(src, WindowSpec(length=2))  # no padding: windows (row t, row t + 1) for t < T
    idx = ds.windows(0)
    assert idx[:, 1].tolist() == list(range(info.n_rows - 1))  # T windows, one per action
    env = make_env(info.task, action_space="joint", image_size=(32, 32), cameras=("front",))
    obs, _ = env.reset(seed=info.seed)
    try:
        for e, t in idx:
            w = ds[(e, t)]
            assert w["mask"].all() and w["is_first"].tolist() == [t == 0, False]
            np.testing.assert_array_equal(obs["state"], w["state"][0], err_msg=f"o_{t}")
            np.testing.assert_array_equal(obs["rgb"]["front"], w["image"][0], err_msg=f"frame {t}")
            np.testing.assert_array_equal(w["prev_action"][1], w["action"][0])  # a_t is what led to o_{t+1}
            obs, *_ = env.step(w["action"][0])
            np.testing.assert_array_equal(obs["state"], w["state"][1], err_msg=f"o_{t + 1} = step(o_{t}, a_{t})")
            np.testing.assert_array_equal(obs["rgb"]["front"], w["image"][1], err_msg=f"frame {t + 1}")
    finally:
        env.close()
        src.close()


def test_a_truncated_episode_is_named_with_the_collect_command_for_the_episodes_this_run_needs(tmp_path):
    from simeval.measures.dynamics_diversity.run import store_source
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    paths = write_group(tmp_path, "diverse", n_tasks=1, episodes=2, n_actions=5, size=8)
    paths[0].write_bytes(paths[0].read_bytes()[:500])
    with pytest.raises(UserError) as err:
        store_source(tmp_path, "synthetic", "diverse", "front", "gensim", episodes_needed=45)
    text = str(err.value)
    assert text.startswith(f"{paths[0]}: not a readable HDF5 episode") and "collecting again moves it aside" in text
    assert "episodes=45" in text


def test_a_damaged_dataset_header_is_found_when_the_source_opens_before_any_training(tmp_path):
    """The object header of obs/state overwritten (the header attributes still read, as a partly overwritten file
    leaves them): StoreSource names the file when it is made, not when a training or evaluation reaches it."""
    import h5py

    from simeval.episodes.dataset import StoreSource
    from simeval.episodes.episode import EpisodeFormatError
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    paths = write_group(tmp_path, "diverse", n_tasks=1, episodes=2, n_actions=9, size=16)
    with h5py.File(paths[1], "r") as f:
        header = h5py.h5o.get_info(f["obs/state"].id).addr
    with open(paths[1], "r+b") as f:
        f.seek(header)
        f.write(b"\xa5" * 64)
    with pytest.raises(EpisodeFormatError, match=f"{paths[1]}: damaged episode .*delete it and re-run"):
        StoreSource(paths, "front")
    StoreSource(paths[:1], "front").close()  # the intact one opens


@pytest.mark.parametrize("camera", ["front", None])
def test_an_episode_whose_arrays_differ_in_rows_or_hold_nan_is_named_before_any_training(tmp_path, camera):
    """A fresh-clone trial's episodes: `action` cut to fewer rows than the observations (an IndexError deep in the
    state reading, a broadcast error in the pixel one) and obs/state NaN in ten rows (a training of NaN loss whose
    verdict blamed the model): each is one error naming the file, when the source opens."""
    import h5py

    from simeval.episodes.dataset import StoreSource
    from simeval.episodes.episode import EpisodeFormatError
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    paths = write_group(tmp_path, "diverse", n_tasks=1, episodes=3, n_actions=9, size=16)
    with h5py.File(paths[1], "r+") as f:
        action = f["action"][()]
        del f["action"]
        f.create_dataset("action", data=action[:4])
    with h5py.File(paths[2], "r+") as f:
        f["obs/state"][3:5] = np.nan
    with pytest.raises(EpisodeFormatError, match=rf"{paths[1]}: damaged episode: its arrays' rows differ \(.*"
                                                 r"action 4.*; n_steps says 10\)"):
        StoreSource(paths[:2], camera)
    with pytest.raises(EpisodeFormatError, match=rf"{paths[2]}: obs/state holds NaN or inf in 2 of its 10 rows "
                                                 r"\(first at row 3\)"):
        StoreSource([paths[0], paths[2]], camera)
    StoreSource(paths[:1], camera).close()  # the intact one opens


def test_an_array_source_with_nan_or_rows_that_differ_is_refused_naming_the_episode():
    info = EpisodeInfo(task="t", seed=3, group="g", n_rows=5, action_space={})
    ok = {"image": np.zeros((5, 4, 4, 3), np.uint8), "state": np.zeros((5, 2)), "action": np.zeros((5, 1))}
    ArraySource([info], [ok])
    with pytest.raises(UserError, match=r"t seed 3: damaged episode: its arrays' rows differ \(image 5, state 4"):
        ArraySource([info], [{**ok, "state": np.zeros((4, 2))}])
    with pytest.raises(UserError, match=r"t seed 3: action holds NaN or inf in 1 of its 5 rows \(first at row 2\)"):
        ArraySource([info], [{**ok, "action": np.array([[0.0], [0], [np.inf], [0], [0]])}])
