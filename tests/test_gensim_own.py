"""GenSim's own code (pipeline=gensim_own): episodes recorded by GenSim's task classes, Environment and oracle from
the GenSim checkout beside this one (../shared/gensim, what a user's `pipeline.root` points at), through
src/collect.py, then read by src/diversity.py. Skipped with one line where that checkout is not beside."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from helpers import load_script

from simeval.episodes.store import EpisodeStore, read_episode

ROOT = Path(__file__).resolve().parents[1]
GENSIM = ROOT.parent / "shared" / "gensim"
TASK = "place-red-in-green"
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "HYDRA_FULL_ERROR": "0"}

# GenSim's episodes take 10-30 s each on 2 busy cores (its own three 480x640 renders per primitive included)
pytestmark = [pytest.mark.skipif(not (GENSIM / "cliport").is_dir(), reason="../shared/gensim is not beside this checkout"),
              pytest.mark.timeout(900)]


def _collect(tmp: Path, *args: str, timeout: int = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "src" / "collect.py"), "pipeline=gensim_own",
                           f"pipeline.root={GENSIM}", f"hydra.run.dir={tmp / 'run'}", *args], cwd=tmp, env=ENV,
                          capture_output=True, text=True, timeout=timeout)


def _tree(root: Path) -> dict[str, float]:
    return {str(p.relative_to(root)): p.stat().st_mtime for p in root.rglob("*")}


@pytest.fixture(scope="module")
def own_store(tmp_path_factory) -> Path:
    """Three episodes of GenSim's place-red-in-green (seeds 0-2, 32x32 frames) collected from the checkout."""
    tmp = tmp_path_factory.mktemp("gensim_own")
    before = _tree(GENSIM / "cliport")
    r = _collect(tmp, f"tasks=[{TASK}]", "debug=tiny", "episodes=3", "workers=2", f"store={tmp / 'store'}")
    assert r.returncode == 0, r.stderr[-3000:]
    assert _tree(GENSIM / "cliport") == before, "collecting wrote into the user's GenSim checkout"
    return tmp / "store"


def test_episodes_come_from_gensims_own_oracle_in_the_stores_convention(own_store):
    store = EpisodeStore(own_store)
    paths = store.paths("gensim_own", TASK)
    assert [p.name for p in paths] == [f"episode_{s:06d}.h5" for s in range(3)]
    for p in paths:
        ep = read_episode(p)
        g = ep.extra["gensim"]
        assert ep.source == "gensim" and ep.group == "placement" and g["task_class"] == "PlaceRedInGreen"
        assert ep.success == (g["total_reward"] >= 0.99) and g["clock"] == "simulated"
        # 240 Hz physics, a frame every 8th step: the rows are the reset frame plus one per 8 physics steps
        assert ep.control_hz == 30.0 and ep.n_steps == 1 + g["physics_steps"] // 8
        assert ep.action_space["kind"] == "joint_pos+suction" and ep.action.shape == (ep.n_steps, 7)
        assert ep.rgb["front"].shape == (ep.n_steps, 32, 32, 3) and ep.state.shape == (ep.n_steps, 14)
        # the high-level action is the oracle's pick/place pose pair, starting at the row where it was given
        assert ep.high_level_action.shape == (g["primitives"], 14) and ep.high_level_step[0] == 0
        assert np.all(np.diff(ep.high_level_step) > 0)
        # GenSim's step reward accumulates into progress; the episode ends at its total
        assert ep.progress[0] == 0 and ep.progress[-1] == pytest.approx(g["total_reward"])
        assert ep.reward.sum() == pytest.approx(g["total_reward"])
        # the arm's pixels are masked in every front frame; the heightmap camera sees only what comes within ~0.3 m
        # of the table: not the arm at home (row 0), the tool while it is down at the objects
        top = ep.robot_mask["top"].any(axis=(1, 2))
        assert ep.robot_mask["front"].any(axis=(1, 2)).all() and not top[0] and top.any()
        assert ep.robot_mask["top"].mean() < ep.robot_mask["front"].mean()
        # the stored action is the last joint target GenSim commanded; the arm follows it: the next row's joints
        # lie near it (GenSim moves the target 0.01 rad per physics step, so within 8 steps' worth)
        moving = np.abs(np.diff(ep.state[:, :6], axis=0)).max(axis=1) > 1e-3
        lag = np.abs(ep.action[:-1, :6] - ep.state[1:, :6]).max(axis=1)
        assert moving.sum() > 10 and np.median(lag[moving]) < 0.08
        # the suction turns on during the pick and is what the state reports
        assert ep.action[:, 6].max() == 1.0 and np.array_equal(ep.action[:-1, 6], ep.state[1:, 12])
        # the poses of the task's rigid bodies every row (what the state reading reads beside the arm): unit
        # quaternions, and something was carried (a block moves by more than 5 cm) while the suction held it
        poses = ep.object_poses
        assert poses.shape[0] == ep.n_steps and poses.shape[1] >= 2 and poses.shape[2] == 7
        assert np.allclose(np.linalg.norm(poses[..., 3:], axis=-1), 1.0, atol=1e-5)
        travel = np.linalg.norm(poses[-1, :, :3] - poses[0, :, :3], axis=-1)
        carried = np.linalg.norm(np.diff(poses[:, travel.argmax(), :3], axis=0), axis=-1) > 1e-3
        assert travel.max() > 0.05 and ep.state[1:, 12][carried].mean() > 0.5
    assert sum(read_episode(p).success for p in paths) >= 2  # GenSim's oracle on this task (3/3 when written)


def test_the_same_seed_gives_the_same_episode_on_any_load(own_store, tmp_path):
    """GenSim's 5 s move timeouts read simulated time: an episode recorded while two others run at once (the
    fixture's 2 workers on 2 cores) equals one recorded alone, bit for bit."""
    r = _collect(tmp_path, f"tasks=[{TASK}]", "debug=tiny", "episodes=1", "seed_offset=1", "workers=1",
                 f"store={tmp_path / 'store'}")
    assert r.returncode == 0, r.stderr[-3000:]
    alone = read_episode(EpisodeStore(tmp_path / "store").path_for("gensim_own", TASK, 1))
    shared = read_episode(EpisodeStore(own_store).path_for("gensim_own", TASK, 1))
    for key in ("state", "action", "progress"):
        assert np.array_equal(getattr(alone, key), getattr(shared, key)), key
    assert np.array_equal(alone.rgb["front"], shared.rgb["front"])


def test_a_collection_without_frames_records_the_same_rows_without_rendering_them(own_store, tmp_path):
    """`record.cameras=[]`: the state reading's collection (~3x faster on GenSim's own code); the renderer does not
    step the physics, so its rows are the rows of the same seed collected with frames, to the bit."""
    r = _collect(tmp_path, f"tasks=[{TASK}]", "debug=tiny", "episodes=1", "seed_offset=1", "record.cameras=[]",
                 f"store={tmp_path / 'store'}")
    assert r.returncode == 0, r.stderr[-3000:]
    frameless = read_episode(EpisodeStore(tmp_path / "store").path_for("gensim_own", TASK, 1))
    framed = read_episode(EpisodeStore(own_store).path_for("gensim_own", TASK, 1))
    assert frameless.rgb == {} and framed.rgb["front"].shape[0] == framed.n_steps
    for key in ("state", "action", "progress", "object_poses"):
        assert np.array_equal(getattr(frameless, key), getattr(framed, key)), key


def test_a_rerun_resumes_and_dynamics_diversity_reads_the_episodes(own_store, tmp_path):
    r = _collect(tmp_path, f"tasks=[{TASK}]", "debug=tiny", "episodes=3", f"store={own_store}")
    assert r.returncode == 0, r.stderr[-3000:]
    assert "0 new episodes, 3 already" in r.stdout + r.stderr
    r = subprocess.run([sys.executable, str(ROOT / "src" / "diversity.py"), "pipeline=gensim_own", "debug=tiny",
                        "task_group=placement", f"store={own_store}", f"checkpoint_dir={tmp_path / 'ck'}",
                        "progress=false", "threads=1", "episodes=2", "eval_episodes=[3,3]", "videos=0",
                        f"hydra.run.dir={tmp_path / 'wm'}"], cwd=tmp_path, env=ENV, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads((tmp_path / "wm" / "result.json").read_text())
    assert result["identity"]["pipeline"] == "gensim_own"
    one_step = result["values"]["prediction"]["summary"]["one_step"]
    assert one_step["frames"] > 0 and np.isfinite(one_step["model"]["error_per_pixel"])


def _error_line(r: subprocess.CompletedProcess) -> str:
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-2000:]
    return lines[-1]


def test_a_folder_that_is_not_a_gensim_checkout_is_one_line(tmp_path):
    (tmp_path / "notgensim").mkdir()
    r = _collect(tmp_path, f"pipeline.root={tmp_path / 'notgensim'}", f"store={tmp_path / 'store'}")
    line = _error_line(r)
    assert "is not a GenSim checkout" in line and "cliport" in line
    r = subprocess.run([sys.executable, str(ROOT / "src" / "collect.py"), "pipeline=gensim_own",
                        f"hydra.run.dir={tmp_path / 'run2'}", f"store={tmp_path / 'store'}"], cwd=tmp_path,
                       env={**ENV, "GENSIM_ROOT": str(tmp_path / "notgensim")}, capture_output=True, text=True,
                       timeout=300)
    assert "(from GENSIM_ROOT) is not a GenSim checkout" in _error_line(r)  # which setting to fix


def test_an_unknown_task_and_a_mismatched_rate_are_one_line(tmp_path):
    line = _error_line(_collect(tmp_path, "tasks=[no-such-task]", f"store={tmp_path / 'store'}"))
    assert "no-such-task" in line and "registry" in line and " tasks in cliport/tasks/" in line
    line = _error_line(_collect(tmp_path, "tasks=[place-red-in-purple]", f"store={tmp_path / 'store'}"))
    assert "did you mean place-red-in-green" in line  # a name in the checkout's registry (cliport/tasks/__init__.py)
    line = _error_line(_collect(tmp_path, f"tasks=[{TASK}]", "pipeline.native.frame_every=6",
                                f"store={tmp_path / 'store'}"))
    assert "record.control_hz=30" in line and "240/6" in line
    line = _error_line(_collect(tmp_path, f"tasks=[{TASK}]", "pipeline.native.python=/nonexistent/python",
                                f"store={tmp_path / 'store'}"))
    assert "/nonexistent/python" in line and "make gensim-env" in line


def _checkout_with_a_raising_task(tmp: Path) -> Path:
    """A GenSim checkout of links to ../shared/gensim plus one generated task whose reset raises (the checkout
    itself is not touched). generated_tasks/__init__.py lists the folder it really lies in, so it is copied."""
    root = tmp / "gensim"
    (root / "cliport" / "generated_tasks").mkdir(parents=True)
    for entry in (GENSIM / "cliport").iterdir():
        if entry.name != "generated_tasks":
            (root / "cliport" / entry.name).symlink_to(entry)
    for entry in (GENSIM / "cliport" / "generated_tasks").iterdir():
        if entry.suffix == ".py" and entry.name != "__init__.py":
            (root / "cliport" / "generated_tasks" / entry.name).symlink_to(entry)
    shutil.copy(GENSIM / "cliport" / "generated_tasks" / "__init__.py", root / "cliport" / "generated_tasks")
    (root / "cliport" / "generated_tasks" / "place_nothing_raising.py").write_text(
        "from cliport.tasks.task import Task\n\n\nclass PlaceNothingRaising(Task):\n"
        "    \"\"\"A task whose reset fails.\"\"\"\n\n    def reset(self, env):\n"
        "        raise ValueError('this task cannot be reset')\n")
    return root


def test_a_gensim_task_that_raises_is_reported_not_dropped(tmp_path):
    root = _checkout_with_a_raising_task(tmp_path)
    r = _collect(tmp_path, f"pipeline.root={root}", "tasks=[place-nothing-raising]", "episodes=1",
                 f"store={tmp_path / 'store'}", timeout=300)
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr[-2000:]
    line = r.stderr.splitlines()[-1]  # what raised, and where in the task's code
    assert "ValueError: this task cannot be reset" in line and "place_nothing_raising.py:8" in line
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["values"]["failed"] == [{"task": "place-nothing-raising", "seed": 0,
                                           "error": "ValueError: this task cannot be reset",
                                           "where": result["values"]["failed"][0]["where"]}]
    assert result["values"]["tasks"]["place-nothing-raising"]["failed"] == [0]


def test_the_torchvision_stand_in_refuses_any_use():
    worker = load_script(ROOT / "src" / "simeval" / "pipelines" / "gensim_own" / "worker.py")  # GenSim's process runs it
    stand_in = worker._StandIn("torchvision")
    with pytest.raises(ImportError, match="stand-in"):
        stand_in.transforms  # noqa: B018
    with pytest.raises(AttributeError):
        stand_in.__file__  # noqa: B018  (introspection sees a plain missing attribute, as for any module)


def _workers_of(store: Path) -> list[int]:
    """Pids of worker processes whose request lies in this store's scratch folders."""
    out = []
    for proc in Path("/proc").iterdir():
        try:
            cmd = (proc / "cmdline").read_bytes().decode(errors="replace")
        except OSError:
            continue
        if "worker.py" in cmd and str(store) in cmd:
            out.append(int(proc.name))
    return out


def test_kill_9_of_the_collector_takes_its_gensim_workers_and_the_rerun_resumes(tmp_path):
    import signal
    import time

    store = tmp_path / "store"
    args = [sys.executable, str(ROOT / "src" / "collect.py"), "pipeline=gensim_own", f"pipeline.root={GENSIM}",
            f"tasks=[{TASK}]", "debug=tiny", "episodes=1", "workers=1", f"store={store}",
            f"hydra.run.dir={tmp_path / 'run'}"]
    collector = subprocess.Popen(args, cwd=tmp_path, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not _workers_of(store) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _workers_of(store), "no GenSim worker started"
    collector.send_signal(signal.SIGKILL)
    collector.wait()
    deadline = time.monotonic() + 10
    while _workers_of(store) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _workers_of(store), "a GenSim worker outlived its collector"
    assert list(store.glob(".gensim-work-*")), "the killed collector's scratch folder is left for the rerun"
    r = subprocess.run(args, cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert EpisodeStore(store).exists_intact("gensim_own", TASK, 0)
    assert not list(store.glob(".gensim-work-*"))  # the dead collector's scratch is removed, and the rerun's own


def test_gensims_own_task_as_a_gymnasium_env_follows_its_oracle_to_the_recorded_episode(own_store):
    """GenSimEnv (pick/place steps through GenSim's env.step in a worker) driven by GenSim's oracle: the same
    pick/place poses as the recorded episode of the same seed, the same reward, success, observations in its space."""
    from simeval.pipelines.gensim_own.env import GensimEnv
    from simeval.pipelines.gensim_own.native import GensimSettings

    recorded = read_episode(EpisodeStore(own_store).path_for("gensim_own", TASK, 0))
    env = GensimEnv(TASK, GensimSettings(root=str(GENSIM)), image_size=(32, 32))
    try:
        obs, info = env.reset(seed=0)
        assert env.observation_space.contains(obs) and info["progress"] == 0 and not info["success"]
        actions = []
        while (action := env.oracle_action()) is not None:
            actions.append(action)
            obs, _, terminated, truncated, info = env.step(action)
            assert env.observation_space.contains(obs)
            if terminated or truncated:
                break
        assert np.allclose(np.stack(actions), recorded.high_level_action, atol=1e-6)
        assert info["progress"] == pytest.approx(recorded.progress[-1]) and info["success"] == recorded.success
        assert terminated and not truncated
    finally:
        env.close()
    assert env._proc is None


def test_a_primitive_that_does_not_return_ends_the_rollout_as_failed_and_the_next_one_runs():
    """GenSim's descent loop never returns for some poses (it lowers the target until contact): a step past
    pipeline.native.step_timeout_s stops GenSim's worker and ends the rollout as failed, with the error in info and
    in the rollout's record; the next reset starts a fresh worker and the oracle solves that seed."""
    from simeval.measures.generalization.rollouts import rollout_task
    from simeval.measures.generalization.random_baseline import RandomActions
    from simeval.pipelines.gensim_own.env import GensimEnv
    from simeval.pipelines.gensim_own.native import GensimSettings

    env = GensimEnv(TASK, GensimSettings(root=str(GENSIM), step_timeout_s=0.01), image_size=(32, 32))
    try:
        obs, _ = env.reset(seed=0)
        first = env._proc
        obs2, reward, terminated, truncated, info = env.step(env.oracle_action())
        assert terminated and not truncated and reward == 0.0 and not info["success"] and info["progress"] == 0.0
        assert info["error"].startswith("one step ran past 0.01 s (pipeline.native.step_timeout_s)")
        assert env._proc is None and first.poll() is not None  # GenSim's worker was stopped, not left running
        assert all(np.array_equal(obs2["rgb"][c], obs["rgb"][c]) for c in obs["rgb"])  # the last observation
        env.settings = GensimSettings(root=str(GENSIM))
        env.reset(seed=0)  # a fresh worker
        while (action := env.oracle_action()) is not None:
            _, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
        assert info["success"] and "error" not in info
    finally:
        env.close()
    settings = GensimSettings(root=str(GENSIM), step_timeout_s=0.01)
    out = rollout_task(RandomActions("pick_place", image_size=(32, 32)), TASK, [0, 1],
                       make_env=lambda task, *a: GensimEnv(task, settings, image_size=a[2], cameras=a[3]))
    assert [(e["steps"], e["success"], e["error"][:13]) for e in out["episodes"]] == [(1, False, "one step ran ")] * 2


def test_generalization_trains_on_gensims_own_episodes_and_rolls_out_in_its_own_env(own_store, tmp_path):
    """src/generalization.py pipeline=gensim_own: a (tiny) pick/place policy trained on GenSim's own episodes, rolled
    out through GenSim's own environment on the train split; the eval split (GenSim's test mode with its unseen
    colours) leaves place-red-in-green's scene as it was (its colours are fixed), so nothing is rolled out again."""
    r = subprocess.run([sys.executable, str(ROOT / "src" / "generalization.py"), "pipeline=gensim_own",
                        f"pipeline.root={GENSIM}", "debug=tiny", "task_group=placement", f"tasks=[{TASK}]",
                        f"store={own_store}", f"checkpoint_dir={tmp_path / 'ck'}", "eval.splits=[train,eval]",
                        "eval.videos=false", "progress=false", "logger=none", f"hydra.run.dir={tmp_path / 'run'}"],
                       cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["identity"]["pipeline"] == "gensim_own"
    assert result["identity"]["variations"] == {TASK: {"mode": "test", "unseen_colors": True}}
    assert result["identity"]["settings"]["model"]["action_space"] == "pick_place"  # the recorded primitives
    rows = {(t["task"], t["split"]): t for t in result["values"]["tasks"]}
    assert set(rows) == {(TASK, "train"), (TASK, "eval")}
    (train,) = rows[TASK, "train"]["episodes"]  # one rollout, ended by GenSim (its done) or the task's max_steps
    assert 1 <= train["steps"] <= 10 and 0.0 <= train["progress"] <= 1.0
    assert rows[TASK, "eval"]["episodes"] == [{"seed": train["seed"], "start": train["start"], "unvaried": True}]
    assert result["values"]["splits"]["eval"] == {"success": {"k": 0, "n": 0, "rate": None, "ci": [0.0, 1.0]},
                                                  "mean_progress": None, "tasks": 1, "unvaried": 1}
    assert "split eval, place-red-in-green: the variation" in r.stdout + r.stderr
    assert "nothing rolled out" in r.stdout + r.stderr
    assert result["values"]["training"]["trained_tasks"] == [TASK]
    # as GenSim's demos.py: the oracle's successful episodes only (pipeline=gensim_own's default)
    assert result["identity"]["demonstrations"] == "successful"
    assert result["values"]["training"]["demonstrations"]["kept"] == "successful"
    assert result["values"]["training"]["demonstrations"]["failed"] == 0


def test_missing_training_episodes_name_the_collect_command_with_the_users_checkout(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "src" / "generalization.py"), "pipeline=gensim_own",
                        f"pipeline.root={GENSIM}", "policy=authors_gensim_cpu", f"tasks=[{TASK}]",
                        f"store={tmp_path / 'store'}", f"checkpoint_dir={tmp_path / 'ck'}",
                        f"hydra.run.dir={tmp_path / 'run'}"], cwd=tmp_path, env=ENV, capture_output=True, text=True,
                       timeout=300)
    line = _error_line(r)
    assert f"python src/collect.py pipeline=gensim_own pipeline.root={GENSIM.resolve()} 'tasks=[{TASK}]' episodes=42 " \
        in line, line


def test_a_pipeline_with_neither_suite_nor_own_code_cannot_be_evaluated_closed_loop(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "src" / "generalization.py"), "pipeline=custom",
                        f"hydra.run.dir={tmp_path / 'run'}", f"checkpoint_dir={tmp_path / 'ck'}"], cwd=tmp_path,
                       env=ENV, capture_output=True, text=True, timeout=300)
    line = _error_line(r)
    assert "pipeline=custom" in line and "pipeline.native" in line


def test_resuming_into_a_store_recorded_at_another_size_is_refused(own_store, tmp_path):
    line = _error_line(_collect(tmp_path, f"tasks=[{TASK}]", "episodes=1", f"store={own_store}"))
    assert "record.image_size=[32, 32]" in line and "[64, 64]" in line


def test_the_collect_hint_repeats_the_stores_frame_size(own_store, tmp_path):
    """The store holds 32x32 episodes: the command diversity suggests must ask for that size, or the collector
    (which never mixes sizes in one store) would refuse it."""
    r = subprocess.run([sys.executable, str(ROOT / "src" / "diversity.py"), "pipeline=gensim_own",
                        "task_group=placement", f"store={own_store}", f"hydra.run.dir={tmp_path / 'run'}"],
                       cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=300)
    line = _error_line(r)
    assert "episodes=50" in line and "'record.image_size=[32,32]'" in line


def test_the_control_on_gensims_own_episodes_runs_resumes_and_refuses_other_settings(own_store, tmp_path):
    """`src/controls.py gensim_own` at tiny sizes on two of GenSim's own tasks (the fixture's and one more
    collected here): a generalist and two specialists trained and scored on the same held-out episodes, the
    table's object-focused errors the ratios of the runs' sums (by hand); a rerun reuses the three runs; other
    settings, one task, and a store without enough episodes are one line each, exit 2."""
    store = tmp_path / "store"
    shutil.copytree(own_store, store)
    r = _collect(tmp_path, "tasks=[place-blue-on-line-ends]", "debug=tiny", "episodes=3", "workers=2",
                 f"store={store}")
    assert r.returncode == 0, r.stderr[-3000:]
    script = ROOT / "src" / "controls.py"
    args = ["--group", "placement", "--tasks", "2", "--per-task", "1", "--heldout", "3", "3", "--preset", "tiny",
            "--steps", "3", "--seeds", "0", "--store", str(store), "--out", str(tmp_path / "out")]

    def control(*extra):
        return subprocess.run([sys.executable, str(script), "gensim_own", *args, *extra], capture_output=True,
                              text=True, timeout=600, cwd=ROOT, env=ENV)

    r = control()
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads((tmp_path / "out" / "tables" / "control_gensim_own.json").read_text())
    assert result["tasks"] == ["place-blue-on-line-ends", TASK] and result["verdict"]["held_out_episodes"] == 2
    runs = tmp_path / "out" / "controls" / "gensim_own" / "runs"
    assert sorted(p.name for p in runs.glob("*.json")) == [
        "generalist_all_s0.json", "specialists_place-blue-on-line-ends_s0.json", f"specialists_{TASK}_s0.json"]

    def object_error(paths):  # sum of squared errors / (3 x kept pixels) over the held-out episodes
        sums = [e["sums"] for p in paths for e in json.loads(p.read_text())["values"]["prediction"]["per_episode"]]
        assert len(sums) == 2  # one held-out episode (3) of each task
        return sum(s["one_step/model/object"] for s in sums) / (3 * sum(s["one_step/kept_pixels"] for s in sums))

    pooled = result["verdict"]["pooled"]["one_step_object"]
    np.testing.assert_allclose(pooled["generalist"], object_error([runs / "generalist_all_s0.json"]), rtol=1e-9)
    np.testing.assert_allclose(pooled["specialists"], object_error(sorted(runs.glob("specialists_*.json"))), rtol=1e-9)
    np.testing.assert_allclose(pooled["difference"], pooled["generalist"] - pooled["specialists"], rtol=1e-9)
    assert (tmp_path / "out" / "figures" / "control_gensim_own.png").stat().st_size > 10_000
    assert "| pooled |" in (tmp_path / "out" / "tables" / "control_gensim_own.md").read_text()

    again = control()
    assert again.returncode == 0 and again.stdout.count("saved already, reused") == 3
    for extra, said in ((("--steps", "4"), "was run with other settings"),  # would label saved runs anew
                        (("--tasks", "1"), "--tasks 1: expected at least 2"),
                        (("--group", "nosuchgroup"), "--group nosuchgroup: GenSim's groups (the authors' substring rule)"),
                        (("--camera", "nosuch"), "--camera nosuch: the episodes were recorded from"),
                        (("--heldout", "3", "5"), "needs 2 gensim_own tasks of group placement with 5 episodes")):
        refused = control(*extra)
        assert refused.returncode == 2 and "Traceback" not in refused.stderr, extra
        assert said in refused.stderr.strip().splitlines()[-1], refused.stderr


def test_the_eval_split_rolls_out_only_the_scenes_its_variation_changed():
    """GenSim's checkout draws its train colours in every task.mode, so mode=test alone changes no scene; with
    unseen_colors a task that passes its mode to utils.get_colors (separating-piles) draws EVAL_COLORS and is
    rolled out, one with fixed colours (place-red-in-green) starts from the train split's scene and is not. Checked
    on the first observations (run_splits compares them with the train rollouts') and on the pixels themselves."""
    from simeval.measures.generalization import rollouts as ev
    from simeval.measures.generalization.run import run_splits
    from simeval.measures.generalization.random_baseline import RandomActions
    from simeval.pipelines.gensim_own.pipeline import GensimOwnPipeline

    pipeline = GensimOwnPipeline.from_config({"name": "gensim_own", "root": str(GENSIM), "native": {}})
    policy = RandomActions("pick_place", image_size=(32, 32))
    piles, unseen, test_only = "separating-piles", {"mode": "test", "unseen_colors": True}, {"mode": "test"}
    plan = {"train": [(TASK, {}), (piles, {})], "eval": [(TASK, unseen), (piles, unseen), (piles, test_only)]}
    with tempfile.TemporaryDirectory() as tmp:
        rows = run_splits(policy, plan, [100000], 1, Path(tmp) / "rollouts.json", 0, make_env=pipeline.make_env,
                          environment=pipeline.environment_id())
    assert len({e["start"] for r in rows if r["task"] == TASK for e in r["episodes"]}) == 1  # one scene in both splits
    train_piles, eval_piles, eval_test_only = (r for r in rows if r["task"] == piles)
    assert eval_piles["episodes"][0]["start"] != train_piles["episodes"][0]["start"]
    assert eval_piles["unvaried"] == 0 and eval_piles["episodes"][0]["steps"] == 1
    assert eval_test_only["unvaried"] == 1 and eval_test_only["episodes"][0]["start"] == train_piles["episodes"][0]["start"]
    assert ev.summarize(rows)["eval"]["success"]["n"] == 1 and ev.summarize(rows)["eval"]["unvaried"] == 2
    # the digests say what the pixels say: EVAL_COLORS on separating-piles' zones and blocks, not on the fixed ones
    images = {}
    for label, variation in (("train", {}), ("unseen", unseen)):
        env = pipeline.make_env(piles, "pick_place", variation, (32, 32), ["front"], 1)
        try:
            images[label] = env.reset(seed=100000)[0]["rgb"]["front"]
        finally:
            env.close()
    assert not np.array_equal(images["train"], images["unseen"])


def test_a_gensim_eval_variation_is_checked_key_by_key():
    """eval.variation for GenSim's own tasks: one line naming the key, and unseen colours refused in train mode
    (where GenSim draws the train colours: it would vary nothing)."""
    from simeval.errors import UserError
    from simeval.pipelines.gensim_own.pipeline import check_eval_variation

    check_eval_variation({"mode": "test", "unseen_colors": True})
    check_eval_variation({"mode": "val"})
    for variation, said in (({"mode": "test", "colours": True}, "eval.variation.colours: not a variation of GenSim's"),
                            ({"mode": "tests"}, ("eval.variation.mode='tests': GenSim's own tasks vary by {mode: "
                                                 "train | val | test, unseen_colors: true | false} only")),
                            ({"mode": "test", "unseen_colors": "true"}, "eval.variation.unseen_colors='true'"),
                            ({"unseen_colors": True}, "in train mode draws the train colours")):
        with pytest.raises(UserError) as e:
            check_eval_variation(variation)
        assert said in str(e.value) and "\n" not in str(e.value), (variation, str(e.value))
