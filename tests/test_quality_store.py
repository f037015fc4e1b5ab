"""Judging the episodes of a store: judge=oracle reads each episode's recorded success/progress from the store
(no bundle export), and its scores match what the files say, read here independently with h5py; a VLM judge
still gets the episodes exported as bundles (it needs images)."""

import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from simeval.episodes.store import Episode, EpisodeStore

ROOT = Path(__file__).resolve().parents[1]


def _episode(task, seed, *, success, progress, success_known=True, pipeline="gensim", steps=6):
    rng = np.random.default_rng(seed)
    return Episode(pipeline=pipeline, task=task, description=f"do {task}", group="stacking", seed=seed,
                   rgb={"top": rng.integers(0, 255, (steps, 16, 16, 3), dtype=np.uint8),
                        "front": rng.integers(0, 255, (steps, 16, 16, 3), dtype=np.uint8)},
                   state=np.zeros((steps, 12)), action=np.zeros((steps, 6)), reward=np.zeros(steps),
                   is_first=np.arange(steps) == 0, is_terminal=np.arange(steps) == steps - 1,
                   progress=None if progress is None else np.linspace(0, progress, steps).astype(np.float32),
                   success=success, success_known=success_known,
                   scene_views=rng.integers(0, 255, (4, 16, 16, 3), dtype=np.uint8),
                   action_space={"kind": "test_6d"})  # every stored episode declares its action space


@pytest.fixture
def store(tmp_path) -> EpisodeStore:
    store = EpisodeStore(tmp_path / "store")
    store.write(_episode("stack-two-blocks", 0, success=True, progress=1.0))
    store.write(_episode("stack-block-tower", 1, success=False, progress=0.25))
    # a success whose shaped progress stays below 1 (Meta-World's reward / 10 at success): complete all the same
    store.write(_episode("align-rope", 2, success=True, progress=0.7))
    store.write(_episode("put-block-in-zone", 0, success=False, progress=None))  # success only
    store.write(_episode("open-laptop", 3, success=False, progress=None, success_known=False))  # nothing known
    return store


def expected_from_files(store: EpisodeStore) -> tuple[dict[str, float], set[str]]:
    """What the oracle should give, from the HDF5 files themselves: 10 where a success is recorded, else 10 x final
    progress where progress is known, else 0 for a recorded failure; the rest has no ground truth."""
    scores, unknown = {}, set()
    for path in store.root.rglob("episode_*.h5"):
        with h5py.File(path, "r") as f:
            a = f.attrs
            name = f"{a['task']}#{a['seed']}"
            if a["success_known"] and a["success"]:
                scores[name] = 10.0
            elif a["progress_known"]:
                scores[name] = 10.0 * float(f["progress"][-1])
            elif a["success_known"]:
                scores[name] = 0.0
            else:
                unknown.add(name)
    return scores, unknown


def _quality(*args):
    return subprocess.run([sys.executable, str(ROOT / "src" / "quality.py"), *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)


def test_oracle_scores_the_store_episodes_from_their_recorded_ground_truth(store, tmp_path):
    want, unknown = expected_from_files(store)
    assert want == {"stack-two-blocks#0": 10.0, "stack-block-tower#1": 2.5, "align-rope#2": 10.0,
                    "put-block-in-zone#0": 0.0}
    assert unknown == {"open-laptop#3"}
    res = _quality("judge=oracle", f"episodes.store={store.root}", f"hydra.run.dir={tmp_path / 'q'}")
    assert res.returncode == 0, res.stderr[-2000:]
    rec = json.loads((tmp_path / "q" / "result.json").read_text())
    got = {task: v["mean"] for task, v in rec["values"]["task_completion"].items()}
    assert got == pytest.approx(want)
    assert set(rec["errors"]) == unknown and "no ground truth" in rec["errors"]["open-laptop#3"]
    assert rec["tasks"]["stack-block-tower#1"] == {"pipeline": "gensim"}
    assert not (tmp_path / "q" / "bundles").exists()  # read from the store: no PNG exported, none read back
    assert "quality (oracle): 5 tasks, 4 scored, 1 failed (open-laptop#3)" in res.stdout + res.stderr
    mean = sum(want.values()) / len(want)  # from the files' ground truth, as `want` above
    assert f"; task_completion {mean:.2f} (mean of 4)" in res.stdout + res.stderr


def test_one_task_and_seed_under_two_pipelines_is_an_error_naming_both_files(store, tmp_path):
    store.write(_episode("stack-two-blocks", 0, success=True, progress=1.0, pipeline="bbsea"))
    res = _quality("judge=oracle", f"episodes.store={store.root}", f"hydra.run.dir={tmp_path / 'q'}")
    assert res.returncode == 2 and res.stderr.startswith("error: ") and res.stderr.count("\n") == 1
    assert "task 'stack-two-blocks#0' is in two episodes" in res.stderr
    assert "bbsea/stack-two-blocks/episode_000000.h5" in res.stderr
    assert "gensim/stack-two-blocks/episode_000000.h5" in res.stderr
    res = _quality("judge=oracle", f"episodes.store={store.root}", "episodes.pipeline=bbsea",
                   f"hydra.run.dir={tmp_path / 'q2'}")
    assert res.returncode == 0, res.stderr[-2000:]


def test_a_vlm_judge_gets_the_store_episodes_as_bundles(store, openai_server, tmp_path):
    openai_server.default_reply = "Score: 4"
    res = _quality(f"episodes.store={store.root}", "episodes.camera=front", "episodes.pipeline=gensim",
                   f"judge.provider.base_url={openai_server.base_url}", "repeats=1", "metric=task_completion",
                   f"cache_dir={tmp_path / 'cache'}", f"hydra.run.dir={tmp_path / 'q'}")
    assert res.returncode == 0, res.stderr[-2000:]
    rec = json.loads((tmp_path / "q" / "result.json").read_text())
    assert set(rec["values"]["task_completion"]) == {"stack-two-blocks#0", "stack-block-tower#1", "align-rope#2",
                                                            "put-block-in-zone#0", "open-laptop#3"}
    bundle = tmp_path / "q" / "bundles" / "stack-two-blocks__seed0"
    assert len(list((bundle / "scene").glob("*.png"))) == 4 and len(list((bundle / "frames").glob("*.png"))) == 6
    sent = openai_server.requests[0]["payload"]["messages"][1]["content"]
    assert sum(part["type"] == "image_url" for part in sent) == 6  # every frame of the 6-step episode


@pytest.mark.parametrize("args, says", [
    (["episodes.store={tmp}/nowhere"], "episodes.store={tmp}/nowhere: no such folder"),
    (["episodes.store={store}", "episodes.pipeline=nosuch"],
     "episodes.store={store} has no episodes of episodes.pipeline=nosuch, episodes.group=null; it holds: "
     "gensim (stacking)"),
    (["episodes.store={store}", "episodes.group=nosuch"],
     "has no episodes of episodes.pipeline=null, episodes.group=nosuch; it holds: gensim (stacking)"),
    (["episodes.store={store}", "episodes.per_task=-1"], "episodes.per_task must be a whole number >= 1, got -1"),
    (["episodes.store={store}", "episodes.per_task=abc"], "episodes.per_task='abc': expected a whole number"),
    (["episodes.store={store}", "episodes.max_frames=1"], "episodes.max_frames must be a whole number >= 2, got 1"),
    (["episodes.store={store}", "episodes.per_task=5"],
     "episodes.store={store}: task 'align-rope' has 1 episodes, fewer than the 5 asked for (episodes.per_task=5;"),
    (["episodes.store={store}", "episodes.camera=side"], "episodes.camera=side: {store}/gensim/"),
    (["episodes.store={store}", "episodes.camera=side"], "records the cameras front, top"),
])
def test_a_store_that_cannot_give_the_episodes_asked_for_is_one_line_naming_the_key(store, tmp_path, args, says):
    fill = {"tmp": tmp_path, "store": store.root}
    res = _quality("judge=oracle", *(a.format(**fill) for a in args), f"hydra.run.dir={tmp_path / 'q'}")
    assert res.returncode == 2 and res.stderr.startswith("error: ") and res.stderr.count("\n") == 1, res.stderr
    assert says.format(**fill) in res.stderr
