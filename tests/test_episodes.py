"""Episode store (atomic, validated), windows for sequence models, and importers of every documented format
(small files built here in each format)."""

import json
import os
import pickle
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from simeval.pipelines.importers import (import_bbsea_pt, import_gensim_pt, import_ravens,
                                        import_robogen_pt)
from simeval.episodes.episode import Episode, EpisodeFormatError
from simeval.episodes.store import EpisodeStore, WindowSpec, iter_windows, read_episode, read_meta, write_episode
from simeval.errors import UserError
from helpers import _write_ravens

ROOT = Path(__file__).resolve().parents[1]


def episode(task="stack-blocks", seed=0, t=10, group="stacking", success=True) -> Episode:
    rng = np.random.default_rng(seed)
    return Episode(
        pipeline="gensim", task=task, description=f"{task} please", group=group, seed=seed,
        rgb={"front": rng.integers(0, 255, (t, 8, 12, 3), dtype=np.uint8)},
        state=np.arange(t * 12, dtype=np.float32).reshape(t, 12) + 1000 * seed, action=rng.normal(size=(t, 6)),
        reward=np.r_[np.zeros(t - 1), 1.0], progress=np.linspace(0, 1, t), is_first=np.arange(t) == 0,
        is_terminal=np.arange(t) == t - 1, success=success, high_level_action=rng.normal(size=(2, 14)),
        high_level_step=np.array([0, t // 2]), scene_views=rng.integers(0, 255, (4, 8, 8, 3), dtype=np.uint8),
        control_hz=30.0, action_space={"kind": "test_6d", "dims": [f"a{i}" for i in range(6)]})


def test_the_simulator_builds_episodes_without_the_storage_layer():
    code = "import sys, simeval.sim.rollout; print('simeval.episodes.store' in sys.modules)"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    assert res.stdout.strip() == "False"


def test_round_trip(tmp_path):
    ep = episode()
    path = write_episode(tmp_path / "e.h5", ep)
    back = read_episode(path)
    np.testing.assert_array_equal(back.rgb["front"], ep.rgb["front"])
    np.testing.assert_allclose(back.state, ep.state)
    assert back.success and back.high_level_step.tolist() == [0, 5] and back.scene_views.shape == (4, 8, 8, 3)
    assert back.final_view is None  # optional; stored as a dataset when an episode has one
    ep.final_view = ep.scene_views[0]
    np.testing.assert_array_equal(read_episode(write_episode(tmp_path / "f.h5", ep)).final_view, ep.scene_views[0])
    meta = read_meta(path)
    assert meta["total_reward"] == 1.0 and meta["n_steps"] == 10 and meta["cameras"] == ["front"]


def test_a_camera_the_episode_does_not_record_names_the_key_that_asked_for_it(tmp_path):
    path = write_episode(tmp_path / "e.h5", episode())
    with pytest.raises(UserError) as e:
        read_episode(path, ["front", "side"], "policy.model.cameras")
    assert str(e.value) == (f"policy.model.cameras=[front,side]: {path} records the cameras front; use those, or "
                            "collect with record.cameras including the others")
    assert list(read_episode(path, ["front"], "policy.model.cameras").rgb) == ["front"]


def test_inconsistent_episode_is_rejected(tmp_path):
    ep = episode()
    ep.reward = ep.reward[:-1]
    with pytest.raises(EpisodeFormatError, match="10 rows of actions but lengths"):
        write_episode(tmp_path / "e.h5", ep)
    assert list(tmp_path.iterdir()) == []  # nothing half-written


def test_truncated_and_foreign_files_are_clear_errors(tmp_path):
    path = write_episode(tmp_path / "e.h5", episode())
    data = path.read_bytes()
    (tmp_path / "cut.h5").write_bytes(data[: len(data) // 2])
    with pytest.raises(EpisodeFormatError, match="cut.h5"):
        read_episode(tmp_path / "cut.h5")
    (tmp_path / "junk.h5").write_text("hello")
    with pytest.raises(EpisodeFormatError, match="junk.h5: not a readable HDF5"):
        read_meta(tmp_path / "junk.h5")
    import h5py

    with h5py.File(tmp_path / "incomplete.h5", "w") as f:  # what a writer killed before marking complete leaves
        f.attrs["schema"] = 2
    with pytest.raises(EpisodeFormatError, match="incomplete episode"):
        read_meta(tmp_path / "incomplete.h5")
    with pytest.raises(EpisodeFormatError, match="not found"):
        read_episode(tmp_path / "nope.h5")


def test_store_index_and_first_k_per_task(tmp_path):
    store = EpisodeStore(tmp_path)
    for task, group in (("stack-a", "stacking"), ("place-b", "placement")):
        for seed in (5, 1, 3):
            store.write(episode(task, seed, group=group))
    assert len(store.index()) == 6 and len(store.index("gensim", "stacking")) == 3
    firsts = store.first_k_per_task(2, "gensim")
    assert [(m["task"], m["seed"]) for m in firsts] == [("place-b", 1), ("place-b", 3), ("stack-a", 1), ("stack-a", 3)]
    with pytest.raises(ValueError, match="fewer than the 4"):
        store.first_k_per_task(4)
    assert store.exists("gensim", "stack-a", 5) and not store.exists("gensim", "stack-a", 6)


def test_stale_temp_files_of_killed_writers_are_removed(tmp_path):
    store = EpisodeStore(tmp_path)
    path = store.write(episode("t", 0))
    old, fresh = path.parent / ".episode_000001.abc.tmp", path.parent / ".episode_000002.def.tmp"
    old.write_bytes(b"half")
    fresh.write_bytes(b"in progress")
    os.utime(old, (0, 0))
    assert store.remove_stale_temp_files() == 1 and not old.exists() and fresh.exists()
    assert len(store.index()) == 1  # neither kind of temp file is ever taken for an episode


def test_windows_never_cross_episodes_unless_asked(tmp_path):
    store = EpisodeStore(tmp_path)
    paths = [store.write(episode("t", s, t=10)) for s in (0, 1)]
    wins = list(iter_windows(paths, WindowSpec(length=4), camera="front"))
    assert len(wins) == 4  # 2 per 10-step episode; the 2 leftover steps of each are not glued to the next
    assert all(len(np.unique(w["obs/state"][:, 0] // 1000)) == 1 for w in wins)
    assert wins[0]["rgb"].shape == (4, 8, 12, 3) and wins[0]["is_first"][0]
    crossing = list(iter_windows(paths, WindowSpec(length=4, cross_episodes=True)))
    assert len(crossing) == 5  # 20 steps as one stream
    seam = crossing[2]  # steps 8..11: the end of episode 0 and the start of episode 1
    assert seam["is_first"].tolist() == [False, False, True, False]
    overlapping = list(iter_windows(paths[:1], WindowSpec(length=4, stride=2)))
    assert len(overlapping) == 4
    with pytest.raises(EpisodeFormatError, match="no camera 'top'"):
        list(iter_windows(paths, WindowSpec(length=4), camera="top"))


def test_import_ravens(tmp_path):
    _write_ravens(tmp_path / "data")
    eps = list(import_ravens(tmp_path / "data", image_size=(12, 16)))
    assert len(eps) == 2
    ep = eps[0]
    assert ep.task == "stack-block-pyramid" and ep.group == "stacking" and ep.seed == 100
    assert ep.description == "stack the blocks into a pyramid" and ep.success
    # 3 actions, 4 rows: the final (solved) observation is kept and the last action is padding
    assert ep.n_steps == 4 and ep.rgb["color_0"].shape == (4, 12, 16, 3) and set(ep.rgb) == {"color_0", "color_1", "color_2"}
    assert ep.depth["color_1"].shape == (4, 12, 16) and ep.depth["color_1"].dtype == np.float32
    assert ep.high_level_action.shape == (3, 14) and ep.high_level_action[0, 7:10].tolist() == pytest.approx([0.3, 0.4, 0.05])
    assert ep.action_space["kind"] == "pick_place_14d" and ep.action.shape == (4, 14)
    assert ep.reward.tolist() == pytest.approx([1 / 3] * 3 + [0]) and ep.progress.tolist() == pytest.approx([0, 1 / 3, 2 / 3, 1])
    assert ep.language == ["stack the blocks into a pyramid"] * 4
    (tmp_path / "data" / "stack-block-pyramid-train" / "color" / "000001-101.pkl").write_bytes(b"garbage")
    with pytest.raises(EpisodeFormatError, match="000001-101.pkl: unreadable pickle"):
        list(import_ravens(tmp_path / "data"))


def test_import_authors_pt_formats(tmp_path):
    h, low = 2, 6
    gensim = {"obs_high": {"color_0": np.zeros((h, 18, 24, 3), np.uint8), "color_1": np.zeros((h, 48, 64, 3), np.uint8)},
              "action_high": {"pose0": np.zeros((h, 7)), "pose1": np.ones((h, 7))},
              "obs_low": {"state": np.zeros((low, 12)), "rgb": np.zeros((low, 18, 24, 3), np.uint8),
                          "depth": np.zeros((low, 18, 24, 1), np.float32)},
              "action_low": np.zeros((low, 6)), "high_step": [0, 3], "is_first": np.arange(low) == 0,
              "is_terminal": np.arange(low) == low - 1, "episode_len_high": h, "episode_len_low": low, "seed": 7}
    (tmp_path / "g" / "place-red-in-green").mkdir(parents=True)
    torch.save(gensim, tmp_path / "g" / "place-red-in-green" / f"episode_000_{h}_{low}.pt")
    ep = next(import_gensim_pt(tmp_path / "g", descriptions={"place-red-in-green": "put red blocks in green bowls"}))
    assert ep.group == "placement" and ep.state.shape == (6, 12) and ep.high_level_action.shape == (2, 14)
    assert ep.high_level_step.tolist() == [0, 3] and ep.seed == 7 and ep.description.startswith("put red")
    assert ep.scene_views is None  # the two cameras differ in size: no stack without image_size
    assert next(import_gensim_pt(tmp_path / "g", image_size=(12, 16))).scene_views.shape == (2, 12, 16, 3)

    bbsea = {"image": torch.zeros((5, 16, 24, 3), dtype=torch.uint8), "state": torch.zeros((5, 7)),
             "action": torch.zeros((5, 9)), "is_first": torch.arange(5) == 0, "is_terminal": torch.arange(5) == 4}
    d = tmp_path / "b" / "3" / "Open the drawer using the handle"
    d.mkdir(parents=True)
    torch.save(bbsea, d / "0_True.pt")
    torch.save(bbsea, d / "1_False.pt")
    eps = list(import_bbsea_pt(tmp_path / "b"))
    assert [e.success for e in eps] == [True, False] and eps[0].group == "drawer" and eps[0].task.startswith("3/")

    robogen = {"action": np.zeros((4, 7), np.float32), "state": np.zeros((4, 20)), "image": np.zeros((4, 19, 24, 3), np.uint8),
               "is_first": np.arange(4) == 0, "is_terminal": np.arange(4) == 3, "length": 4}
    (tmp_path / "r" / "Open_Laptop").mkdir(parents=True)
    torch.save(robogen, tmp_path / "r" / "Open_Laptop" / "episode_2_4.pt")
    ep = next(import_robogen_pt(tmp_path / "r", groups={"Open_Laptop": "table-top"}))
    assert ep.group == "table-top" and ep.seed == 2 and ep.description == "Open Laptop"
    assert not ep.success_known and ep.progress is None  # these files record neither
    from simeval.measures.quality.episode_bundles import export_bundles
    from simeval.measures.quality.bundle import load_bundles
    from simeval.measures.quality.run import oracle_completion

    store = EpisodeStore(tmp_path / "store")
    store.write(ep)
    back = read_episode(store.path_for("robogen", "Open_Laptop", 2))
    assert not back.success_known and back.progress is None
    export_bundles(store.root, tmp_path / "bundles")
    bundles, _ = load_bundles(tmp_path / "bundles")
    assert bundles[0].ground_truth == {} and oracle_completion(bundles) == {}  # unknown is not scored as 0
    torch.save({"image": np.zeros((4, 2, 2, 3), np.uint8)}, tmp_path / "r" / "Open_Laptop" / "episode_3_4.pt")
    with pytest.raises(EpisodeFormatError, match="episode_3_4.pt: missing key 'state'"):
        list(import_robogen_pt(tmp_path / "r"))


def test_import_entrypoint_resumes(tmp_path):
    _write_ravens(tmp_path / "data", episodes=3)
    args = [sys.executable, str(ROOT / "src" / "import_data.py"), "format=ravens", f"src={tmp_path / 'data'}",
            f"store={tmp_path / 'store'}", "image_size=[12,16]"]
    res = subprocess.run([*args, f"hydra.run.dir={tmp_path / 'r1'}"], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    assert json.loads((tmp_path / "r1" / "result.json").read_text())["values"]["written"] == 3
    res = subprocess.run([*args, f"hydra.run.dir={tmp_path / 'r2'}"], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    values = json.loads((tmp_path / "r2" / "result.json").read_text())["values"]
    assert values["written"] == 0 and values["skipped"] == 3
    assert values["tasks"]["stack-block-pyramid"] == {"episodes": 3, "success": 3, "success_unknown": 0,
                                                      "group": "stacking"}
    assert len(EpisodeStore(tmp_path / "store").index("gensim")) == 3
    # a resumed import does not even read the sources of episodes it already holds
    (tmp_path / "data" / "stack-block-pyramid-train" / "color" / "000000-100.pkl").write_bytes(b"damaged later")
    res = subprocess.run([*args, f"hydra.run.dir={tmp_path / 'r3'}"], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    assert json.loads((tmp_path / "r3" / "result.json").read_text())["values"]["skipped"] == 3


def test_store_files_get_the_normal_file_mode(tmp_path):
    from simeval.results import umask_file_mode

    old = os.umask(0o022)  # what a shared store's writers typically run with
    try:
        path = EpisodeStore(tmp_path).write(episode())
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o644  # readable by the group and others, as plainly created files
    assert umask_file_mode() == 0o666 & ~old  # (the helper the store uses follows the umask in force)


def _corrupt_chunk(path: Path, dataset: str, index: int) -> None:
    import h5py

    with h5py.File(path, "r") as f:
        info = f[dataset].id.get_chunk_info(index)
    with path.open("r+b") as fh:
        fh.seek(info.byte_offset)
        fh.write(b"\xff" * info.size)


def test_a_damaged_chunk_read_through_windows_names_the_file(tmp_path):
    path = EpisodeStore(tmp_path).write(episode(t=10))
    _corrupt_chunk(path, "obs/rgb/front", 6)
    windows = iter_windows([path], WindowSpec(length=4), camera="front")
    assert next(windows)["rgb"].shape == (4, 8, 12, 3)  # frames 0-3 are intact and still read
    with pytest.raises(EpisodeFormatError, match=r"episode_000000\.h5: damaged episode"):
        next(windows)
    with pytest.raises(EpisodeFormatError, match=r"episode_000000\.h5: damaged episode"):
        list(iter_windows([path], WindowSpec(length=4, cross_episodes=True), camera="front"))


def test_an_unreadable_stored_episode_is_moved_aside_not_trusted(tmp_path, caplog):
    store = EpisodeStore(tmp_path)
    good = store.write(episode(seed=0))
    empty = store.path_for("gensim", "stack-blocks", 1)
    empty.write_bytes(b"")  # what a full disk or a crashed copy leaves
    assert store.exists_intact("gensim", "stack-blocks", 0)
    assert not store.exists_intact("gensim", "stack-blocks", 1) and not empty.exists()
    aside = list(empty.parent.glob("episode_000001.h5.corrupt-*"))
    assert len(aside) == 1 and aside[0].stat().st_size == 0
    assert "episode_000001.h5: unreadable episode moved aside" in caplog.text
    assert store.paths() == [good]  # the file moved aside is not taken for an episode


def _robogen_file(folder: Path, image, name="episode_0_4.pt") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    torch.save({"action": np.zeros((4, 7), np.float32), "state": np.zeros((4, 20)), "image": image,
                "is_first": np.arange(4) == 0, "is_terminal": np.arange(4) == 3}, folder / name)
    return folder / name


def test_importers_convert_float_images_by_range(tmp_path):
    rng = np.random.default_rng(0)
    unit = rng.uniform(0, 1, (4, 6, 8, 3)).astype(np.float32)  # what RoboGen renders: floats in [0, 1]
    _robogen_file(tmp_path / "a" / "Open_Laptop", unit)
    ep = next(import_robogen_pt(tmp_path / "a"))
    np.testing.assert_array_equal(ep.rgb["image"], np.round(unit * 255).astype(np.uint8))
    assert ep.rgb["image"].mean() > 100  # not the black frames a plain cast gives
    _robogen_file(tmp_path / "b" / "Open_Laptop", torch.tensor(unit * 255, dtype=torch.float64))
    np.testing.assert_array_equal(next(import_robogen_pt(tmp_path / "b")).rgb["image"], np.round(unit * 255))
    bad = _robogen_file(tmp_path / "c" / "Open_Laptop", unit * 2 - 1)  # [-1, 1]: no range to guess from
    with pytest.raises(EpisodeFormatError, match=r"episode_0_4\.pt: images 'image' are float32, values in \[-0.99"):
        next(import_robogen_pt(tmp_path / "c"))
    assert bad.exists()
    _write_ravens(tmp_path / "r", episodes=1)  # the other importers convert the same way
    color_file = next((tmp_path / "r").glob("*/color/*.pkl"))
    color = pickle.loads(color_file.read_bytes())
    color_file.write_bytes(pickle.dumps(color.astype(np.float32) / 255))
    # the final observation is kept (T + 1 rows)
    np.testing.assert_array_equal(next(import_ravens(tmp_path / "r")).rgb["color_0"], color[:, 0])


def test_an_import_replaces_an_unreadable_stored_episode(tmp_path, caplog):
    from simeval.pipelines.importers import import_into_store

    _write_ravens(tmp_path / "data", episodes=2)
    store = EpisodeStore(tmp_path / "store")
    empty = store.path_for("gensim", "stack-block-pyramid", 100)
    empty.parent.mkdir(parents=True)
    empty.write_bytes(b"")
    summary = import_into_store(import_ravens, tmp_path / "data", store, progress=False)
    assert summary["written"] == 2 and len(store.index()) == 2
    assert "unreadable episode moved aside" in caplog.text


def _import(tmp_path, *args):
    return subprocess.run([sys.executable, str(ROOT / "src" / "import_data.py"), f"store={tmp_path / 'store'}",
                           f"hydra.run.dir={tmp_path / 'run'}", *args], cwd=ROOT, capture_output=True, text=True)


def _one_line_error(res, *expected):
    """Exit status 2 and one line of error (after the progress bar, which shows how far the run got)."""
    assert res.returncode == 2, res.stderr[-2000:]
    lines = [x for x in res.stderr.strip().splitlines() if not re.match(r"(importing|collecting).*(it|episode)/s]", x)]
    assert "Traceback" not in res.stderr and len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    for text in expected:
        assert text in res.stderr, res.stderr


def test_import_entrypoint_errors_are_one_line(tmp_path):
    data = _write_ravens(tmp_path / "data", episodes=1).parent
    _one_line_error(_import(tmp_path, "format=ravens", f"src={data}", "image_size=[12]"),
                    "error: image_size must be null (keep the source size) or [H, W]", "got [12]")
    action = next((data).glob("*/action/*.pkl"))
    action.write_bytes(pickle.dumps([{"pose0": ((0, 0, 0), (0, 0, 0, 1))}, None]))  # pose1 missing
    _one_line_error(_import(tmp_path, "format=ravens", f"src={data}"),
                    f"{action}: action 0 is not {{pose0, pose1}}", "got ['pose0']")
    scene = tmp_path / "bbsea" / "3"
    scene.mkdir(parents=True)
    bad = os.fsencode(scene) + b"/Open the dr\xe9wer"  # a Latin-1 name copied onto a UTF-8 system
    os.mkdir(bad)
    with open(os.path.join(bad, b"0_True.pt"), "wb") as f:
        torch.save({"image": np.zeros((2, 4, 4, 3), np.uint8)}, f)
    _one_line_error(_import(tmp_path, "format=bbsea_pt", f"src={tmp_path / 'bbsea'}"),
                    f"{scene}/Open the dr\\xe9wer: folder name is not valid UTF-8; rename it")


def test_bbsea_task_folders_must_have_utf8_names(tmp_path):
    from simeval.pipelines.task_texts import load_tasks
    from simeval.pipelines.task_records import TaskSourceError

    os.makedirs(os.fsencode(tmp_path / "trajectory" / "0") + b"/Put the \xe9 block in the drawer")
    with pytest.raises(TaskSourceError, match=r"trajectory/0/Put the \\xe9 block in the drawer: folder name is not"):
        load_tasks("bbsea", root=str(tmp_path))
