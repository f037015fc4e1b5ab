"""The PyBullet core and the GenSim-style suite: spec validation, seeded sampling, what an episode records,
the oracle on one task of every group, and parallel, resumable, deterministic collection."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from simeval.episodes.store import EpisodeStore, read_episode
from simeval.sim.rollout import RecordSettings, run_episode
from simeval.sim.spec import SUITES_DIR, SpecError, load_suite, parse_spec, sample_instance

ROOT = Path(__file__).resolve().parents[1]
SUITE = {s.name: s for s in load_suite(SUITES_DIR / "gensim")}


def test_suite_has_every_group_with_enough_tasks():
    groups = {}
    for s in SUITE.values():
        groups.setdefault(s.group, []).append(s.name)
    assert set(groups) == {"placement", "stacking", "piles", "assembling"}
    assert all(len(v) >= 5 for g, v in groups.items() if g != "piles") and len(groups["piles"]) >= 3
    assert len({s.description for s in SUITE.values()}) == len(SUITE)  # every task has its own description


@pytest.mark.parametrize("bad,match", [
    ({"shape": "cube"}, "shape 'cube' is not one of"),
    ({"colors": ["mauve"]}, "unknown colour"),
    ({"count": [3, 1]}, "count must satisfy"),
])
def test_spec_errors_name_the_problem(bad, match):
    data = {"name": "t", "group": "g", "description": "d",
            "objects": [{"name": "a", "shape": "block", "colors": ["red"], **bad}], "goals": []}
    with pytest.raises(SpecError, match=match):
        parse_spec(data, "t.yaml")
    with pytest.raises(SpecError, match="names object 'b'"):
        parse_spec({**data, "objects": [{"name": "a", "shape": "block"}],
                    "goals": [{"type": "stack", "what": ["a", "b"]}]}, "t.yaml")
    with pytest.raises(SpecError, match="missing goals"):
        parse_spec({k: v for k, v in data.items() if k != "goals"}, "t.yaml")


def test_sampling_is_seeded_matched_and_non_overlapping():
    spec = SUITE["put-blocks-in-matching-zones"]
    a, b = sample_instance(spec, 3), sample_instance(spec, 3)
    assert [(o.id, o.color) for o in a.objects] == [(o.id, o.color) for o in b.objects]
    assert all(np.allclose(a.poses[k][0], b.poses[k][0]) for k in a.poses)
    colors = {o.name: o.color for o in a.objects}
    assert colors["block_a"] == colors["zone_a"] and colors["block_b"] == colors["zone_b"]
    assert f"the {colors['block_a']} block to the {colors['zone_a']} zone" in a.description
    seen = {tuple(o.color for o in sample_instance(spec, s).objects) for s in range(10)}
    assert len(seen) > 1  # colours vary with the seed
    inst = sample_instance(SUITE["construct-corner-building"], 0)
    xy = [inst.poses[o.id][0] for o in inst.objects]
    r = [o.footprint for o in inst.objects]
    assert all(np.linalg.norm(xy[i] - xy[j]) > r[i] + r[j] for i in range(len(xy)) for j in range(i))


def test_an_episode_records_what_the_authors_logged():
    ep = run_episode(SUITE["stack-two-blocks"], 0, RecordSettings(cameras=("top", "front"), image_size=(32, 40),
                                                                  scene_view_size=(48, 48)))
    t = ep.n_steps
    assert ep.success and t > 30
    assert ep.rgb["top"].shape == (t, 32, 40, 3) and ep.rgb["front"].dtype == np.uint8
    assert ep.state.shape == (t, 12) and ep.action.shape == (t, 6)  # 6 joint pos + 6 vel; joint targets
    assert ep.high_level_action.shape[1] == 14 and np.all(np.diff(ep.high_level_step) > 0)
    assert ep.scene_views.shape == (4, 48, 48, 3) and ep.scene_views.std() > 5  # 4 views with something in them
    assert ep.reward.sum() == pytest.approx(ep.progress[-1]) and ep.progress[-1] == 1.0
    assert ep.is_first[0] and ep.is_terminal[-1] and ep.is_first.sum() == ep.is_terminal.sum() == 1
    assert ep.control_hz == 30.0 and "stack" in ep.description.lower()


@pytest.mark.parametrize("task", ["put-block-in-zone", "stack-block-tower", "sweep-pile-into-zone", "build-bridge"])
def test_oracle_solves_a_task_of_every_group(task):
    ep = run_episode(SUITE[task], 1, RecordSettings(cameras=()))
    assert ep.success and ep.progress[-1] == 1.0


def _collect(store, run_dir, *extra):
    return [sys.executable, str(ROOT / "src" / "collect.py"), "tasks=[stack-two-blocks,put-block-in-zone]",
            "episodes=3", "workers=2", f"store={store}", "record.image_size=[24,24]", "record.scene_view_size=[32,32]",
            f"hydra.run.dir={run_dir}", *extra]


def test_collection_is_parallel_resumable_and_deterministic(tmp_path):
    store = tmp_path / "store"
    proc = subprocess.Popen(_collect(store, tmp_path / "r1"), cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 120
    while not list(store.rglob("episode_*.h5")) and time.time() < deadline:
        time.sleep(0.1)
    os.killpg(proc.pid, signal.SIGKILL)  # the collector and its workers, mid-run
    proc.wait()
    done_before = len(EpisodeStore(store).paths())
    assert 1 <= done_before < 6
    res = subprocess.run(_collect(store, tmp_path / "r2"), cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    summary = json.loads((tmp_path / "r2" / "result.json").read_text())["values"]
    assert summary["skipped"] == done_before and len(summary["new"]) == 6 - done_before
    assert summary["tasks"]["stack-two-blocks"]["episodes"] == 3 and summary["tasks"]["put-block-in-zone"]["rate"] == 1.0
    assert len(EpisodeStore(store).index("gensim")) == 6  # every file complete and readable
    again = run_episode(SUITE["put-block-in-zone"], 2, RecordSettings(image_size=(24, 24), scene_view_size=(32, 32)))
    stored = read_episode(EpisodeStore(store).path_for("gensim", "put-block-in-zone", 2))
    np.testing.assert_array_equal(stored.rgb["top"], again.rgb["top"])  # same seed, same episode
    np.testing.assert_allclose(stored.state, again.state)


def test_collect_rejects_unknown_tasks(tmp_path):
    res = subprocess.run([sys.executable, str(ROOT / "src" / "collect.py"), "task_group=juggling",
                          f"hydra.run.dir={tmp_path}"], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode != 0 and "unknown task_group 'juggling'; available: assembling, piles, placement" in res.stderr


@pytest.mark.parametrize("data,match", [
    (None, "a task spec is a mapping, got NoneType"),
    ({"name": "t", "group": "g", "description": "d", "objects": ["block"], "goals": []}, "an object is a mapping"),
    ({"name": "t", "group": "g", "description": "d", "objects": [{"shape": "block"}], "goals": []}, "at least `name`"),
    ({"name": "t", "group": "g", "description": "d", "objects": [], "goals": ["stack"]}, "a goal is a mapping"),
])
def test_malformed_specs_are_spec_errors_not_crashes(data, match, tmp_path):
    with pytest.raises(SpecError, match=match):
        parse_spec(data, "t.yaml")
    (tmp_path / "empty.yaml").write_text("")
    with pytest.raises(SpecError, match="empty.yaml: a task spec is a mapping"):
        from simeval.sim.spec import load_spec

        load_spec(tmp_path / "empty.yaml")
