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
from simeval.sim.tasks.spec import suite_dir, SpecError, load_suite, parse_spec, sample_instance

ROOT = Path(__file__).resolve().parents[1]
SUITE = {s.name: s for s in load_suite(suite_dir("gensim"))}


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
    t = ep.n_steps  # rows: the reset observation + one per action (simeval.episodes.store's convention)
    assert ep.success and t > 30
    assert ep.rgb["top"].shape == (t, 32, 40, 3) and ep.rgb["front"].dtype == np.uint8
    # 6 joint pos + 6 vel (the authors' 12) + suction command + holding; 6 joint targets + suction command
    assert ep.state.shape == (t, 14) and ep.action.shape == (t, 7)
    assert ep.high_level_action.shape[1] == 14 and np.all(np.diff(ep.high_level_step) > 0)
    assert ep.scene_views.shape == (4, 48, 48, 3) and ep.scene_views.std() > 5  # 4 views with something in them
    assert ep.progress[0] == 0.0 and ep.progress[-1] == 1.0  # not solved at the start, solved at the end
    assert ep.is_first[0] and ep.is_terminal[-1] and ep.is_first.sum() == ep.is_terminal.sum() == 1
    assert ep.control_hz == 30.0 and "stack" in ep.description.lower()


def test_reward_comes_when_and_where_a_goal_is_met():
    """Two blocks, each to the zone of its colour (two goals): progress reaches 0.5 during the first
    pick-and-place and 1.0 during the second, and each primitive during which a goal is met places its block
    inside that goal's zone, located from the seed's sampled poses (zones do not move), not from progress."""
    spec = SUITE["put-blocks-in-matching-zones"]
    ep = run_episode(spec, 0, RecordSettings(cameras=()))
    inst = sample_instance(spec, 0)
    starts = list(ep.high_level_step) + [ep.n_steps]
    assert len(starts) == 3  # two pick-and-place primitives
    for goal, (level, zone) in enumerate(((0.5, "zone_a0"), (1.0, "zone_b0"))):
        first = int(np.argmax(ep.progress >= level))  # the step where the goal first counts as met
        assert ep.progress[first] >= level and ep.progress[:first].max(initial=0) < level
        # row `first` is what action first - 1 produced (simeval.episodes.store's convention): that action's
        # primitive met the goal and that action earned the reward
        prim = int(np.searchsorted(starts, first - 1, side="right")) - 1
        assert prim == goal and ep.reward[first - 1] > 0
        zone_xy, _ = inst.poses[zone]
        place_xy = ep.high_level_action[prim, 7:9]
        assert np.linalg.norm(place_xy - zone_xy) < 0.05  # the 0.10 m zone's half-width: placed inside it
    assert ep.progress[: starts[1]].max() == 0.5 and ep.progress[-1] == 1.0 and ep.success
    assert ep.reward[: int(np.argmax(ep.progress > 0)) - 1].sum() == 0  # nothing before the first block lands


@pytest.mark.parametrize("task", ["put-block-in-zone", "stack-block-tower", "sweep-pile-into-zone", "build-bridge"])
def test_oracle_solves_a_task_of_every_group(task):
    ep = run_episode(SUITE[task], 1, RecordSettings(cameras=()))
    assert ep.success and ep.progress[-1] == 1.0


def _collect(store, run_dir, *extra):
    return [sys.executable, str(ROOT / "src" / "collect.py"), "tasks=[stack-two-blocks,put-block-in-zone]",
            "episodes=3", "workers=2", f"store={store}", "record.image_size=[24,24]", "record.scene_view_size=[32,32]",
            f"hydra.run.dir={run_dir}", *extra]


def _children(pid: int) -> set[int]:
    kids = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == pid:
                kids.add(int(stat.parent.name))
        except (OSError, IndexError, ValueError):  # a process that ended while we looked
            pass
    return kids


def _running(pid: int) -> bool:
    try:  # a zombie (state Z) has stopped; only its parent has not collected it yet
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _kill_group(pgid: int) -> None:
    try:
        os.killpg(pgid, signal.SIGKILL)
    except ProcessLookupError:  # every process of the group has ended
        pass


def _wait_until_none_runs(pids: set[int], seconds: float) -> set[int]:
    deadline = time.time() + seconds
    while {p for p in pids if _running(p)} and time.time() < deadline:
        time.sleep(0.1)
    return {p for p in pids if _running(p)}


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds worker processes through /proc")
def test_collection_is_parallel_resumable_and_deterministic(tmp_path):
    store = tmp_path / "store"
    proc = subprocess.Popen(_collect(store, tmp_path / "r1"), cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.time() + 120
        while not list(store.rglob("episode_*.h5")) and time.time() < deadline:
            time.sleep(0.1)
        workers = _children(proc.pid)
        assert len(workers) >= 2
        os.kill(proc.pid, signal.SIGKILL)  # the collector only, mid-run: nothing can clean up after it
        proc.wait()
        assert _wait_until_none_runs(workers, 5) == set()  # its workers stop too, rather than run on under init
    finally:
        _kill_group(proc.pid)  # whatever is left, so a failure leaves no process behind
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


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds worker processes through /proc")
def test_a_plain_kill_of_the_collector_stops_its_workers(tmp_path):
    proc = subprocess.Popen(_collect(tmp_path / "store", tmp_path / "r"), cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)  # Hydra logs to stdout
    try:
        deadline = time.time() + 120
        while len(_children(proc.pid)) < 2 and time.time() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # the workers are running episodes
        workers = _children(proc.pid)
        assert len(workers) >= 2
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
        assert proc.returncode == 128 + signal.SIGTERM and "run the same command again to resume" in out, out
        assert "Traceback" not in out
        assert _wait_until_none_runs(workers, 5) == set()
    finally:
        _kill_group(proc.pid)


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
        from simeval.sim.tasks.spec import load_spec

        load_spec(tmp_path / "empty.yaml")


@pytest.mark.parametrize("robot", ["xarm6", "panda"])
def test_both_robots_meet_the_robot_interface_the_environment_uses(robot):
    from simeval.sim.core.world import World
    from simeval.sim.robots import Robot
    from simeval.sim.robots.panda import Panda
    from simeval.sim.robots.xarm import Arm

    world = World(30.0, shadows=False)
    try:
        arm = Panda(world) if robot == "panda" else Arm(world)
        assert isinstance(arm, Robot)
        assert arm.held is None and arm.body in arm.body_ids
        state = arm.state()
        applied = arm.apply(arm.last_action if robot == "panda" else np.r_[arm.target, 0.0].astype(np.float32))
        assert state.dtype == np.float32 and applied.dtype == np.float32
    finally:
        world.close()
