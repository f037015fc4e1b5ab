"""robomimic / robosuite HDF5 import (simeval.pipelines.robomimic_format) against robomimic 0.3.0's own
SequenceDataset reading the same file: actions, low-dimensional observations and frames equal, mask/ filter keys
read as robomimic reads them; bad files one line with exit 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from helpers import one_line_error
from simeval.episodes.store import EpisodeStore, read_episode

ROOT = Path(__file__).resolve().parents[1]
DEMOS, STEPS, CAMERAS, LOW = 5, 9, ("agentview", "robot0_eye_in_hand"), {"robot0_eef_pos": 3,
                                                                       "robot0_gripper_qpos": 2, "object": 10}


def write_robosuite_style(path: Path, demos: int = DEMOS, steps: int = STEPS) -> dict:
    """A file in the layout robosuite's and robomimic's conversion scripts write (data/demo_N/{obs, next_obs,
    actions, rewards, dones, states}, data.attrs env_args and total, demo attrs num_samples, mask/<key>); returns
    what was written, demo by demo."""
    rng = np.random.default_rng(7)
    written = {}
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        data.attrs["env_args"] = json.dumps({"env_name": "PickPlaceCan", "type": 1, "env_kwargs": {
            "control_freq": 20, "camera_names": list(CAMERAS), "reward_shaping": False}})
        for d in range(demos):
            g = data.create_group(f"demo_{d}")
            frames = {c: rng.integers(0, 256, (steps + 1, 24, 32, 3), dtype=np.uint8) for c in CAMERAS}
            low = {k: rng.normal(size=(steps + 1, n)) for k, n in LOW.items()}
            for key, v in [*((f"{c}_image", x) for c, x in frames.items()), *low.items()]:
                g.create_dataset(f"obs/{key}", data=v[:-1])
                g.create_dataset(f"next_obs/{key}", data=v[1:])
            g.create_dataset("obs/agentview_depth", data=rng.random((steps, 24, 32, 1)).astype(np.float32))
            g.create_dataset("next_obs/agentview_depth", data=rng.random((steps, 24, 32, 1)).astype(np.float32))
            actions = rng.uniform(-1, 1, (steps, 7))
            rewards = np.zeros(steps)
            rewards[-1] = float(d % 2 == 0)  # even demos succeed
            g.create_dataset("actions", data=actions)
            g.create_dataset("rewards", data=rewards)
            g.create_dataset("dones", data=(np.arange(steps) == steps - 1).astype(np.int64))
            g.create_dataset("states", data=rng.normal(size=(steps, 32)))
            g.attrs["num_samples"] = steps
            written[d] = {"frames": frames, "low": low, "actions": actions, "rewards": rewards}
        data.attrs["total"] = demos * steps
        f.create_dataset("mask/train", data=np.array([f"demo_{d}" for d in range(demos - 2)], dtype="S"))
        f.create_dataset("mask/valid", data=np.array([f"demo_{d}" for d in range(demos - 2, demos)], dtype="S"))
    return written


def _import(tmp_path: Path, src, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "src" / "import_data.py"), "format=robomimic", f"src={src}",
                           f"store={tmp_path / 'store'}", f"hydra.run.dir={tmp_path / 'run'}", *args], cwd=ROOT,
                          capture_output=True, text=True)


def test_the_import_reads_what_robomimics_sequence_dataset_reads(tmp_path):
    robomimic_dataset = pytest.importorskip("robomimic.utils.dataset")
    obs_utils = pytest.importorskip("robomimic.utils.obs_utils")
    path = tmp_path / "can_demos.hdf5"
    written = write_robosuite_style(path)
    res = _import(tmp_path, path, "filter_key=train")
    assert res.returncode == 0, res.stderr[-2000:]
    eps = {e.seed: e for e in (read_episode(p) for p in EpisodeStore(tmp_path / "store").paths("can_demos"))}
    assert sorted(eps) == [0, 1, 2]  # mask/train only
    obs_keys = [f"{c}_image" for c in CAMERAS] + sorted(LOW)
    obs_utils.initialize_obs_utils_with_obs_specs({"obs": {"rgb": obs_keys[:2], "low_dim": obs_keys[2:]}})
    theirs = robomimic_dataset.SequenceDataset(str(path), obs_keys, ("actions", "rewards", "dones"),
                                               filter_by_attribute="train", load_next_obs=True)
    assert len(theirs) == 3 * STEPS  # robomimic reads the same mask
    for i in range(len(theirs)):
        item = theirs[i]
        demo = theirs._index_to_demo_id[i]
        t = i - theirs._demo_id_to_start_indices[demo]
        ep = eps[int(demo.split("_")[1])]
        np.testing.assert_array_equal(ep.action[t], item["actions"][0].astype(np.float32))
        for c in CAMERAS:  # the frames as stored (robomimic's models, not its dataset, scale them)
            np.testing.assert_array_equal(ep.rgb[c][t], item["obs"][f"{c}_image"][0])
        low = np.concatenate([np.ravel(item["obs"][k][0]) for k in sorted(LOW)]).astype(np.float32)
        np.testing.assert_array_equal(ep.state[t], low)
        nxt = np.concatenate([np.ravel(item["next_obs"][k][0]) for k in sorted(LOW)]).astype(np.float32)
        np.testing.assert_array_equal(ep.state[t + 1], nxt)  # row t + 1 is what action t led to
    for d, ep in eps.items():
        w = written[d]
        assert ep.n_steps == STEPS + 1 and ep.rgb["agentview"].shape == (STEPS + 1, 24, 32, 3)
        np.testing.assert_array_equal(ep.rgb["robot0_eye_in_hand"], w["frames"]["robot0_eye_in_hand"])
        np.testing.assert_array_equal(ep.action[:-1], w["actions"].astype(np.float32))
        assert ep.success == (d % 2 == 0) and ep.success_known and ep.control_hz == 20
        assert ep.task == "pickplacecan" and ep.description == "pick place can"
        assert ep.state_names[:3] == ["object.0", "object.1", "object.2"] and ep.extra["filter_keys"] == ["train"]
        assert "agentview_depth" not in ep.rgb and len(ep.state_names) == sum(LOW.values())
    again = _import(tmp_path, path)  # every demo now: the 3 stored are skipped, the 2 valid ones written
    assert again.returncode == 0, again.stderr[-2000:]
    values = json.loads((tmp_path / "run" / "result.json").read_text())["values"]
    assert (values["written"], values["skipped"]) == (2, 3)


def test_bad_robomimic_files_are_one_line_naming_the_file_or_key(tmp_path):
    path = tmp_path / "demos.hdf5"
    write_robosuite_style(path, demos=2, steps=3)
    one_line_error(_import(tmp_path, tmp_path), f"src={tmp_path}: is a folder; give the file")
    one_line_error(_import(tmp_path, tmp_path / "nope.hdf5"), "does not exist; give the file")
    one_line_error(_import(tmp_path, path, "filter_key=test"), f"{path}: no mask/test (filter keys: train, valid)")
    with h5py.File(tmp_path / "nodata.hdf5", "w") as f:
        f.create_dataset("demos", data=np.zeros(3))
    one_line_error(_import(tmp_path, tmp_path / "nodata.hdf5"), "nodata.hdf5: no 'data' group: not a robomimic")
    (tmp_path / "text.hdf5").write_text("not hdf5")
    one_line_error(_import(tmp_path, tmp_path / "text.hdf5"), "text.hdf5: not a readable HDF5 file")
    cut = tmp_path / "cut.hdf5"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    one_line_error(_import(tmp_path, cut), "cut.hdf5: ")
    with h5py.File(path, "a") as f:
        del f["data/demo_1/actions"]
    one_line_error(_import(tmp_path, path), f"{path}: data/demo_1 has no 'actions'")
