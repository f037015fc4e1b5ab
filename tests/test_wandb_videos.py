"""`logger=wandb` (offline) on the two entrypoints that train models, with the `tiny` presets: src/diversity.py logs
the world model's open-loop prediction videos and src/generalization.py its best/worst rollout videos. Read back
from the run's `.wandb` file (history entries of type video-file) and its `files/media/videos/`, compared with the
mp4 files the run wrote to its own folder and with the episodes they show; no API key in any written file."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from helpers import _no_secret_anywhere, _run, wandb_records

SIZE, WINDOW, CONTEXT = 16, 8, 5  # conf/world_model/tiny.yaml image_size and window length; conf/diversity.yaml


def logged_videos(run_dir: Path) -> dict[str, dict]:
    """{history key: {caption, path (inside the offline run's files/), sha256, ...}} of every video logged."""
    [path] = list(run_dir.glob("wandb/offline-run-*/run-*.wandb"))
    fields: dict[str, dict] = defaultdict(dict)
    for r in wandb_records(path):
        if r.WhichOneof("record_type") == "history":
            for item in r.history.item:
                keys = list(item.nested_key) or item.key.split("/")
                fields["/".join(keys[:-1])][keys[-1]] = json.loads(item.value_json)
    return {k: v for k, v in fields.items() if v.get("_type") == "video-file"}


def frames_of(path: Path) -> np.ndarray:
    import imageio.v2 as imageio

    return np.stack([f for f in imageio.get_reader(path)])  # list() asks the ffmpeg reader its length: inf


def test_diversity_logs_open_loop_prediction_videos(wandb_env, tmp_path):
    from simeval.measures.dynamics_diversity.controls.synthetic import make_group, write_group

    write_group(tmp_path / "store", "diverse", n_tasks=2, episodes=3, n_actions=10, size=SIZE, pipeline="gensim")
    res = _run("diversity.py", "debug=tiny", "pipeline=gensim", "task_group=diverse", f"store={tmp_path / 'store'}",
               f"checkpoint_dir={tmp_path / 'ck'}", "progress=false", "episodes=2", "protocol=paper", "eval_episodes=[1,3]",
               "heldout_episodes=null", "threads=1", f"hydra.run.dir={tmp_path / 'run'}", env=wandb_env, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    run = tmp_path / "run"
    rec = json.loads((run / "result.json").read_text())
    tasks = ["diverse-0-move", "diverse-1-turn"]
    assert rec["values"]["videos"] == {t: str(run / "videos" / f"open_loop_{t}.mp4") for t in tasks}
    episodes = make_group("diverse", 2, 3, 10, SIZE)  # what write_group stored: task t's seed e at 3 t + e
    for t, task in enumerate(tasks):
        frames = frames_of(run / "videos" / f"open_loop_{task}.mp4")
        # the window's 8 frames, truth | reconstruction | open loop at 16 px with 2 px separators
        assert frames.shape == (WINDOW, SIZE, 3 * SIZE + 2 * 2, 3)
        truth = episodes.arrays[3 * t]["image"][:WINDOW].astype(float)  # the task's lowest-seed evaluated episode
        assert np.abs(frames[:, :, :SIZE] - truth).mean() < 10  # mp4 is lossy; another episode differs far more
        other = episodes.arrays[3 * t + 1]["image"][:WINDOW].astype(float)
        assert np.abs(other - truth).mean() > 2 * np.abs(frames[:, :, :SIZE] - truth).mean()
        sep = frames[:, SIZE // 2, SIZE + 1].astype(int)  # a separator column: white, then red once imagined
        assert (sep[:CONTEXT] > 200).all() and (sep[CONTEXT:, 0] > 150).all() and (sep[CONTEXT:, 1:] < 100).all()
    logged = logged_videos(run)
    assert sorted(logged) == [f"open_loop/{t}" for t in tasks]
    [files] = list(run.glob("wandb/offline-run-*/files"))
    for task in tasks:
        entry = logged[f"open_loop/{task}"]
        assert entry["caption"].startswith(f"{task}: ground truth | reconstruction | open loop after {CONTEXT}")
        # W&B copied the run's own mp4 into the offline run (media/videos/), so `wandb sync` uploads it
        assert entry["path"].startswith("media/videos/open_loop/")
        assert (files / entry["path"]).read_bytes() == (run / "videos" / f"open_loop_{task}.mp4").read_bytes()
    _no_secret_anywhere(tmp_path)


def test_generalization_logs_best_and_worst_rollout_videos(tiny_sim_store, wandb_env, tmp_path):
    res = _run("generalization.py", "debug=tiny", f"store={tiny_sim_store}", "task_group=stacking",
               "tasks=[stack-two-blocks]", f"checkpoint_dir={tmp_path / 'ckpt'}", "eval.splits=[train]",
               "eval.sampler_check=false", f"hydra.run.dir={tmp_path / 'run'}", env=wandb_env, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    run = tmp_path / "run"
    rec = json.loads((run / "result.json").read_text())
    steps = rec["values"]["tasks"][0]["episodes"][0]["steps"]
    mp4 = run / "videos" / "worst_train_stack-two-blocks.mp4"
    assert rec["values"]["videos"] == {"worst": str(mp4), "best": str(mp4)}  # one task: it is both
    assert len(frames_of(mp4)) == steps + 1  # the reset frame, then one per control step
    logged = logged_videos(run)
    assert sorted(logged) == ["rollout/best", "rollout/worst"]
    [files] = list(run.glob("wandb/offline-run-*/files"))
    for which in ("best", "worst"):
        entry = logged[f"rollout/{which}"]
        assert entry["caption"] == f"{which} task of the train split: stack-two-blocks (seed 100000, camera front)"
        assert (files / entry["path"]).read_bytes() == mp4.read_bytes()
    _no_secret_anywhere(tmp_path)
